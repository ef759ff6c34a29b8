"""The game client's I/O edge: pose frames in over Zenoh, game events and state out, log and frames.

On one zenoh session it declares

* a channel subscriber on ``mocap/tracker/<tracker>/pose`` (``PoseFrame``) and one on
  ``.../body`` (``BodyInfo``, for the player's height),
* publishers on ``mocap/game/<id>/event`` (one ``GameEvent`` per recognised gesture and game
  event) and ``mocap/game/<id>/state`` (``GameState`` at ``state_hz`` of game time).

Every frame is fed to a :class:`~game_client.round.GameRound`; the round's records go to the JSON-lines
log, and with ``frames_out`` rendered frames are written (PNG, GIF, MP4). The message handling is
:class:`GameClient` (no I/O of its own: it is fed payloads and hands encoded messages to two
callables), so it is tested in-process.

Input checks
------------
Payloads that do not decode are counted (``decode_errors``). Decoded messages are then checked by
meaning (:mod:`protocol.wire.validate`): a ``BodyInfo`` of implausible scale, a ``PoseFrame`` with
out-of-range positions, rotations or joints, or one that does not fit the stream's clock
(:class:`~protocol.wire.validate.StreamClock`: far-future or stale stamps, seq jumps) is counted
per reason (``invalid_<reason>``) and dropped before it touches the round, so no state outlives
it. Warnings are rate-limited (one line per reason per 5 s, with the suppressed count). A new
stream (tracker restart: seq reset or a time jump, confirmed by a few frames) is counted
(``tracker_restarts``), the recogniser starts over and the game clock continues, so gestures are
recognised again from the new stream's first frames. Every counter and sequence number that goes
into a message is clamped to the codec's integer range. Channel subscribers are used (a callback
subscriber still declared at exit hangs eclipse-zenoh 1.10), everything is undeclared in
``finally``, and the loop checks its stop event at least every few milliseconds, so SIGINT/SIGTERM
end the process well within 2 s. After a round ends a new one starts ``next_round_s`` later.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import zenoh

from protocol.net.follow import TrackerFollower, follow_step
from protocol.net.session import open_session, undeclare_quietly
from protocol.wire.codec import ProtocolError, decode
from protocol.wire.game_messages import GameEvent, GameEventKind, GamePhase, GameState, encode_game, pack_projectiles
from protocol.wire.keys import (
    ALL_ALIVE,
    DEFAULT_TRACKER_ID,
    body_key,
    game_event_key,
    game_state_key,
    pose_key,
    validate_id,
)
from protocol.wire.messages import BodyInfo, PoseFrame
from protocol.wire.validate import RateLimitedLog, StreamClock, check_body_info, check_pose_frame, clamp_count

from .game import GameConfig, GameRecord, GameSnapshot
from .gestures import GestureEvent
from .render import FrameWriter, Renderer, event_line
from .round import GameRound

__all__ = ["AppOptions", "AppResult", "FrameSink", "GameClient", "run_game"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AppOptions:
    """How the live game client runs (see ``mocap-game run --help``)."""

    game_id: str = DEFAULT_TRACKER_ID
    tracker_id: str = DEFAULT_TRACKER_ID
    log_path: Path | None = None
    frames_out: Path | None = None
    frames_fps: float = 10.0  # rendered frames per second of game time with frames_out
    max_frames: int | None = None
    duration: float | None = None
    exit_when_over: bool = False
    follow: bool = False  # follow the first tracker alive (liveliness) and switch when it goes
    state_hz: float = 5.0
    next_round_s: float = 5.0
    poll_s: float = 0.002


@dataclass
class AppResult:
    """What a run did: frames, events, rounds, counters and why it stopped."""

    frames: int = 0
    events: int = 0
    rounds: int = 0
    reason: str = "stopped"
    counters: dict[str, int] = field(default_factory=dict)
    summaries: list[dict[str, Any]] = field(default_factory=list)


class FrameSink:
    """Renders the round into ``out_dir`` at ``fps`` of game time (PNG, GIF, MP4)."""

    def __init__(self, out_dir: Path, config: GameConfig, fps: float = 10.0) -> None:
        self.renderer = Renderer(config)
        self.writer = FrameWriter(Path(out_dir), fps=fps)
        self.lines: list[str] = []
        self.flash: dict[str, float] = {}

    def note(self, t: float, gestures: list[GestureEvent], records: list[GameRecord]) -> None:
        """Remember recent gestures and events for the panel and hit flashes."""
        for e in gestures:
            self.lines.append(f"{t:5.1f} > {e.gesture.value}" + (f" {e.direction}" if e.direction else ""))
        for r in records:
            if r.kind in ("hit", "attack", "dodge", "transform", "round_end"):
                self.lines.append(event_line(r))
            if r.kind == "hit":
                self.flash[r.actor] = r.t + 0.3
        self.lines = self.lines[-8:]

    def maybe_draw(self, snap: GameSnapshot, joints: Any) -> None:
        """Draw and save a frame if one is due at the snapshot's time."""
        if self.writer.due(snap.t):
            flash = {who for who, until in self.flash.items() if snap.t < until}
            self.writer.add(snap.t, self.renderer.draw(snap, joints, self.lines, flash))

    def close(self) -> list[Path]:
        """Finish the GIF and MP4."""
        return self.writer.close()


