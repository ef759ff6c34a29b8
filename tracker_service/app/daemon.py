"""The tracker daemon (``mocap-tracker run``): frames from a source -> pipeline -> Zenoh.

On one zenoh session it declares, for tracker id ``<id>``:

* ``mocap/tracker/<id>/pose``: one :class:`~protocol.wire.messages.PoseFrame` per tracked frame;
* ``mocap/tracker/<id>/body``: the :class:`~protocol.wire.messages.BodyInfo` of the body model in use,
  put when it changes and answered to every ``get`` (queryable);
* ``mocap/tracker/<id>/status``: a :class:`~protocol.wire.messages.TrackerStatus` about once per second
  (state, fps, per-stage milliseconds, error counters) and a final one with state ``stopped``;
* ``mocap/tracker/<id>/preview``: while somebody subscribes (``mocap-view``), the camera frame with
  the silhouette and skeleton drawn on it, as JPEG, at most :data:`PREVIEW_HZ` a second
  (:class:`~protocol.wire.media.PreviewFrame`);
* a liveliness token ``mocap/tracker/<id>/alive`` while running.

A frame the pipeline cannot use (wrong size, decoding error) is skipped, logged and counted; the
daemon keeps running. SIGINT/SIGTERM stop it within a frame and everything is undeclared in
``finally`` (a callback queryable left declared hangs the interpreter with eclipse-zenoh 1.10).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import zenoh

from protocol.net.session import open_session, undeclare_quietly
from protocol.wire.codec import ProtocolError, encode
from protocol.wire.keys import alive_key, body_key, pose_key, status_key, validate_id
from protocol.wire.media import PreviewFrame, encode_preview, preview_key
from protocol.wire.messages import PoseFrame, TrackerState, TrackerStatus, body_info_from_body
from tracker_service.app.options import RunCommandOptions, RunOptions
from tracker_service.app.replay_daemon import has_subscriber, wait_for_subscriber
from tracker_service.pipeline.process import FrameResult, TrackerConfig, advice, new_state, process_frame
from tracker_service.pipeline.warmup import warm_up
from tracker_service.sources.frame_source import FrameSource
from tracker_service.templates.database import LoadedDatabase
from tracker_service.viz.overlay import draw_overlay, hud_lines

__all__ = ["FrameHook", "RunOptions", "preview_payload", "run_from_options", "run_tracker"]

#: A per-frame hook of the daemon: ``hook(timestamp, frame, result)`` after every frame the source
#: gave (``result`` None: a frame the pipeline could not use), e.g. the overlay video of ``--video``.
FrameHook = Callable[[float, Any, FrameResult | None], None]

log = logging.getLogger(__name__)

_STATE = {"learning": TrackerState.WAITING, "waiting": TrackerState.WAITING,
          "initialising": TrackerState.INITIALISING, "tracking": TrackerState.TRACKING}


#: Preview frames (the camera frame with the overlay) a second at most, while a viewer watches.
PREVIEW_HZ = 10.0
PREVIEW_QUALITY = 80


def preview_payload(tid: str, seq: int, ts: float, frame: Any, camera: Any, res: FrameResult,
                    fps: float | None) -> bytes | None:
    """The encoded :class:`~protocol.wire.media.PreviewFrame` of one frame: the camera frame with the
    silhouette, skeleton and HUD drawn on it (:func:`~tracker_service.viz.overlay.draw_overlay`), as a
    JPEG at :data:`PREVIEW_QUALITY`; None when the JPEG cannot be made. What a watching viewer costs
    the tracker, :data:`PREVIEW_HZ` times a second (``bench/bench_preview.py``).

    Raises
    ------
    ProtocolError
        When the message does not encode (a frame too large for it).
    """
    image = draw_overlay(frame, camera, joints=res.joints, silhouette=res.silhouette,
                         hud=hud_lines(str(res.phase), fps, res.confidence if res.joints is not None else None))
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, PREVIEW_QUALITY])
    if not ok:
        return None
    h, w = image.shape[:2]
    return encode_preview(PreviewFrame(tid, int(seq), float(ts), w, h, buf.tobytes()))


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


def _pose_frame(tid: str, seq: int, ts: float, wall: float, res: FrameResult, body_name: str, estimator: str
                ) -> PoseFrame:
    assert res.pose is not None and res.joints is not None
    now = time.time()
    return PoseFrame(tracker_id=tid, seq=seq, capture_ts=float(ts), publish_ts=now, capture_wall_ts=min(wall, now),
                     pose=res.pose.astype(np.float32), joints=res.joints.astype(np.float32),
                     visibility=np.clip(res.visibility, 0, 1).astype(np.float32),
                     confidence=float(np.clip(res.confidence, 0, 1)), estimator=estimator, body_model=body_name)


class _Run:
    """One run of the daemon: the pipeline state, the counters, the body description and the
    publishers once declared."""

    def __init__(self, tid: str, loaded: LoadedDatabase, config: TrackerConfig, options: RunOptions):
        self.tid = tid
        self.loaded = loaded
        self.config = config
        self.options = options
        self.counters = _Counters()
        self.state = new_state(loaded.body)
        self.body_bytes = encode(body_info_from_body(self.state.body, tid))
        self.body_matched = False  # whether a subscriber matched the body publisher at the last frame
        self.last_preview = -np.inf
        self.t_start = time.monotonic()
        self.seq = 0
        self.advice = ""  # the last advice logged

    def on_body_query(self, query: zenoh.Query) -> None:
        try:
            query.reply(body_key(self.tid), self.body_bytes)
            self.counters.values["body_queries"] += 1
        except Exception as exc:  # zenoh thread: never raise
            log.warning("could not answer body query: %s", exc)

    def status(self, st: TrackerState) -> bytes:
        c = self.counters
        return encode(TrackerStatus(
            tracker_id=self.tid, state=st, ts=time.time(), uptime_s=time.monotonic() - self.t_start, fps=c.fps(),
            frames=c.values["published"], counters=dict(c.values), stage_ms=c.stage_means(),
            estimator=self.config.estimator, body_model=self.state.body.name, advice=advice(self.state),
            camera=self.state.camera_estimate.as_dict() if self.state.camera_estimate is not None else {}))

    def step(self, ts: float, frame: Any, pose_pub: zenoh.Publisher, body_pub: zenoh.Publisher,
             wall: float | None = None) -> FrameResult | None:
        """Process one frame and publish its pose (and the body when it changed); None for a frame
        the pipeline cannot use (skipped and counted). ``wall``: when the frame was got
        (``time.time()``; default now)."""
        wall = time.time() if wall is None else wall
        values = self.counters.values
        values["frames_in"] += 1
        loaded = self.loaded
        try:
            self.state, res = process_frame(self.state, frame, loaded.db, loaded.body, loaded.camera, self.config, ts)
        except ValueError as exc:  # a frame the pipeline cannot use
            values["bad_frames"] += 1
            log.warning("skipping frame %d: %s", values["frames_in"], exc)
            return None
        self.counters.add_stages(res.stage_ms)
        if (said := advice(self.state)) != self.advice:  # what the person should do, in the log too
            if said:
                log.info("%s", said)
            self.advice = said
        self.counters.times.append(time.monotonic())
        if res.reinitialised:
            values["reinitialisations"] += 1
        if res.rejected is not None:  # a pose without grounds: withheld
            values["withheld"] = values.get("withheld", 0) + 1
        matched = has_subscriber(body_pub)
        if res.body_changed:
            values["body_changes"] += 1
            self.body_bytes = encode(body_info_from_body(self.state.body, self.tid))
            body_pub.put(self.body_bytes)
        elif matched and not self.body_matched:  # a first subscriber appeared: it gets the body now
            values["body_republished"] = values.get("body_republished", 0) + 1
            body_pub.put(self.body_bytes)
        self.body_matched = matched
        if res.pose is not None:
            try:
                frame_msg = _pose_frame(self.tid, self.seq, ts, wall, res, self.state.body.name, self.config.estimator)
                pose_pub.put(encode(frame_msg))
                values["published"] += 1
                self.seq += 1
            except zenoh.ZError as exc:
                values["publish_errors"] += 1
                log.warning("publishing failed: %s", exc)
        return res

    def preview(self, ts: float, frame: Any, res: FrameResult, pub: zenoh.Publisher) -> None:
        """Put the frame with the overlay (JPEG, :class:`~protocol.wire.media.PreviewFrame`) when
        somebody watches (a viewer subscribed) and ``1 / PREVIEW_HZ`` passed since the last one."""
        now = time.monotonic()
        if now - self.last_preview < 1.0 / PREVIEW_HZ or not has_subscriber(pub):
            return
        self.last_preview = now
        try:
            payload = preview_payload(self.tid, max(self.seq - 1, 0), ts, frame, self.loaded.camera, res,
                                      self.counters.fps())
            if payload is None:
                return
            pub.put(payload)
            self.counters.values["previews"] = self.counters.values.get("previews", 0) + 1
        except (zenoh.ZError, ProtocolError) as exc:
            self.counters.values["publish_errors"] += 1
            log.warning("preview not published: %s", exc)

    def track(self, source: FrameSource, pose_pub: zenoh.Publisher, body_pub: zenoh.Publisher,
              status_pub: zenoh.Publisher, stop: threading.Event, observe: FrameHook | None = None,
              preview_pub: zenoh.Publisher | None = None) -> None:
        """The frame loop: until the source ends, a limit or ``stop``; ``observe`` is called after
        every frame; ``preview_pub`` gets the frame with the overlay while a viewer watches."""
        options = self.options
        t_run = time.monotonic()  # --duration counts from here
        body_pub.put(self.body_bytes)
        next_status = time.monotonic() + options.status_interval
        period = 1.0 / options.fps_hint  # until the source's own frame interval is known
        prev_ts: float | None = None
        due = time.monotonic()
        for ts, frame in source:
            wall = time.time()  # the frame is here: its capture, as far as the tracker can tell
            if stop.is_set():
                break
            if prev_ts is not None and 0.0 < ts - prev_ts <= 1.0:
                period = ts - prev_ts  # a 25 fps video or a 120 fps recording plays at its own rate
            prev_ts = ts
            res = self.step(ts, frame, pose_pub, body_pub, wall)
            if observe is not None:
                observe(ts, frame, res)
            if res is None:
                continue
            if preview_pub is not None:
                self.preview(ts, frame, res, preview_pub)
            now = time.monotonic()
            if now >= next_status:
                status_pub.put(self.status(_STATE[res.phase]))
                next_status = now + options.status_interval
            if options.max_frames is not None and self.counters.values["frames_in"] >= options.max_frames:
                break
            if options.duration is not None and now - t_run >= options.duration:
                break
            if options.realtime:  # a file or synthetic source is played at its frame rate
                due += period
                if stop.wait(max(0.0, due - time.monotonic())):
                    break
                due = max(due, time.monotonic() - period)
        self.counters.values["bad_frames"] += int(getattr(source, "counters", {}).get("bad_frames", 0))


def run_tracker(source: FrameSource, loaded: LoadedDatabase, config: TrackerConfig, conf: zenoh.Config,
                options: RunOptions, stop: threading.Event, observe: FrameHook | None = None) -> dict[str, int]:
    """Track frames from ``source`` and publish until the source ends, a limit or ``stop``; ``observe``
    (optional) is called after every frame with its time stamp, the frame and the pipeline's result.

    With ``options.warm_up`` the pipeline first runs on a generated clip
    (:func:`~tracker_service.pipeline.warmup.warm_up`) before the Zenoh session opens, so a stop during
    start-up leaves no entity declared and the first real frame compiles nothing.

    Returns
    -------
    dict[str, int]
        Final counters.
    """
    tid = validate_id(options.tracker_id)
    run = _Run(tid, loaded, config, options)
    if options.warm_up:  # compile (first run) or load every kernel before the first real frame
        log.info("warming up the pipeline (the first run after an install compiles its kernels)")
        wu = warm_up(loaded.db, loaded.body, loaded.camera, config, should_stop=stop.is_set)
        log.info("warm-up: %d frames in %.1f s (reached %s)", wu.frames, wu.seconds, wu.phase)
        if stop.is_set():  # stopped during start-up: no session was opened
            source.close()
            return dict(run.counters.values)
    with open_session(conf) as session:
        entities: list[Any] = []
        try:
            pose_pub = session.declare_publisher(pose_key(tid))
            body_pub = session.declare_publisher(body_key(tid))
            status_pub = session.declare_publisher(status_key(tid))
            preview_pub = session.declare_publisher(preview_key(tid))
            entities += [pose_pub, body_pub, status_pub, preview_pub]
            entities.append(session.declare_queryable(body_key(tid), run.on_body_query))
            entities.append(session.liveliness().declare_token(alive_key(tid)))
            status_pub.put(run.status(TrackerState.STARTING))
            log.info("publishing poses of tracker %r on %s (database %s, %d templates)", tid, pose_key(tid),
                     loaded.body.name, loaded.db.n_leaves)
            if options.wait_for_subscriber > 0 and not wait_for_subscriber(pose_pub, options.wait_for_subscriber, stop):
                log.warning("no subscriber after %.1f s; tracking anyway", options.wait_for_subscriber)
            run.track(source, pose_pub, body_pub, status_pub, stop, observe, preview_pub)
            status_pub.put(run.status(TrackerState.STOPPED))
        finally:
            undeclare_quietly(*reversed(entities))
            source.close()
    return dict(run.counters.values)


def run_from_options(options: RunCommandOptions, stop: threading.Event) -> int:
    """``mocap-tracker run``: open the frame source, load the database and the tracker
    configuration, and run :func:`run_tracker` until the source ends, a limit or ``stop`` (set by
    the caller's signal handling). Returns the exit status."""
    from tracker_service.app.resources import DEFAULT_SCRIPT, ensure_db, requested_camera
    from tracker_service.app.tracker_config import tracker_config
    from tracker_service.sources.frame_source import open_source, parse_source

    spec = parse_source(options.source)
    config = tracker_config(options.tracker)
    loaded = ensure_db(options.tracker.db)
    if stop.is_set():
        return 0
    source = open_source(spec, (loaded.camera.width, loaded.camera.height), default_motion=DEFAULT_SCRIPT,
                         seed=options.seed, camera=requested_camera(options.tracker), fps=options.fps,
                         prerender=options.prerender)
    try:
        conf = options.zenoh.config()
    except BaseException:
        source.close()
        raise
    if stop.is_set():
        source.close()
        return 0
    if options.video is None:
        counters = run_tracker(source, loaded, config, conf, options.daemon, stop)
    else:
        from tracker_service.viz.overlay import OverlayVideo

        fps = float(getattr(source, "fps", 0.0) or options.daemon.fps_hint)
        try:
            video = OverlayVideo(options.video, loaded.camera, fps)
        except BaseException:
            source.close()
            raise
        with video:
            counters = run_tracker(source, loaded, config, conf, options.daemon, stop,
                                   lambda _ts, frame, res: video(frame, res))
        log.info("wrote the overlay of %d frames to %s", video.frames, options.video)
    log.info("tracker stopped: %s", counters)
    return 0
