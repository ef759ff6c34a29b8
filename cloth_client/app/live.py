"""Live cloth client: Zenoh in (``PoseFrame`` + ``BodyInfo``), simulated garment out.

The client subscribes to ``mocap/tracker/<id>/pose`` and ``.../body`` with channel subscribers
(polled with ``try_recv``; no callback entity outlives the session, see :mod:`protocol.net.session`),
asks for the ``BodyInfo`` with a ``get`` until one arrives, then drives a
:class:`~cloth_client.solver.driver.ClothDriver` with every pose. When it falls behind it skips to the
newest pose (the driver interpolates across the gap like a dropped frame). Optionally it renders
frames (PNG directory and/or video) and publishes the cloth vertices on ``mocap/cloth/<id>/mesh``.

Mesh message (msgpack map)
--------------------------
``type`` ``"cloth_mesh"``, ``schema_version`` 1, ``cloth_id``, ``seq`` (0, 1, ...), ``ts`` (Unix
time), ``capture_ts`` (the pose's stream time), ``garment``, ``n_vertices``, ``vertices`` (bytes:
little-endian float32, ``n_vertices x 3``, metres, Y up) and, in the first message and every
:data:`TOPOLOGY_EVERY`-th, ``triangles`` (bytes: little-endian uint32, ``T x 3``).

Malformed messages are counted and logged (rate-limited), never fatal. SIGINT / SIGTERM end the
loop within a poll interval and the session is closed cleanly.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import msgpack
import numpy as np
import zenoh

from cloth_client.avatar.capsules import body_of
from cloth_client.solver.cloth import ClothParams
from cloth_client.solver.driver import ClothDriver
from cloth_client.solver.garment import DEFAULT_PARTICLES, Garment, make_garment
from protocol.net.session import open_session, undeclare_quietly
from protocol.wire.codec import ProtocolError, decode
from protocol.wire.keys import body_key, cloth_mesh_key, pose_key
from protocol.wire.messages import BodyInfo, PoseFrame

__all__ = ["TOPOLOGY_EVERY", "LiveOptions", "LiveResult", "mesh_message", "run_live"]

log = logging.getLogger(__name__)
#: The mesh message carries the triangles in its first message and then every this many messages.
TOPOLOGY_EVERY: Final[int] = 30
_POLL_S: Final[float] = 0.002
_BODY_RETRY_S: Final[float] = 1.0


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
    """Encode one cloth mesh message (layout in the module docstring)."""
    msg: dict[str, Any] = {
        "type": "cloth_mesh", "schema_version": 1, "cloth_id": cloth_id, "seq": int(seq), "ts": time.time(),
        "capture_ts": float(capture_ts), "garment": garment.kind, "n_vertices": len(x),
        "vertices": np.ascontiguousarray(x, dtype="<f4").tobytes(),
    }
    if with_topology:
        msg["triangles"] = np.ascontiguousarray(garment.triangles, dtype="<u4").tobytes()
    return bytes(msgpack.packb(msg, use_bin_type=True))


class _Warn:
    """Log a recurring warning at most once per second (with a count)."""

    def __init__(self) -> None:
        self.last = 0.0
        self.pending = 0

    def __call__(self, text: str, *args: object) -> None:
        self.pending += 1
        now = time.monotonic()
        if now - self.last >= 1.0:
            log.warning(text + " (%d since last report)", *args, self.pending)
            self.last, self.pending = now, 0


def _payload(sample: zenoh.Sample) -> bytes:
    return bytes(sample.payload.to_bytes())


def _decode_body(data: bytes, result: LiveResult, warn: _Warn) -> BodyInfo | None:
    try:
        return decode(data, BodyInfo)
    except ProtocolError as exc:
        result.malformed += 1
        warn("malformed BodyInfo ignored: %s", exc)
        return None


def _query_body(session: zenoh.Session, key: str, result: LiveResult, warn: _Warn) -> BodyInfo | None:
    for reply in session.get(key, timeout=0.5):
        if reply.ok is not None:
            info = _decode_body(_payload(reply.ok), result, warn)
            if info is not None:
                return info
    return None


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


def run_live(conf: zenoh.Config, opts: LiveOptions, stop: threading.Event) -> LiveResult:
    """Run the live client until ``stop`` is set, ``max_frames`` poses were simulated or ``duration``
    seconds passed.

    Parameters
    ----------
    conf : zenoh.Config
    opts : LiveOptions
    stop : threading.Event
        Checked every poll (a few milliseconds).

    Returns
    -------
    LiveResult

    Raises
    ------
    ConnectionError
        If the zenoh session cannot be opened.
    """
    result = LiveResult()
    warn = _Warn()
    t_start = time.monotonic()
    driver: ClothDriver | None = None
    outputs: _Outputs | None = None
    info: BodyInfo | None = None
    with open_session(conf) as session:
        entities: list[Any] = []
        try:
            pose_sub = session.declare_subscriber(pose_key(opts.tracker_id))
            body_sub = session.declare_subscriber(body_key(opts.tracker_id))
            entities += [pose_sub, body_sub]
            publisher = session.declare_publisher(cloth_mesh_key(opts.tracker_id)) if opts.publish_mesh else None
            if publisher is not None:
                entities.append(publisher)
            log.info("cloth client: %s on tracker %r (%s)", opts.garment, opts.tracker_id, pose_key(opts.tracker_id))
            last_query = -np.inf
            while not stop.is_set():
                now = time.monotonic()
                if opts.duration is not None and now - t_start >= opts.duration:
                    result.reason = "duration"
                    break
                if opts.max_frames is not None and result.frames >= opts.max_frames:
                    result.reason = "max_frames"
                    break
                new_info = None
                while (s := body_sub.try_recv()) is not None:
                    new_info = _decode_body(_payload(s), result, warn) or new_info
                if new_info is None and info is None and now - last_query >= _BODY_RETRY_S:
                    last_query = now
                    new_info = _query_body(session, body_key(opts.tracker_id), result, warn)
                if new_info is not None and new_info != info:
                    info = new_info
                    if outputs is not None:
                        outputs.close()
                    body = body_of(info)
                    driver = ClothDriver(body, make_garment(opts.garment, body, opts.particles), opts.params)
                    outputs = _Outputs(opts, driver, publisher)
                    result.body_updates += 1
                    log.info("body %r received: %d-particle %s", info.body_model, driver.garment.n_particles,
                             opts.garment)
                samples = []
                while (s := pose_sub.try_recv()) is not None:
                    samples.append(s)
                if not samples:
                    stop.wait(_POLL_S)
                    continue
                result.skipped_behind += len(samples) - 1
                try:
                    frame = decode(_payload(samples[-1]), PoseFrame)
                except ProtocolError as exc:
                    result.malformed += 1
                    warn("malformed PoseFrame ignored: %s", exc)
                    continue
                if driver is None or outputs is None:
                    continue  # no body yet
                t0 = time.perf_counter()
                stats = driver.feed(np.asarray(frame.pose, dtype=np.float64), float(frame.capture_ts))
                result.sim_wall_s += time.perf_counter() - t0
                if stats is None:
                    continue
                result.frames += 1
                result.resets += int(stats.reset)
                result.max_strain = max(result.max_strain, stats.max_strain)
                result.max_penetration_mm = max(result.max_penetration_mm, 1000.0 * stats.max_penetration)
                outputs.emit(frame, result)
            if not result.reason:
                result.reason = "signal"
        finally:
            if outputs is not None:
                outputs.close()
            undeclare_quietly(*reversed(entities))
    result.wall_s = time.monotonic() - t_start
    log.info("cloth client stopped (%s): %d frames, %d rendered, %d published, %d malformed", result.reason,
             result.frames, result.rendered, result.published, result.malformed)
    return result