def _state_message(game_id: str, seq: int, snap: GameSnapshot, stream_ts: float, frames: int,
                   counters: dict[str, int]) -> GameState:
    arr, n = pack_projectiles([(p.kind, p.x, p.y, p.radius, p.width) for p in snap.projectiles])
    return GameState(
        game_id=game_id, seq=clamp_count(seq), t=snap.t, stream_ts=max(stream_ts, 0.0), tick=clamp_count(snap.tick),
        phase=GamePhase(snap.phase),
        round_left_s=snap.round_left_s, player_health=snap.player_health, opponent_health=snap.opponent_health,
        player_x=snap.player_x, player_lane=snap.player_lane,
        player_stance="crouching" if snap.crouching else "standing", opponent_x=snap.opponent_x,
        telegraph=snap.telegraph, projectiles=arr, n_projectiles=n, winner=snap.winner, end_reason=snap.end_reason,
        frames=clamp_count(frames), counters={k: clamp_count(v) for k, v in counters.items()},
    )


def _event_messages(game_id: str, seq: int, res_t: float, stream_ts: float, gestures: list[GestureEvent],
                    records: list[GameRecord]) -> list[GameEvent]:
    out = [GameEvent(game_id=game_id, seq=clamp_count(seq + i), t=res_t, stream_ts=max(stream_ts, 0.0),
                     kind=GameEventKind.GESTURE, actor="player", gesture=e.gesture.value,
                     direction=e.direction or "", start_s=e.start_s, end_s=e.end_s,
                     confidence=min(max(e.confidence, 0.0), 1.0), latency_ms=e.latency_ms)
           for i, e in enumerate(gestures)]
    base = seq + len(out)
    out += [GameEvent(game_id=game_id, seq=clamp_count(base + i), t=r.t, stream_ts=max(stream_ts, 0.0),
                      kind=GameEventKind(r.kind), actor=r.actor, detail=r.detail, value=r.value)
            for i, r in enumerate(records)]
    return out


def _write(fh: IO[str] | None, record: dict[str, Any]) -> None:
    if fh is not None:
        fh.write(json.dumps(record, allow_nan=False) + "\n")



#: How long a query for the tracker's ``BodyInfo`` waits (at the start, after a new stream).
_BODY_QUERY_S = 0.3
_COUNTERS = ("decode_errors", "bad_frames", "tracker_restarts", "dropped_frames", "publish_errors", "invalid_body",
             "invalid_pose")


