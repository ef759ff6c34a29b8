"""Live cloth client: Zenoh in (``PoseFrame`` + ``BodyInfo``), simulated garment out.

The client subscribes to ``mocap/tracker/<id>/pose`` and ``.../body`` with channel subscribers
(polled with ``try_recv``; no callback entity outlives the session, see :mod:`protocol.net.session`),
asks for the ``BodyInfo`` with a ``get`` until one arrives, then drives a
:class:`~cloth_client.solver.driver.ClothDriver` with every pose: it simulates every pose received
since its last look, in order, and renders / publishes the newest of each batch, so the view runs
at what the machine allows and the simulation misses no pose. Only poses more than
:data:`MAX_BACKLOG_S` behind the newest are skipped (the driver interpolates across the gap like a
dropped frame), so a client slower than real time catches up. Optionally it renders frames (PNG
directory and/or video) and publishes the cloth vertices on ``mocap/cloth/<id>/mesh``.

Mesh message
------------
:class:`protocol.wire.media.ClothMesh` (layout there); the first message and every
:data:`TOPOLOGY_EVERY`-th carry the triangles.

Input checks and bounds
-----------------------
Malformed messages are counted and logged (rate-limited), never fatal. Decoded messages are then
checked by meaning (:mod:`protocol.wire.validate`): a ``BodyInfo`` of implausible scale (a 1.7 mm
or a 170 m body) or whose garment cannot be built or simulated within the substep bound is
dropped and the current body kept; a ``PoseFrame`` with out-of-range positions, rotations or
joints, or that does not fit the stream's clock (far-future or stale stamps, seq jumps;
:class:`~protocol.wire.validate.StreamClock`) is dropped before it reaches the solver. Each
drop is counted per reason in :attr:`LiveResult.counters` (``invalid_<reason>``) and logged at
most once per reason per 5 s.

The solver does not see the stream's time: :class:`ClothClient` keeps its own simulation clock,
advanced by each accepted frame's time step. A step longer than the driver's ``max_gap_s``, and
the first frame of a new stream (a tracker restart, its time back at 0), advance it by just over
``max_gap_s``, which the driver bridges with a smooth reset (a fixed ``reset_blend_s`` of
simulation), so a restart is followed from the new stream's first confirmed frames and no frame
asks for more than :data:`MAX_SUBSTEPS_PER_FRAME` substeps (a garment that would need more is
refused). Each simulated frame's wall time is measured against :data:`STEP_BUDGET_S`; after
:data:`OVER_BUDGET_LIMIT` consecutive overruns the cloth is switched off (``sim_disabled``) until
another body arrives, so the loop keeps polling and SIGINT / SIGTERM end it within a poll
interval or one bounded step; the session is closed cleanly.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import zenoh

from cloth_client.avatar.capsules import body_of
from cloth_client.solver.cloth import ClothParams
from cloth_client.solver.driver import ClothDriver
from cloth_client.solver.garment import DEFAULT_PARTICLES, Garment, make_garment
from protocol.net.follow import TrackerFollower, follow_step
from protocol.net.session import open_session, undeclare_quietly
from protocol.skeleton import default_body, standing_pose
from protocol.wire.codec import ProtocolError, decode
from protocol.wire.keys import ALL_ALIVE, body_key, cloth_mesh_key, pose_key
from protocol.wire.media import ClothMesh, encode_cloth_mesh
from protocol.wire.messages import BodyInfo, PoseFrame
from protocol.wire.validate import RateLimitedLog, StreamClock, check_body_info, check_pose_frame

__all__ = ["MAX_BACKLOG_S", "MAX_SUBSTEPS_PER_FRAME", "OVER_BUDGET_LIMIT", "STEP_BUDGET_S", "TOPOLOGY_EVERY",
           "ClothClient", "LiveOptions", "LiveResult", "mesh_message", "run_live", "warm_up"]

log = logging.getLogger(__name__)
#: The mesh message carries the triangles in its first message and then every this many messages.
TOPOLOGY_EVERY: Final[int] = 30
_POLL_S: Final[float] = 0.002
_BODY_RETRY_S: Final[float] = 1.0
#: Most substeps one received frame may cost (a garment whose stable substep needs more for the
#: longest bridged step is refused).
MAX_SUBSTEPS_PER_FRAME: Final[int] = 256
#: Wall-clock budget of one simulated frame, seconds.
STEP_BUDGET_S: Final[float] = 2.0
#: Poses further behind the newest received than this (stream seconds) are skipped, not simulated:
#: a client slower than real time catches up instead of falling further behind. 1.5 s outlasts a
#: new body's garment and avatar build (~0.6 s, three times in the demo's round as the tracker
#: chooses the body and reads its proportions), which 0.5 s turned into 47 skipped poses of 421 at
#: 28 frames a second; the solver's 2-2.5x real time catches such a backlog up within a second.
MAX_BACKLOG_S: Final[float] = 1.5
#: Consecutive frames over budget after which the cloth is switched off until another body arrives.
OVER_BUDGET_LIMIT: Final[int] = 3


@dataclass(frozen=True)
class LiveOptions:
    """What :func:`run_live` does (see ``mocap-cloth run --help``)."""

    tracker_id: str
    garment: str = "cape"
    particles: int = DEFAULT_PARTICLES
    frames_out: Path | None = None
    video: Path | None = None
    video_fps: float = 30.0
    size: tuple[int, int] = (480, 480)
    publish_mesh: bool = False
    max_frames: int | None = None
    duration: float | None = None
    params: ClothParams | None = None
    follow: bool = False  # follow the first tracker alive (liveliness) instead of tracker_id
    warm_up: bool = True  # run the solver on a standing default body before the session opens


@dataclass
class LiveResult:
    """Counters of a live run (all JSON-ready)."""

    frames: int = 0
    rendered: int = 0
    published: int = 0
    skipped_behind: int = 0
    malformed: int = 0
    body_updates: int = 0
    resets: int = 0
    max_strain: float = 0.0
    max_penetration_mm: float = 0.0
    sim_wall_s: float = 0.0
    wall_s: float = 0.0
    reason: str = ""
    counters: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["realtime_load"] = round(self.sim_wall_s / self.wall_s, 3) if self.wall_s > 0 else 0.0
        return d


def mesh_message(cloth_id: str, seq: int, capture_ts: float, garment: Garment, x: np.ndarray,
                 with_topology: bool) -> bytes:
    """Encode one cloth mesh message (:mod:`protocol.wire.media`)."""
    return encode_cloth_mesh(ClothMesh(cloth_id, int(seq), time.time(), float(capture_ts), garment.kind,
                                       np.asarray(x, np.float32),
                                       np.asarray(garment.triangles, np.uint32) if with_topology else None))


class _Outputs:
    """Renderer, frame/video writers and mesh publisher of one garment (rebuilt with the body)."""

    def __init__(self, opts: LiveOptions, driver: ClothDriver, publisher: Any) -> None:
        self.opts, self.driver, self.publisher = opts, driver, publisher
        self.renderer: Any = None
        self.writers: list[Any] = []
        self.next_render = -np.inf
        if opts.frames_out is not None or opts.video is not None:
            from cloth_client.app.render import ClothRenderer, FrameWriter

            self.renderer = ClothRenderer(driver.body, driver.garment, *opts.size,
                                          limb_clearance=driver.config.limb_clearance)
            self.writers = [FrameWriter(p, opts.video_fps) for p in (opts.frames_out, opts.video) if p is not None]

    def emit(self, frame: PoseFrame, result: LiveResult) -> None:
        state = self.driver.state
        assert state is not None
        if self.renderer is not None and frame.capture_ts >= self.next_render:
            rgb = self.renderer.render(np.asarray(frame.pose, dtype=np.float64), state.x, self.driver.body_capsules)
            for w in self.writers:
                w.write(rgb)
            result.rendered += 1
            self.next_render = max(self.next_render + 1.0 / self.opts.video_fps, frame.capture_ts)
        if self.publisher is not None:
            topo = result.published % TOPOLOGY_EVERY == 0
            self.publisher.put(mesh_message(self.opts.tracker_id, result.published, frame.capture_ts,
                                            self.driver.garment, state.x, topo))
            result.published += 1

    def close(self) -> None:
        for w in self.writers:
            w.close()
        if self.renderer is not None:
            self.renderer.close()


def _payload(sample: zenoh.Sample) -> bytes:
    return bytes(sample.payload.to_bytes())


DriverFactory = Callable[[BodyInfo, LiveOptions], ClothDriver]


def _make_driver(info: BodyInfo, opts: LiveOptions) -> ClothDriver:
    body = body_of(info)
    return ClothDriver(body, make_garment(opts.garment, body, opts.particles), opts.params)


def substep_bound(driver: ClothDriver) -> int:
    """Most substeps one frame can cost with ``driver``: its longest bridged step (``max_gap_s``,
    or a reset's ``reset_blend_s``) over its smallest substep."""
    model = getattr(driver, "model", None)
    if model is None:
        return 1
    cfg = driver.config
    longest = max(cfg.continuity.max_gap_s, cfg.reset_blend_s, cfg.dress_s / max(1, round(cfg.dress_s / cfg.frame_dt)))
    sub = min(model.params.max_substep_dt, model.stable_dt)
    if not (math.isfinite(sub) and sub > 0.0):
        return 2**31
    return max(math.ceil(longest / sub - 1e-9), int(model.params.max_substeps), 1)


class ClothClient:
    """The live cloth client's message handling, without I/O: feed it payloads, it drives the cloth.

    Parameters
    ----------
    opts : LiveOptions
    result : LiveResult, optional
    publisher : object with ``put(bytes)``, optional
        Mesh publisher.
    driver_factory : callable, optional
        ``(BodyInfo, LiveOptions) -> ClothDriver`` (default: the options' garment on the body).
    clock : StreamClock, optional
    """

    def __init__(self, opts: LiveOptions, result: LiveResult | None = None, publisher: Any = None,
                 driver_factory: DriverFactory | None = None, clock: StreamClock | None = None) -> None:
        self.opts = opts
        self.result = result if result is not None else LiveResult()
        self.publisher = publisher
        self.factory = driver_factory or _make_driver
        self.clock = clock or StreamClock()
        self.warn = RateLimitedLog(log)
        self.info: BodyInfo | None = None
        self.driver: ClothDriver | None = None
        self.outputs: _Outputs | None = None
        self.sim_t: float | None = None  # the solver's clock (not the stream's)
        self.last_ts = 0.0
        self.over_budget = 0
        self.want_body = True  # ask the tracker's queryable for its BodyInfo (at start, after a new stream)
        self.waiting: list[tuple[PoseFrame, float]] = []  # accepted before there was a cape to move

    def _count(self, key: str, n: int = 1) -> None:
        self.result.counters[key] = self.result.counters.get(key, 0) + n

    def _drop(self, reason: str, what: str) -> None:
        self._count(f"invalid_{reason}")
        self.warn(reason, "%s dropped (%s)", what, reason)

    def decode_body(self, data: bytes) -> BodyInfo | None:
        """A decoded, plausible ``BodyInfo`` or None (counted and logged)."""
        try:
            info = decode(data, BodyInfo)
        except ProtocolError as exc:
            self.result.malformed += 1
            self.warn("decode_body", "malformed BodyInfo ignored: %s", exc)
            return None
        reason = check_body_info(info)
        if reason is not None:
            self._drop(reason, "implausible BodyInfo")
            return None
        return info

    def on_body(self, data: bytes) -> bool:
        """Handle one ``BodyInfo`` payload; True if the garment was (re)built on it."""
        info = self.decode_body(data)
        return info is not None and self.set_body(info)

    def set_body(self, info: BodyInfo) -> bool:
        """Dress a new garment on ``info`` (already checked) unless it is the current body; True if
        done. A garment that cannot be built, or would need more than ``MAX_SUBSTEPS_PER_FRAME``
        substeps a frame, is refused and the current one kept."""
        if info == self.info and self.driver is not None:
            return False
        try:
            driver = self.factory(info, self.opts)
        except (ValueError, ArithmeticError, FloatingPointError) as exc:
            self._drop("garment_failed", f"BodyInfo {info.body_model!r} ({exc})")
            return False
        n = substep_bound(driver)
        if n > MAX_SUBSTEPS_PER_FRAME:
            self._drop("garment_substeps", f"BodyInfo {info.body_model!r} ({n} substeps a frame)")
            return False
        if self.outputs is not None:
            self.outputs.close()
            self.outputs = None
        self.info, self.driver, self.over_budget = info, driver, 0
        self.sim_t = None  # a new cape starts its own clock; poses that waited for it are timed on it
        self.waiting = [(frame, self._advance(float(frame.capture_ts), False)) for frame, _ in self.waiting]
        self.outputs = _Outputs(self.opts, driver, self.publisher)
        self.result.body_updates += 1
        log.info("body %r received: %d-particle %s", info.body_model, driver.garment.n_particles, self.opts.garment)
        return True

    def accept(self, data: bytes, now: float | None = None) -> tuple[PoseFrame, float] | None:
        """Decode and check one ``PoseFrame`` payload against the stream clock; ``(frame, sim_t)``
        with the frame's time on the solver's clock, or None (counted and logged)."""
        try:
            frame = decode(data, PoseFrame)
        except ProtocolError as exc:
            self.result.malformed += 1
            self.warn("decode_pose", "malformed PoseFrame ignored: %s", exc)
            return None
        reason = check_pose_frame(frame)
        if reason is not None:
            self._drop(reason, f"PoseFrame {frame.seq}")
            return None
        verdict = self.clock.observe(frame.seq, frame.capture_ts, now)
        if verdict.reason is not None:
            self._drop(verdict.reason, f"PoseFrame {frame.seq}")
            return None
        ts = float(frame.capture_ts)
        if verdict.restart:
            self._count("tracker_restarts")
            self.want_body = True  # the new stream may track another body: ask for it
            log.warning("new tracker stream (seq %d, t=%.3f s): the cloth follows it", frame.seq, ts)
        return frame, self._advance(ts, verdict.new_stream)

    def _advance(self, ts: float, new_stream: bool) -> float:
        """The solver's clock at a pose stamped ``ts`` (stream seconds): it follows the stream, and
        a new stream or a gap longer than the driver's continuity allows is a jump past that gap."""
        if self.sim_t is None:
            self.sim_t = 0.0
        else:
            dt = ts - self.last_ts
            gap = self.driver.config.continuity.max_gap_s if self.driver is not None else 0.5
            self.sim_t += 1.01 * gap + 1e-3 if new_stream or dt > gap else max(dt, 0.0)
        self.last_ts = ts
        return self.sim_t

    def on_poses(self, payloads: list[bytes], now: float | None = None) -> bool:
        """Handle the pose payloads received since the last call (oldest first): each goes through
        the checks and the clock, and every accepted one within :data:`MAX_BACKLOG_S` of the newest
        is simulated, in order; only the last is rendered and published (the view runs at what the
        machine allows, the simulation misses no pose). Older ones are skipped (counted as
        ``skipped_behind``; the driver interpolates across the gap like a dropped frame). Poses that
        come before the body are kept (within the same window) for its first look. Never more than
        ``max_frames`` in all. True if a frame was simulated."""
        accepted = self.waiting + [got for data in payloads if (got := self.accept(data, now)) is not None]
        if not accepted:
            return False  # nothing usable
        newest = accepted[-1][0].capture_ts
        keep = [g for g in accepted if newest - g[0].capture_ts <= MAX_BACKLOG_S]
        self.result.skipped_behind += len(accepted) - len(keep)
        if self.driver is None or self.outputs is None:  # no body yet: kept for when it comes
            self.waiting = keep
            return False
        self.waiting = []
        if self.opts.max_frames is not None:  # a batch never runs past --max-frames
            keep = keep[: max(0, self.opts.max_frames - self.result.frames)]
        stepped = False
        for i, (frame, sim_t) in enumerate(keep):
            if self.driver is None:  # switched off over its budget
                break
            stepped = self.simulate(frame, sim_t, emit=i == len(keep) - 1) or stepped
        return stepped

    def simulate(self, frame: PoseFrame, sim_t: float, emit: bool = True) -> bool:
        """Advance the cloth to ``frame`` at ``sim_t`` (solver clock); True if a step was taken.
        ``emit``: render and publish this frame (the newest of a batch)."""
        driver, outputs, result = self.driver, self.outputs, self.result
        assert driver is not None and outputs is not None
        t0 = time.perf_counter()
        stats = driver.feed(np.asarray(frame.pose, dtype=np.float64), sim_t)
        wall = time.perf_counter() - t0
        result.sim_wall_s += wall
        if wall > STEP_BUDGET_S:
            self.over_budget += 1
            self._count("sim_over_budget")
            self.warn("sim_over_budget", "cloth step took %.2f s (budget %.2f s)", wall, STEP_BUDGET_S)
            if self.over_budget >= OVER_BUDGET_LIMIT:
                self._count("sim_disabled")
                log.error("cloth switched off: %d steps in a row over the %.1f s budget; waiting for another body",
                          self.over_budget, STEP_BUDGET_S)
                outputs.close()
                self.driver = self.outputs = None
                self.info = None
        else:
            self.over_budget = 0
        if stats is None:
            return False
        result.frames += 1
        result.resets += int(stats.reset)
        result.max_strain = max(result.max_strain, stats.max_strain)
        result.max_penetration_mm = max(result.max_penetration_mm, 1000.0 * stats.max_penetration)
        if self.outputs is not None and emit:
            self.outputs.emit(frame, result)
        return True

    def close(self) -> None:
        if self.outputs is not None:
            self.outputs.close()
            self.outputs = None


def _same_body(a: BodyInfo, b: BodyInfo) -> bool:
    """Whether two ``BodyInfo`` describe the same skeleton (a re-queried body changes nothing)."""
    return (a.body_model == b.body_model and np.array_equal(a.offsets, b.offsets)
            and np.array_equal(a.capsule_radii, b.capsule_radii))


def _query_body(session: zenoh.Session, key: str, client: ClothClient) -> BodyInfo | None:
    for reply in session.get(key, timeout=0.5):
        if reply.ok is not None:
            info = client.decode_body(_payload(reply.ok))
            if info is not None:
                return info
    return None


def warm_up(opts: LiveOptions, should_stop: Callable[[], bool] = lambda: False) -> float:
    """Compile (the first run after an install) or load every solver kernel before the first pose:
    the garment dressed on the default body standing still, a few frames. Without it the first
    received pose would wait for the compilation (about a minute on a fresh install, 2 cores busy)
    while the poses pile up. Returns the seconds it took."""
    t0 = time.monotonic()
    body = default_body()
    driver = ClothDriver(body, make_garment(opts.garment, body, min(opts.particles, DEFAULT_PARTICLES)), opts.params)
    pose = standing_pose(body)
    for k in range(3):
        if should_stop():
            break
        driver.feed(pose, k / 30.0)
    return time.monotonic() - t0


def run_live(conf: zenoh.Config, opts: LiveOptions, stop: threading.Event) -> LiveResult:
    """Run the live client until ``stop`` is set, ``max_frames`` poses were simulated or ``duration``
    seconds passed.

    Parameters
    ----------
    conf : zenoh.Config
    opts : LiveOptions
    stop : threading.Event
        Checked every poll (a few milliseconds) and after every (bounded) simulated frame.

    Returns
    -------
    LiveResult

    Raises
    ------
    ConnectionError
        If the zenoh session cannot be opened.
    """
    result = LiveResult()
    if opts.warm_up:
        log.info("warming up the cloth solver (the first run after an install compiles its kernels)")
        log.info("warm-up: %.1f s", warm_up(opts, stop.is_set))
        if stop.is_set():
            result.reason = "signal"
            return result
    t_start = time.monotonic()
    client: ClothClient | None = None
    with open_session(conf) as session:
        entities: list[Any] = []
        subs: list[Any] = []
        try:
            asked = -1e9  # when the network was last asked for the trackers alive
            follower = TrackerFollower() if opts.follow else None
            live_sub = session.liveliness().declare_subscriber(ALL_ALIVE, history=True) if follower else None
            if live_sub is not None:
                entities.append(live_sub)
            publisher = session.declare_publisher(cloth_mesh_key(opts.tracker_id)) if opts.publish_mesh else None
            if publisher is not None:
                entities.append(publisher)
            client = ClothClient(opts, result, publisher)
            tracker: str | None = None

            def follow(tid: str | None) -> None:
                undeclare_quietly(*subs)
                subs.clear()
                if tid is not None:
                    subs.extend([session.declare_subscriber(pose_key(tid)), session.declare_subscriber(body_key(tid))])
                    assert client is not None
                    client.want_body = True

            tracker = None if follower else opts.tracker_id
            follow(tracker)
            where = "the first tracker alive" if follower else f"tracker {opts.tracker_id!r}"
            log.info("cloth client: %s on %s", opts.garment, where)
            last_query = -np.inf
            while not stop.is_set():
                now = time.monotonic()
                if opts.duration is not None and now - t_start >= opts.duration:
                    result.reason = "duration"
                    break
                if opts.max_frames is not None and result.frames >= opts.max_frames:
                    result.reason = "max_frames"
                    break
                if follower is not None and live_sub is not None:
                    changed, asked = follow_step(session, live_sub, follower, asked, time.monotonic())
                    if changed:
                        tracker = follower.current
                        follow(tracker)
                        result.counters["tracker_switches"] = follower.switches
                if not subs or tracker is None:
                    stop.wait(_POLL_S)
                    continue
                pose_sub, body_sub = subs
                new_info = None
                while (s := body_sub.try_recv()) is not None:
                    new_info = client.decode_body(_payload(s)) or new_info
                ask = client.driver is None or client.want_body
                if new_info is None and ask and now - last_query >= _BODY_RETRY_S:
                    last_query = now
                    client.want_body = False  # once per new stream; without a body, every second
                    new_info = _query_body(session, body_key(tracker), client)
                if new_info is not None:
                    if client.info is None or not _same_body(client.info, new_info):
                        client.set_body(new_info)
                payloads = []
                while (s := pose_sub.try_recv()) is not None:
                    payloads.append(_payload(s))
                if not payloads:
                    stop.wait(_POLL_S)
                    continue
                client.on_poses(payloads, time.monotonic())
            if not result.reason:
                result.reason = "signal"
        finally:
            if client is not None:
                client.close()
            undeclare_quietly(*subs)
            undeclare_quietly(*reversed(entities))
    result.wall_s = time.monotonic() - t_start
    log.info("cloth client stopped (%s): %d frames, %d rendered, %d published, %d malformed", result.reason,
             result.frames, result.rendered, result.published, result.malformed)
    return result
