"""The game client's I/O edge: pose frames in over Zenoh, game events and state out, log and frames.

On one zenoh session it declares

* a channel subscriber on ``mocap/tracker/<tracker>/pose`` (``PoseFrame``) and one on
  ``.../body`` (``BodyInfo``, for the player's height),
* publishers on ``mocap/game/<id>/event`` (one ``GameEvent`` per recognised gesture and game
  event) and ``mocap/game/<id>/state`` (``GameState`` at ``state_hz`` of game time).

Every frame is fed to a :class:`~game_client.round.GameRound`; the round's records go to the JSON-lines
log, and with ``frames_out`` rendered frames are written (PNG, GIF, MP4). Payloads that do not
decode are counted (``decode_errors``) and logged, never fatal; a tracker restart (sequence or
time going backwards) is counted and the round continues. Channel subscribers are used (a callback
subscriber still declared at exit hangs eclipse-zenoh 1.10), everything is undeclared in
``finally``, and the loop checks its stop event at least every few milliseconds, so SIGINT/SIGTERM
end the process well within 2 s. After a round ends a new one starts ``next_round_s`` later.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import zenoh

from protocol.net.session import open_session, undeclare_quietly
from protocol.wire.codec import ProtocolError, decode
from protocol.wire.game_messages import GameEvent, GameEventKind, GamePhase, GameState, encode_game, pack_projectiles
from protocol.wire.keys import DEFAULT_TRACKER_ID, body_key, game_event_key, game_state_key, pose_key, validate_id
from protocol.wire.messages import BodyInfo, PoseFrame

from .game import GameConfig, GameRecord, GameSnapshot
from .gestures import GestureEvent
from .render import FrameWriter, Renderer, event_line
from .round import GameRound

__all__ = ["AppOptions", "AppResult", "FrameSink", "run_game"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AppOptions:
    """How the live game client runs (see ``mocap-game run --help``)."""

    game_id: str = DEFAULT_TRACKER_ID
    tracker_id: str = DEFAULT_TRACKER_ID
    log_path: Path | None = None
    frames_out: Path | None = None
    max_frames: int | None = None
    duration: float | None = None
    exit_when_over: bool = False
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
        game_id=game_id, seq=seq, t=snap.t, stream_ts=max(stream_ts, 0.0), tick=snap.tick, phase=GamePhase(snap.phase),
        round_left_s=snap.round_left_s, player_health=snap.player_health, opponent_health=snap.opponent_health,
        player_x=snap.player_x, player_lane=snap.player_lane,
        player_stance="crouching" if snap.crouching else "standing", opponent_x=snap.opponent_x,
        telegraph=snap.telegraph, projectiles=arr, n_projectiles=n, winner=snap.winner, end_reason=snap.end_reason,
        frames=frames, counters={k: int(v) for k, v in counters.items()},
    )


def _event_messages(game_id: str, seq: int, res_t: float, stream_ts: float, gestures: list[GestureEvent],
                    records: list[GameRecord]) -> list[GameEvent]:
    out = [GameEvent(game_id=game_id, seq=seq + i, t=res_t, stream_ts=max(stream_ts, 0.0),
                     kind=GameEventKind.GESTURE, actor="player", gesture=e.gesture.value,
                     direction=e.direction or "", start_s=e.start_s, end_s=e.end_s,
                     confidence=min(max(e.confidence, 0.0), 1.0), latency_ms=e.latency_ms)
           for i, e in enumerate(gestures)]
    base = seq + len(out)
    out += [GameEvent(game_id=game_id, seq=base + i, t=r.t, stream_ts=max(stream_ts, 0.0), kind=GameEventKind(r.kind),
                      actor=r.actor, detail=r.detail, value=r.value) for i, r in enumerate(records)]
    return out


def _write(fh: IO[str] | None, record: dict[str, Any]) -> None:
    if fh is not None:
        fh.write(json.dumps(record, allow_nan=False) + "\n")


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
    result = AppResult(counters=dict.fromkeys(
        ("decode_errors", "bad_frames", "tracker_restarts", "dropped_frames", "publish_errors"), 0))
    c = result.counters
    fh = options.log_path.open("w", encoding="utf-8", buffering=1) if options.log_path else None
    sink = FrameSink(options.frames_out, gconf) if options.frames_out else None
    height: float | None = None
    rnd = GameRound(gconf)
    ev_seq = st_seq = 0
    last_seq: int | None = None
    last_ts = -1.0
    next_state = 0.0
    over_at: float | None = None
    t_start = time.monotonic()
    with open_session(conf) as session:
        entities: list[Any] = []
        try:
            pose_sub = session.declare_subscriber(pose_key(tid))
            body_sub = session.declare_subscriber(body_key(tid))
            ev_pub = session.declare_publisher(game_event_key(gid))
            st_pub = session.declare_publisher(game_state_key(gid))
            entities += [pose_sub, body_sub, ev_pub, st_pub]
            log.info("game %r listening on %s, publishing on %s and %s", gid, pose_key(tid), game_event_key(gid),
                     game_state_key(gid))
            while not stop.is_set():
                if options.duration is not None and time.monotonic() - t_start >= options.duration:
                    result.reason = "duration"
                    break
                if options.max_frames is not None and result.frames >= options.max_frames:
                    result.reason = "frames"
                    break
                body_sample = body_sub.try_recv()
                if body_sample is not None:
                    try:
                        info = decode(body_sample.payload.to_bytes(), BodyInfo)
                        height = float(info.measurements.get("height_m", 0.0)) or None
                        if rnd.frames == 0 and height:
                            rnd = GameRound(gconf, height_m=height)
                    except ProtocolError as exc:
                        c["decode_errors"] += 1
                        log.warning("bad body message (%d so far): %s", c["decode_errors"], exc)
                sample = pose_sub.try_recv()
                if sample is None:
                    stop.wait(options.poll_s)
                    continue
                try:
                    frame = decode(sample.payload.to_bytes(), PoseFrame)
                except ProtocolError as exc:
                    c["decode_errors"] += 1
                    if c["decode_errors"] <= 10 or c["decode_errors"] % 100 == 0:
                        log.warning("dropping undecodable pose message (%d so far): %s", c["decode_errors"], exc)
                    continue
                if last_seq is not None:
                    if frame.seq <= last_seq or frame.capture_ts < last_ts:
                        c["tracker_restarts"] += 1
                        log.warning("tracker restarted (seq %d after %d); the round continues", frame.seq, last_seq)
                    elif frame.seq > last_seq + 1:
                        c["dropped_frames"] += frame.seq - last_seq - 1
                last_seq, last_ts = frame.seq, frame.capture_ts
                try:
                    res = rnd.feed(frame.capture_ts, frame.joints, frame.visibility, frame.confidence)
                except ValueError as exc:
                    c["bad_frames"] += 1
                    log.warning("dropping bad pose frame %d: %s", frame.seq, exc)
                    continue
                result.frames += 1
                for rec in res.log:
                    _write(fh, rec)
                msgs = _event_messages(gid, ev_seq, res.game_t, frame.capture_ts, res.gestures, res.events)
                for m in msgs:
                    try:
                        ev_pub.put(encode_game(m))
                    except (zenoh.ZError, ProtocolError) as exc:
                        c["publish_errors"] += 1
                        log.warning("could not publish event %d: %s", m.seq, exc)
                ev_seq += len(msgs)
                result.events += len(msgs)
                snap = rnd.game.snapshot()
                if sink is not None:
                    sink.note(res.game_t, res.gestures, res.events)
                    sink.maybe_draw(snap, rnd.last_joints)
                if snap.t >= next_state or any(r.kind == "round_end" for r in res.events):
                    try:
                        st_pub.put(encode_game(_state_message(gid, st_seq, snap, frame.capture_ts, result.frames,
                                                              {**c, **rnd.recognizer.counters})))
                        st_seq += 1
                    except (zenoh.ZError, ProtocolError) as exc:
                        c["publish_errors"] += 1
                        log.warning("could not publish state: %s", exc)
                    next_state = snap.t + 1.0 / options.state_hz
                if rnd.over:
                    if over_at is None:
                        over_at = snap.t
                        summary = rnd.summary()
                        summary = {**summary, "round": result.rounds, "counters": {**summary["counters"], **c}}
                        result.summaries.append(summary)
                        _write(fh, summary)
                        result.rounds += 1
                        log.info("round %d over: %s wins by %s", result.rounds, snap.winner, snap.end_reason)
                        if options.exit_when_over:
                            result.reason = "over"
                            break
                    elif snap.t - over_at >= options.next_round_s:
                        rnd, over_at, next_state = GameRound(gconf, height_m=height), None, 0.0
            if not rnd.over and rnd.frames:
                summary = rnd.summary()
                summary = {**summary, "round": result.rounds, "counters": {**summary["counters"], **c}}
                result.summaries.append(summary)
                _write(fh, summary)
        finally:
            undeclare_quietly(*reversed(entities))
            if fh is not None:
                fh.close()
            if sink is not None:
                sink.close()
    log.info("game client stopped (%s): %d frames, %d events, counters %s", result.reason, result.frames,
             result.events, c)
    return result