class GameClient:
    """The live client's message handling, without I/O: feed it payloads, it plays the round.

    Parameters
    ----------
    game_id : str
    options : AppOptions
    game_config : GameConfig
    publish_event, publish_state : callable
        Called with each encoded ``GameEvent`` / ``GameState`` (``Publisher.put``); a
        ``zenoh.ZError`` or ``ProtocolError`` they raise is counted (``publish_errors``).
    result : AppResult, optional
        Where frames, events, rounds and counters are kept.
    log_file : text file, optional
        JSON-lines log.
    sink : FrameSink, optional
    clock : StreamClock, optional
    """

    def __init__(self, game_id: str, options: AppOptions, game_config: GameConfig,
                 publish_event: Callable[[bytes], object], publish_state: Callable[[bytes], object], *,
                 result: AppResult | None = None, log_file: IO[str] | None = None, sink: FrameSink | None = None,
                 clock: StreamClock | None = None) -> None:
        self.gid, self.options, self.gconf = game_id, options, game_config
        self.publish_event, self.publish_state = publish_event, publish_state
        self.result = result if result is not None else AppResult()
        for k in _COUNTERS:
            self.result.counters.setdefault(k, 0)
        self.c = self.result.counters
        self.fh, self.sink = log_file, sink
        self.clock = clock or StreamClock()
        self.warn = RateLimitedLog(log)
        self.height: float | None = None
        self.rnd = GameRound(game_config)
        self.ev_seq = self.st_seq = 0
        self.last_seq: int | None = None
        self.next_state = 0.0
        self.over_at: float | None = None
        self.want_body = True  # ask the tracker's queryable for its BodyInfo (at start, after a new stream)

    def _count(self, key: str, n: int = 1) -> None:
        self.c[key] = clamp_count(self.c.get(key, 0) + n)

    def on_body(self, payload: bytes) -> None:
        """Handle one ``BodyInfo`` payload (the player's height for the next round)."""
        try:
            info = decode(payload, BodyInfo)
        except ProtocolError as exc:
            self._count("decode_errors")
            self.warn("decode_body", "bad body message (%d so far): %s", self.c["decode_errors"], exc)
            return
        reason = check_body_info(info)
        if reason is not None:
            self._count("invalid_body")
            self._count(f"invalid_{reason}")
            self.warn(reason, "implausible body message dropped (%s)", reason)
            return
        self.height = float(info.measurements.get("height_m", 0.0)) or None
        if self.rnd.frames == 0 and self.height:
            self.rnd = GameRound(self.gconf, height_m=self.height)

    def on_pose(self, payload: bytes, now: float | None = None) -> bool:
        """Handle one ``PoseFrame`` payload at local monotonic time ``now``; True when the run
        should end (the round is over and ``exit_when_over``)."""
        try:
            frame = decode(payload, PoseFrame)
        except ProtocolError as exc:
            self._count("decode_errors")
            self.warn("decode_pose", "dropping undecodable pose message (%d so far): %s", self.c["decode_errors"], exc)
            return False
        reason = check_pose_frame(frame)
        verdict = None if reason is not None else self.clock.observe(frame.seq, frame.capture_ts, now)
        if verdict is None or verdict.reason is not None:
            reason = reason if verdict is None else verdict.reason
            self._count("invalid_pose")
            self._count(f"invalid_{reason}")
            self.warn(str(reason), "dropping pose frame %d (%s)", frame.seq, reason)
            return False
        if verdict.restart:
            self._count("tracker_restarts")
            self.want_body = True  # the new stream may track another player: ask for the body
            log.warning("new tracker stream (seq %d, t=%.3f s); the round continues", frame.seq, frame.capture_ts)
            self.rnd.restart_stream()
        elif self.last_seq is not None and frame.seq > self.last_seq + 1:
            self._count("dropped_frames", frame.seq - self.last_seq - 1)
        self.last_seq = frame.seq
        return self._play(frame)

    def _play(self, frame: PoseFrame) -> bool:
        c, result, rnd, gid = self.c, self.result, self.rnd, self.gid
        try:
            res = rnd.feed(frame.capture_ts, frame.joints, frame.visibility, frame.confidence)
        except ValueError as exc:
            self._count("bad_frames")
            self.warn("bad_frame", "dropping bad pose frame %d: %s", frame.seq, exc)
            return False
        result.frames += 1
        for rec in res.log:
            _write(self.fh, rec)
        msgs = _event_messages(gid, self.ev_seq, res.game_t, frame.capture_ts, res.gestures, res.events)
        for m in msgs:
            try:
                self.publish_event(encode_game(m))
            except (zenoh.ZError, ProtocolError) as exc:
                self._count("publish_errors")
                self.warn("publish_event", "could not publish event %d: %s", m.seq, exc)
        self.ev_seq += len(msgs)
        result.events += len(msgs)
        snap = rnd.game.snapshot()
        if self.sink is not None:
            self.sink.note(res.game_t, res.gestures, res.events)
            self.sink.maybe_draw(snap, rnd.last_joints)
        if snap.t >= self.next_state or any(r.kind == "round_end" for r in res.events):
            try:
                self.publish_state(encode_game(_state_message(gid, self.st_seq, snap, frame.capture_ts, result.frames,
                                                              {**c, **rnd.recognizer.counters})))
                self.st_seq += 1
            except (zenoh.ZError, ProtocolError) as exc:
                self._count("publish_errors")
                self.warn("publish_state", "could not publish state: %s", exc)
            self.next_state = snap.t + 1.0 / self.options.state_hz
        if rnd.over:
            if self.over_at is None:
                self.over_at = snap.t
                self._summarise()
                result.rounds += 1
                log.info("round %d over: %s wins by %s", result.rounds, snap.winner, snap.end_reason)
                if self.options.exit_when_over:
                    result.reason = "over"
                    return True
            elif snap.t - self.over_at >= self.options.next_round_s:
                self.rnd, self.over_at, self.next_state = GameRound(self.gconf, height_m=self.height), None, 0.0
        return False

    def _summarise(self) -> None:
        summary = self.rnd.summary()
        summary = {**summary, "round": self.result.rounds, "counters": {**summary["counters"], **self.c}}
        self.result.summaries.append(summary)
        _write(self.fh, summary)

    def finish(self) -> None:
        """Write the summary of a round still running."""
        if not self.rnd.over and self.rnd.frames:
            self._summarise()


