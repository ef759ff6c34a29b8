"""Replay core: turn a :class:`~protocol.motion.Motion` into the ``PoseFrame`` stream a tracker sends.

Pure functions and a small precomputing class; no clock, no I/O, no zenoh (the wiring lives in
:mod:`tracker_service.app.replay_daemon`).

Timing model
------------
Output frame ``k`` (``k = 0, 1, 2, ...``, continuous across loops) is stamped with stream time
``capture_ts = k / rate`` and shows source frame ``floor(k * fps / rate) mod F`` (nearest-earlier
frame, "hold"), where ``fps`` is the motion's frame rate, ``F`` its frame count and ``rate`` the
output rate (default ``fps``). At ``rate == fps`` this is frame ``k mod F`` at its own time plus one
motion duration per completed loop, and ``seq == k``. Smooth resampling (interpolating
rotations) belongs in :func:`protocol.formats.load.load_motion`; this module only maps frame indices.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Final

import numpy as np
from numpy.typing import NDArray

from protocol.kinematics import fk
from protocol.motion import Motion
from protocol.skeleton import N_PARTS, ROT_JOINTS, Body, default_body, standing_pose
from protocol.wire.messages import BodyInfo, PoseFrame, body_info_from_body

__all__ = [
    "ESTIMATOR",
    "ReplayStream",
    "frames_per_pass",
    "replay_body_info",
    "source_indices",
    "synthetic_wave_motion",
]

#: ``PoseFrame.estimator`` of replayed frames.
ESTIMATOR: Final[str] = "replay"
# Tolerance on k * fps / rate so that exact ratios (30 -> 30 Hz, 30 -> 60 Hz) never round down.
_EPS: Final[float] = 1e-6


def _check_rate(rate: float, what: str = "rate") -> float:
    r = float(rate)
    if not (r > 0 and math.isfinite(r)):
        raise ValueError(f"{what} must be a positive number, got {rate}")
    return r


def frames_per_pass(n_src: int, src_fps: float, rate: float) -> int:
    """Number of output frames one pass through a motion takes at ``rate``.

    Parameters
    ----------
    n_src : int
        Source frames ``F`` (>= 1).
    src_fps, rate : float
        Source and output frame rates, Hz.

    Returns
    -------
    int
        ``ceil(F * rate / fps)`` (up to rounding noise); ``F`` when ``rate == fps``.
    """
    if n_src < 1:
        raise ValueError("a motion needs at least one frame")
    fps, r = _check_rate(src_fps, "source fps"), _check_rate(rate)
    return max(1, math.ceil((n_src - _EPS) * r / fps))


def source_indices(
    k: NDArray[np.int64] | int, n_src: int, src_fps: float, rate: float, *, loop: bool = True
) -> NDArray[np.int64]:
    """Source frame shown by each output frame ``k`` (hold / nearest-earlier mapping).

    Parameters
    ----------
    k : int or (N,) int64
        Output frame numbers, >= 0.
    n_src : int
        Source frames ``F``.
    src_fps, rate : float
        Source and output frame rates, Hz.
    loop : bool
        Wrap around modulo ``F``; otherwise indices past the end are clamped to ``F - 1``.

    Returns
    -------
    (N,) int64
        Indices in ``[0, F)`` (a 0-d array for scalar ``k``).
    """
    fps, r = _check_rate(src_fps, "source fps"), _check_rate(rate)
    kk = np.asarray(k, dtype=np.int64)
    if np.any(kk < 0):
        raise ValueError("output frame numbers must be >= 0")
    raw = np.floor(kk * (fps / r) + _EPS).astype(np.int64)
    return raw % n_src if loop else np.minimum(raw, n_src - 1)


def replay_body_info(motion: Motion, tracker_id: str) -> BodyInfo:
    """The ``BodyInfo`` announced for a replay: the motion's body under ``tracker_id``."""
    return body_info_from_body(motion.body, tracker_id)


