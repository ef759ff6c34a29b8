"""Replay publisher: stream a recorded or scripted motion over Zenoh as if a tracker saw it live.

This is the I/O edge around :mod:`tracker_service.app.replay`. On one zenoh session it declares

* a publisher on ``mocap/tracker/<id>/pose`` (one :class:`~protocol.wire.messages.PoseFrame` per frame),
* a publisher and a queryable on ``mocap/tracker/<id>/body`` (the ``BodyInfo`` is put once when
  streaming starts and sent as the reply to every ``get``),
* a publisher on ``mocap/tracker/<id>/status`` (a ``TrackerStatus`` about once per second and a
  final one with state ``stopped``),
* a liveliness token on ``mocap/tracker/<id>/alive``.

Frames are paced on a monotonic clock against an absolute schedule (frame ``k`` is due at
``start + k / rate``), so timing errors do not accumulate. If the process falls more than
``max_burst`` frames behind, the schedule is moved forward instead of bursting to catch up; every
frame is still sent, ``seq`` stays continuous, and the ``clock_resyncs`` counter says it happened.

SIGINT and SIGTERM set a stop event; the loop notices within one wait and everything is
undeclared in ``finally`` (a still-declared callback queryable would hang the interpreter at exit
with eclipse-zenoh 1.10). A requested shutdown exits with status 0.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from protocol.formats.load import load_motion
from protocol.motion import Motion
from protocol.net.session import open_session, stop_on_signals, undeclare_quietly
from protocol.wire.codec import encode
from protocol.wire.keys import alive_key, body_key, pose_key, status_key, validate_id
from protocol.wire.messages import TrackerState, TrackerStatus
from tracker_service.app.options import ReplayCommandOptions, ReplayOptions
from tracker_service.app.replay import ESTIMATOR, ReplayStream, synthetic_wave_motion

__all__ = ["ReplayOptions", "ReplayResult", "load_replay_motion", "publish_motion", "run_replay"]

log = logging.getLogger(__name__)


@dataclass
class ReplayResult:
    """What a replay did.

    Attributes
    ----------
    frames : int
        Frames published.
    elapsed_s : float
        Seconds from the first frame to the end.
    reason : str
        ``"end"`` (motion finished), ``"frames"``, ``"duration"`` or ``"stopped"`` (signal).
    counters : dict[str, int]
        ``body_queries``, ``clock_resyncs``, ``loops``, ``publish_errors``.
    """

    frames: int = 0
    elapsed_s: float = 0.0
    reason: str = "stopped"
    counters: dict[str, int] = field(default_factory=dict)


def load_replay_motion(options: ReplayCommandOptions) -> Motion:
    """Load the motion chosen by ``--bvh``, ``--script`` or ``--synthetic-wave``.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If it cannot be read.
    NotImplementedError
        While :func:`protocol.formats.load.load_motion` does not support the format yet.
    """
    if options.synthetic_wave:
        return synthetic_wave_motion(seconds=4.0, fps=30.0)
    if not options.motion:
        raise ValueError("choose a motion with --bvh FILE, --script FILE or --synthetic-wave")
    path = Path(options.motion)
    if not path.is_file():
        raise FileNotFoundError(f"motion file not found: {path}")
    return load_motion(path)


class _Status:
    """Counters and the once-per-interval ``TrackerStatus`` (thread-safe counters)."""

    def __init__(self, stream: ReplayStream, t0: float):
        self.stream = stream
        self.t0 = t0
        self.lock = threading.Lock()
        self.counters = {"body_queries": 0, "clock_resyncs": 0, "loops": 0, "publish_errors": 0}
        self.frames = 0
        self._last_t = t0
        self._last_frames = 0
        self._publish_s = 0.0

    def bump(self, name: str, n: int = 1) -> None:
        with self.lock:
            self.counters[name] += n

    def published(self, seconds: float) -> None:
        self.frames += 1
        self._publish_s += seconds

    def message(self, state: TrackerState, now: float) -> TrackerStatus:
        dt = max(now - self._last_t, 1e-9)
        n = self.frames - self._last_frames
        stage = {"publish": 1000.0 * self._publish_s / n} if n else {}
        self._last_t, self._last_frames, self._publish_s = now, self.frames, 0.0
        with self.lock:
            counters = dict(self.counters)
        return TrackerStatus(
            tracker_id=self.stream.tracker_id, state=state, ts=time.time(), uptime_s=now - self.t0,
            fps=n / dt, frames=self.frames, counters=counters, stage_ms=stage,
            estimator=ESTIMATOR, body_model=self.stream.body_model,
        )


def has_subscriber(pub: zenoh.Publisher) -> bool:
    """Whether a subscriber matches ``pub`` now."""
    # eclipse-zenoh 1.10's stub says ``matching_status -> bool`` but it returns a MatchingStatus
    # object, which is always truthy; the answer is its ``.matching``.
    status: Any = pub.matching_status
    return bool(getattr(status, "matching", status))


def wait_for_subscriber(pub: zenoh.Publisher, seconds: float, stop: threading.Event) -> bool:
    """Wait up to ``seconds`` for a subscriber matching ``pub``; True if one is there."""
    deadline = time.monotonic() + seconds
    while not stop.is_set() and time.monotonic() < deadline:
        if has_subscriber(pub):
            return True
        stop.wait(0.01)
    return has_subscriber(pub)


def publish_motion(
    motion: Motion, conf: zenoh.Config, options: ReplayOptions, stop: threading.Event
) -> ReplayResult:
    """Publish ``motion`` on a new zenoh session until it ends, a limit is reached or ``stop`` is set.

    Parameters
    ----------
    motion : Motion
    conf : zenoh.Config
        Session configuration (see :mod:`protocol.net.session`).
    options : ReplayOptions
    stop : threading.Event
        Set it (e.g. from a signal handler) to end the replay; checked at least once per frame.

    Returns
    -------
    ReplayResult

    Raises
    ------
    ConnectionError
        If the session cannot be opened (e.g. the listen port is taken).
    """
    tid = validate_id(options.tracker_id)
    stream = ReplayStream(motion, tid, rate=options.rate, loop=options.loop)
    total = stream.n_frames
    if options.max_frames is not None:
        total = options.max_frames if total is None else min(total, options.max_frames)
    body_bytes = encode(stream.body_info())
    status = _Status(stream, time.monotonic())
    result = ReplayResult()
    bkey = body_key(tid)

    def on_body_query(query: zenoh.Query) -> None:
        try:
            query.reply(bkey, body_bytes)
            status.bump("body_queries")
        except Exception as exc:  # runs on a zenoh thread: never let it raise
            log.warning("could not answer body query: %s", exc)

    with open_session(conf) as session:
        entities: list[Any] = []
        try:
            pose_pub = session.declare_publisher(pose_key(tid))
            body_pub = session.declare_publisher(bkey)
            status_pub = session.declare_publisher(status_key(tid))
            entities += [pose_pub, body_pub, status_pub]
            entities.append(session.declare_queryable(bkey, on_body_query))
            entities.append(session.liveliness().declare_token(alive_key(tid)))
            log.info(
                "publishing %r (%d frames at %g fps) as tracker %r on %s at %g Hz%s; listen=%s connect=%s",
                motion.name, motion.n_frames, motion.fps, tid, pose_key(tid), stream.rate,
                " looping" if stream.loop else "", conf.get_json("listen/endpoints"),
                conf.get_json("connect/endpoints"),
            )
            if options.wait_for_subscriber > 0:
                status_pub.put(encode(status.message(TrackerState.WAITING, time.monotonic())))
                if not wait_for_subscriber(pose_pub, options.wait_for_subscriber, stop):
                    log.warning("no subscriber after %.1f s; publishing anyway", options.wait_for_subscriber)
            body_pub.put(body_bytes)
            _run_frames(stream, pose_pub, status_pub, status, options, total, stop, result)
            status_pub.put(encode(status.message(TrackerState.STOPPED, time.monotonic())))
        finally:
            undeclare_quietly(*reversed(entities))
    result.frames = status.frames
    result.counters = dict(status.counters)
    log.info("replay ended (%s): %d frames in %.2f s", result.reason, result.frames, result.elapsed_s)
    return result


def _run_frames(
    stream: ReplayStream,
    pose_pub: zenoh.Publisher,
    status_pub: zenoh.Publisher,
    status: _Status,
    options: ReplayOptions,
    total: int | None,
    stop: threading.Event,
    result: ReplayResult,
) -> None:
    """The paced publishing loop (absolute schedule on ``time.monotonic``)."""
    period = 1.0 / stream.rate
    start = anchor = time.monotonic()
    next_status = start + options.status_interval
    k = 0
    while True:
        if total is not None and k >= total:
            result.reason = "frames" if stream.n_frames is None or total < stream.n_frames else "end"
            break
        due = anchor + k * period
        if options.duration is not None and due - start >= options.duration - 1e-9:
            result.reason = "duration"
            break
        now = time.monotonic()
        if now >= next_status:
            status_pub.put(encode(status.message(TrackerState.TRACKING, now)))
            next_status = max(next_status + options.status_interval, now)
        if now < due:
            if stop.wait(min(due, next_status) - now):
                break
            continue
        if stop.is_set():
            break
        if now - due > options.max_burst * period:  # fell behind: move the schedule, don't burst
            anchor += now - due
            status.bump("clock_resyncs")
        if k > 0 and k % stream.frames_per_pass == 0:
            status.bump("loops")
        t_pub = time.perf_counter()
        try:
            pose_pub.put(encode(stream.frame(k, publish_ts=time.time())))
        except zenoh.ZError as exc:
            status.bump("publish_errors")
            log.warning("publishing frame %d failed: %s", k, exc)
        status.published(time.perf_counter() - t_pub)
        k += 1
    result.elapsed_s = time.monotonic() - start


def run_replay(options: ReplayCommandOptions) -> int:
    """``mocap-tracker replay``: load the motion, publish it, return an exit code.

    Returns
    -------
    int
        0 when the replay ended normally or was stopped by SIGINT/SIGTERM.
    """
    with stop_on_signals(threading.Event()) as stop:  # first, so an early Ctrl-C is clean too
        motion = load_replay_motion(options)
        conf = options.zenoh.config()
        if not stop.is_set():
            publish_motion(motion, conf, options.publish, stop)
    return 0
