"""The tracker daemon (``mocap-tracker run``): frames from a source -> pipeline -> Zenoh.

On one zenoh session it declares, for tracker id ``<id>``:

* ``mocap/tracker/<id>/pose``: one :class:`~protocol.wire.messages.PoseFrame` per tracked frame;
* ``mocap/tracker/<id>/body``: the :class:`~protocol.wire.messages.BodyInfo` of the body model in use,
  put when it changes and answered to every ``get`` (queryable);
* ``mocap/tracker/<id>/status``: a :class:`~protocol.wire.messages.TrackerStatus` about once per second
  (state, fps, per-stage milliseconds, error counters) and a final one with state ``stopped``;
* a liveliness token ``mocap/tracker/<id>/alive`` while running.

A frame the pipeline cannot use (wrong size, decoding error) is skipped, logged and counted; the
daemon keeps running. SIGINT/SIGTERM stop it within a frame and everything is undeclared in
``finally`` (a callback queryable left declared hangs the interpreter with eclipse-zenoh 1.10).
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from protocol.net.session import config_from_args, open_session, undeclare_quietly
from protocol.wire.codec import encode
from protocol.wire.keys import alive_key, body_key, pose_key, status_key, validate_id
from protocol.wire.messages import PoseFrame, TrackerState, TrackerStatus, body_info_from_body
from tracker_service.app.replay_daemon import wait_for_subscriber
from tracker_service.pipeline.process import FrameResult, TrackerConfig, new_state, process_frame
from tracker_service.pipeline.warmup import warm_up
from tracker_service.sources.frame_source import FrameSource
from tracker_service.templates.database import LoadedDatabase

__all__ = ["RunOptions", "run_tracker"]

log = logging.getLogger(__name__)

_STATE = {"learning": TrackerState.WAITING, "waiting": TrackerState.WAITING,
          "initialising": TrackerState.INITIALISING, "tracking": TrackerState.TRACKING}


@dataclass(frozen=True)
class RunOptions:
    """Daemon options: id, frame limit, duration, status period, real-time pacing, and whether to
    warm the pipeline up (:mod:`tracker_service.pipeline.warmup`) before the first real frame."""

    tracker_id: str = "default"
    max_frames: int | None = None
    duration: float | None = None
    status_interval: float = 1.0
    realtime: bool = True
    fps_hint: float = 30.0
    wait_for_subscriber: float = 0.0
    warm_up: bool = True


@dataclass
class _Counters:
    values: dict[str, int] = field(default_factory=lambda: {
        "frames_in": 0, "bad_frames": 0, "published": 0, "publish_errors": 0, "reinitialisations": 0,
        "body_queries": 0, "body_changes": 0})
    stage: dict[str, deque[float]] = field(default_factory=dict)
    times: deque[float] = field(default_factory=lambda: deque(maxlen=120))

    def add_stages(self, ms: dict[str, float]) -> None:
        for k, v in ms.items():
            self.stage.setdefault(k, deque(maxlen=120)).append(v)

    def stage_means(self) -> dict[str, float]:
        return {k: round(float(np.mean(v)), 3) for k, v in self.stage.items() if v}

    def fps(self) -> float:
        if len(self.times) < 2:
            return 0.0
        span = self.times[-1] - self.times[0]
        return (len(self.times) - 1) / span if span > 0 else 0.0


def _pose_frame(tid: str, seq: int, ts: float, res: FrameResult, body_name: str) -> PoseFrame:
    assert res.pose is not None and res.joints is not None
    return PoseFrame(tracker_id=tid, seq=seq, capture_ts=float(ts), publish_ts=time.time(),
                     pose=res.pose.astype(np.float32), joints=res.joints.astype(np.float32),
                     visibility=np.clip(res.visibility, 0, 1).astype(np.float32),
                     confidence=float(np.clip(res.confidence, 0, 1)), estimator="tree", body_model=body_name)


def run_tracker(source: FrameSource, loaded: LoadedDatabase, config: TrackerConfig, conf: zenoh.Config,
                options: RunOptions, stop: threading.Event) -> dict[str, int]:
    """Track frames from ``source`` and publish until the source ends, a limit or ``stop``.

    With ``options.warm_up`` the pipeline first runs on a generated clip
    (:func:`~tracker_service.pipeline.warmup.warm_up`) before the Zenoh session opens, so a stop during
    start-up leaves no entity declared and the first real frame compiles nothing.

    Returns
    -------
    dict[str, int]
        Final counters.
    """
    tid = validate_id(options.tracker_id)
    counters = _Counters()
    state = new_state(loaded.body)
    body_bytes = [encode(body_info_from_body(state.body, tid))]
    t_start = time.monotonic()

    def on_body_query(query: zenoh.Query) -> None:
        try:
            query.reply(body_key(tid), body_bytes[0])
            counters.values["body_queries"] += 1
        except Exception as exc:  # zenoh thread: never raise
            log.warning("could not answer body query: %s", exc)

    def status(st: TrackerState) -> bytes:
        return encode(TrackerStatus(
            tracker_id=tid, state=st, ts=time.time(), uptime_s=time.monotonic() - t_start, fps=counters.fps(),
            frames=counters.values["published"], counters=dict(counters.values), stage_ms=counters.stage_means(),
            estimator="tree", body_model=state.body.name))

    if options.warm_up:  # compile (first run) or load every kernel before the first real frame
        log.info("warming up the pipeline (the first run after an install compiles its kernels)")
        wu = warm_up(loaded.db, loaded.body, loaded.camera, config, should_stop=stop.is_set)
        log.info("warm-up: %d frames in %.1f s (reached %s)", wu.frames, wu.seconds, wu.phase)
        if stop.is_set():  # stopped during start-up: no session was opened
            source.close()
            return dict(counters.values)
    with open_session(conf) as session:
        entities: list[Any] = []
        try:
            pose_pub = session.declare_publisher(pose_key(tid))
            body_pub = session.declare_publisher(body_key(tid))
            status_pub = session.declare_publisher(status_key(tid))
            entities += [pose_pub, body_pub, status_pub]
            entities.append(session.declare_queryable(body_key(tid), on_body_query))
            entities.append(session.liveliness().declare_token(alive_key(tid)))
            status_pub.put(status(TrackerState.STARTING))
            log.info("publishing poses of tracker %r on %s (database %s, %d templates)", tid, pose_key(tid),
                     loaded.body.name, loaded.db.n_leaves)
            if options.wait_for_subscriber > 0 and not wait_for_subscriber(pose_pub, options.wait_for_subscriber, stop):
                log.warning("no subscriber after %.1f s; tracking anyway", options.wait_for_subscriber)
            t_run = time.monotonic()  # --duration counts from here
            body_pub.put(body_bytes[0])
            next_status = time.monotonic() + options.status_interval
            seq = 0
            period = 1.0 / options.fps_hint
            due = time.monotonic()
            for ts, frame in source:
                if stop.is_set():
                    break
                counters.values["frames_in"] += 1
                try:
                    state, res = process_frame(state, frame, loaded.db, loaded.body, loaded.camera, config, ts)
                except ValueError as exc:  # a frame the pipeline cannot use
                    counters.values["bad_frames"] += 1
                    log.warning("skipping frame %d: %s", counters.values["frames_in"], exc)
                    continue
                counters.add_stages(res.stage_ms)
                counters.times.append(time.monotonic())
                if res.reinitialised:
                    counters.values["reinitialisations"] += 1
                if res.body_changed:
                    counters.values["body_changes"] += 1
                    body_bytes[0] = encode(body_info_from_body(state.body, tid))
                    body_pub.put(body_bytes[0])
                if res.pose is not None:
                    try:
                        pose_pub.put(encode(_pose_frame(tid, seq, ts, res, state.body.name)))
                        counters.values["published"] += 1
                        seq += 1
                    except zenoh.ZError as exc:
                        counters.values["publish_errors"] += 1
                        log.warning("publishing failed: %s", exc)
                now = time.monotonic()
                if now >= next_status:
                    status_pub.put(status(_STATE[res.phase]))
                    next_status = now + options.status_interval
                if options.max_frames is not None and counters.values["frames_in"] >= options.max_frames:
                    break
                if options.duration is not None and now - t_run >= options.duration:
                    break
                if options.realtime:  # a file or synthetic source is played at its frame rate
                    due += period
                    if stop.wait(max(0.0, due - time.monotonic())):
                        break
                    due = max(due, time.monotonic() - period)
            counters.values["bad_frames"] += int(getattr(source, "counters", {}).get("bad_frames", 0))
            status_pub.put(status(TrackerState.STOPPED))
        finally:
            undeclare_quietly(*reversed(entities))
            source.close()
    return dict(counters.values)


def run_tracker_cli(args: argparse.Namespace, loaded: LoadedDatabase, config: TrackerConfig,
                    source: FrameSource, stop: threading.Event) -> int:
    """Wire ``mocap-tracker run`` arguments to :func:`run_tracker` (zenoh config; ``stop`` is set by
    the caller's signal handling)."""
    conf = config_from_args(args, "publisher")
    opts = RunOptions(tracker_id=args.id, max_frames=args.frames, duration=args.duration,
                      realtime=not args.as_fast_as_possible, wait_for_subscriber=args.wait_for_subscriber)
    if stop.is_set():
        source.close()
        return 0
    counters = run_tracker(source, loaded, config, conf, opts, stop)
    log.info("tracker stopped: %s", counters)
    return 0