class ReplayStream:
    """Precomputed replay of one motion: pose frames by output frame number.

    Parameters
    ----------
    motion : Motion
        Poses ``(F, P)`` float64 at ``motion.fps``; joints are computed once with
        :func:`protocol.fk` for ``motion.body``.
    tracker_id : str
        Id stamped into every frame.
    rate : float, optional
        Output rate in Hz (default: ``motion.fps``).
    loop : bool
        Repeat the motion forever (seq and capture time keep increasing).

    Attributes
    ----------
    poses : (F, P) float32
    joints : (F, J, 3) float32
        World joint positions, metres.
    rate : float
    loop : bool
    n_frames : int or None
        Output frames in total; ``None`` when looping.
    """

    def __init__(self, motion: Motion, tracker_id: str, *, rate: float | None = None, loop: bool = False):
        self.motion = motion
        self.tracker_id = tracker_id
        self.rate = _check_rate(motion.fps if rate is None else rate)
        self.loop = bool(loop)
        self.poses: NDArray[np.float32] = motion.poses.astype(np.float32)
        self.joints: NDArray[np.float32] = fk(motion.poses, motion.body).astype(np.float32)
        self._visibility = np.ones(N_PARTS, dtype=np.float32)
        self.frames_per_pass = frames_per_pass(motion.n_frames, motion.fps, self.rate)

    @property
    def n_frames(self) -> int | None:
        """Total output frames, or ``None`` when looping (endless)."""
        return None if self.loop else self.frames_per_pass

    @property
    def body_model(self) -> str:
        """Name of the motion's body, stamped into each frame."""
        return self.motion.body.name

    def body_info(self) -> BodyInfo:
        """``BodyInfo`` for this stream's tracker id and body."""
        return replay_body_info(self.motion, self.tracker_id)

    def capture_ts(self, k: int) -> float:
        """Stream time of output frame ``k``, seconds (``k / rate``)."""
        return k / self.rate

    def source_index(self, k: int) -> int:
        """Source frame shown by output frame ``k``."""
        return int(source_indices(k, self.motion.n_frames, self.motion.fps, self.rate, loop=self.loop))

    def loop_count(self, k: int) -> int:
        """How many complete passes precede output frame ``k``."""
        return k // self.frames_per_pass

    def frame(self, k: int, publish_ts: float = 0.0) -> PoseFrame:
        """Output frame ``k`` as a ``PoseFrame`` (``seq == k``).

        Parameters
        ----------
        k : int
            Output frame number, ``0 <= k < n_frames`` (any ``k >= 0`` when looping).
        publish_ts : float
            Wall-clock publication time, seconds since the epoch (filled in by the publisher).

        Returns
        -------
        PoseFrame
            ``pose (P,) float32``, ``joints (J, 3) float32``, visibility all 1, confidence 1.
        """
        if k < 0 or (self.n_frames is not None and k >= self.n_frames):
            raise IndexError(f"frame {k} outside 0..{self.n_frames}")
        i = self.source_index(k)
        return PoseFrame(
            tracker_id=self.tracker_id,
            seq=k,
            capture_ts=self.capture_ts(k),
            publish_ts=float(publish_ts),
            capture_wall_ts=float(publish_ts),  # a replay has no camera: captured as published
            pose=self.poses[i],
            joints=self.joints[i],
            visibility=self._visibility,
            confidence=1.0,
            estimator=ESTIMATOR,
            body_model=self.body_model,
        )

    def frames(self, max_frames: int | None = None) -> Iterator[PoseFrame]:
        """Iterate over the output frames (``publish_ts`` left at 0).

        Parameters
        ----------
        max_frames : int, optional
            Stop after this many frames (required to end a looping stream).
        """
        total = self.n_frames
        if max_frames is not None:
            total = max_frames if total is None else min(total, max_frames)
        k = 0
        while total is None or k < total:
            yield self.frame(k)
            k += 1


def synthetic_wave_motion(
    seconds: float = 4.0, fps: float = 30.0, *, wave_hz: float = 1.0, body: Body | None = None
) -> Motion:
    """A built-in self-test motion: standing still and waving the right arm overhead.

    Needs no files, so tests and ``--synthetic-wave`` work on any machine.

    Parameters
    ----------
    seconds : float
        Length of the motion.
    fps : float
        Frame rate, Hz.
    wave_hz : float
        Waves per second (the forearm swings side to side once per period).
    body : Body, optional
        Default :func:`protocol.skeleton.default_body`.

    Returns
    -------
    Motion
        ``poses (round(seconds * fps), P) float64`` named ``"synthetic-wave"``.
    """
    b = body or default_body()
    n = max(1, round(_check_rate(seconds, "seconds") * _check_rate(fps, "fps")))
    t = np.arange(n) / fps
    poses = np.tile(standing_pose(b), (n, 1))
    rot = poses[:, 3:].reshape(n, len(ROT_JOINTS), 3)
    # raise the right upper arm from hanging (80 deg about +Z) to ~60 deg above horizontal
    raise_amt = np.clip(t / 0.5, 0.0, 1.0)
    rot[:, ROT_JOINTS.index("r_shoulder"), 2] = np.radians(80.0 - 140.0 * raise_amt)
    # bend the right elbow and swing the forearm side to side
    swing = np.sin(2 * np.pi * wave_hz * t) * raise_amt
    elbow = rot[:, ROT_JOINTS.index("r_elbow"), :]
    elbow *= (1.0 - raise_amt)[:, None]
    elbow[:, 2] += raise_amt * np.radians(-45.0 + 35.0 * swing)
    return Motion(poses=poses, fps=float(fps), name="synthetic-wave", body=b, source="built-in")