def run_game(conf: zenoh.Config, options: AppOptions, stop: threading.Event,
             game_config: GameConfig | None = None) -> AppResult:
    """Run the live game client until a limit is reached or ``stop`` is set.

    Parameters
    ----------
    conf : zenoh.Config
        Session configuration (subscriber role, see :mod:`protocol.net.session`).
    options : AppOptions
    stop : threading.Event
        Set it (e.g. from a signal handler) to end the run.
    game_config : GameConfig, optional

    Returns
    -------
    AppResult

    Raises
    ------
    ConnectionError
        If the zenoh session cannot be opened.
    """
    gid = validate_id(options.game_id)
    tid = validate_id(options.tracker_id, allow_any=True)
    gconf = game_config or GameConfig()
    result = AppResult(counters=dict.fromkeys(_COUNTERS, 0))
    fh = options.log_path.open("w", encoding="utf-8", buffering=1) if options.log_path else None
    sink = FrameSink(options.frames_out, gconf, options.frames_fps) if options.frames_out else None
    t_start = time.monotonic()
    with open_session(conf) as session:
        entities: list[Any] = []
        subs: list[Any] = []
        try:
            asked = -1e9  # when the network was last asked for the trackers alive
            follower = TrackerFollower() if options.follow else None
            live_sub = session.liveliness().declare_subscriber(ALL_ALIVE, history=True) if follower else None
            if live_sub is not None:
                entities.append(live_sub)
            ev_pub = session.declare_publisher(game_event_key(gid))
            st_pub = session.declare_publisher(game_state_key(gid))
            entities += [ev_pub, st_pub]
            client = GameClient(gid, options, gconf, ev_pub.put, st_pub.put, result=result, log_file=fh, sink=sink)

            def follow(tracker: str | None) -> None:
                undeclare_quietly(*subs)
                subs.clear()
                if tracker is not None:
                    subs.extend([session.declare_subscriber(pose_key(tracker)),
                                 session.declare_subscriber(body_key(tracker))])
                    client.want_body = True

            follow(None if follower else tid)
            log.info("game %r listening on %s, publishing on %s and %s", gid,
                     "the first tracker alive" if follower else pose_key(tid), game_event_key(gid),
                     game_state_key(gid))
            while not stop.is_set():
                if options.duration is not None and time.monotonic() - t_start >= options.duration:
                    result.reason = "duration"
                    break
                if options.max_frames is not None and result.frames >= options.max_frames:
                    result.reason = "frames"
                    break
                if follower is not None and live_sub is not None:
                    changed, asked = follow_step(session, live_sub, follower, asked, time.monotonic())
                    if changed:
                        follow(follower.current)
                        result.counters["tracker_switches"] = follower.switches
                if not subs:
                    stop.wait(options.poll_s)
                    continue
                pose_sub, body_sub = subs
                current = follower.current if follower is not None else tid
                body_sample = body_sub.try_recv()
                if body_sample is not None:
                    client.on_body(bytes(body_sample.payload.to_bytes()))
                    client.want_body = False
                elif client.want_body and current not in (None, "*"):  # once at the start and once per new stream
                    client.want_body = False
                    for reply in session.get(body_key(str(current)), timeout=_BODY_QUERY_S):
                        if reply.ok is not None:
                            client.on_body(bytes(reply.ok.payload.to_bytes()))
                sample = pose_sub.try_recv()
                if sample is None:
                    stop.wait(options.poll_s)
                    continue
                if client.on_pose(bytes(sample.payload.to_bytes()), time.monotonic()):
                    break
            client.finish()
        finally:
            undeclare_quietly(*subs)
            undeclare_quietly(*reversed(entities))
            if fh is not None:
                fh.close()
            if sink is not None:
                sink.close()
    log.info("game client stopped (%s): %d frames, %d events, counters %s", result.reason, result.frames,
             result.events, result.counters)
    return result
