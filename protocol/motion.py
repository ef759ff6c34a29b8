"""Pose sequences: the common in-memory form of recordings and gesture scripts, and resampling."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from protocol.formats.bvh import BvhFile, read_bvh
from protocol.formats.retarget import UNITS, artifact_mask, detect_armature, retarget, source_skeleton
from protocol.kinematics import fk
from protocol.rotations import (
    euler_to_matrix,
    matrix_to_quat,
    matrix_to_rotvec,
    quat_slerp,
    quat_to_matrix,
    rotvec_to_matrix,
)
from protocol.skeleton import (
    CAPSULE_INDEX,
    END_JOINTS,
    JOINT_INDEX,
    JOINT_NAMES,
    PARENTS,
    POSE_SIZE,
    ROT_JOINTS,
    Body,
    body_from_measurements,
    default_body,
)

#: Highest frame rate accepted (Hz), matching the shortest BVH ``Frame Time`` read (1e-4 s).
MAX_FPS = 1e4

__all__ = ["MAX_FPS", "Motion", "ground", "is_native", "load_bvh_motion", "resample", "sample_poses"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Motion:
    """A pose sequence on the shared skeleton.

    Attributes
    ----------
    poses : (F, P) float64
        One pose vector per frame (layout in :mod:`protocol.skeleton`).
    fps : float
        Frames per second.
    name : str
        Human-readable name (file stem or script name).
    body : Body
        Body the poses were retargeted for (root height and translation are scaled to it).
    source : str
        Where it came from (path), empty if built in memory.
    valid : (F,) bool
        False for frames flagged as artefacts (glitches, converter T-poses) that a pose database
        should skip; all True unless the reader found some.
    """

    poses: NDArray[np.float64]
    fps: float
    name: str = ""
    body: Body = field(default_factory=default_body)
    source: str = ""
    valid: NDArray[np.bool_] | None = None

    def __post_init__(self) -> None:
        p = np.asarray(self.poses, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != POSE_SIZE:
            raise ValueError(f"poses must be (F, {POSE_SIZE}), got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError("poses contain NaN or inf")
        if not (0 < self.fps <= MAX_FPS):
            raise ValueError(f"{self.source or self.name or 'motion'}: fps must be in (0, {MAX_FPS:g}], got {self.fps}")
        object.__setattr__(self, "poses", p)
        v = np.ones(len(p), dtype=bool) if self.valid is None else np.asarray(self.valid, dtype=bool)
        if v.shape != (len(p),):
            raise ValueError("valid must have one entry per frame")
        object.__setattr__(self, "valid", v)

    @property
    def n_frames(self) -> int:
        return int(self.poses.shape[0])

    @property
    def duration(self) -> float:
        """Seconds from the first to one frame past the last frame."""
        return self.n_frames / self.fps

    @property
    def times(self) -> NDArray[np.float64]:
        """(F,) float64 frame times in seconds, starting at 0."""
        return np.arange(self.n_frames) / self.fps


def resample(motion: Motion, fps: float) -> Motion:
    """Resample to another frame rate: slerp on joint rotations, linear on the root position.

    Parameters
    ----------
    motion : Motion
    fps : float
        Target rate (Hz), > 0.

    Returns
    -------
    Motion
        Same duration; a frame is valid if both source frames around it are.
    """
    if not (0 < fps <= MAX_FPS):
        raise ValueError(f"{motion.source or motion.name or 'motion'}: fps must be in (0, {MAX_FPS:g}], got {fps}")
    if abs(fps - motion.fps) < 1e-9:
        return motion
    n_out = max(1, int(np.floor((motion.n_frames - 1) * fps / motion.fps + 1e-9)) + 1)
    t = np.arange(n_out, dtype=np.float64) * float(motion.fps / fps)  # position in source frames
    poses = sample_poses(motion.poses, t)
    i0 = np.clip(np.floor(t).astype(int), 0, motion.n_frames - 1)
    i1 = np.clip(i0 + 1, 0, motion.n_frames - 1)
    assert motion.valid is not None
    valid = motion.valid[i0] & motion.valid[i1]
    return replace(motion, poses=poses, fps=float(fps), valid=valid)


def sample_poses(poses: NDArray[np.float64], t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Interpolate a pose sequence at fractional frame positions.

    Parameters
    ----------
    poses : (F, P) float
    t : (N,) float
        Positions in frames (clipped to ``[0, F-1]``).

    Returns
    -------
    (N, P) float64
    """
    p = np.asarray(poses, dtype=np.float64)
    t = np.clip(np.asarray(t, dtype=np.float64), 0, len(p) - 1)
    i0 = np.floor(t).astype(int)
    i1 = np.minimum(i0 + 1, len(p) - 1)
    a = t - i0
    out = np.empty((len(t), POSE_SIZE))
    out[:, :3] = (1 - a)[:, None] * p[i0, :3] + a[:, None] * p[i1, :3]
    r0 = p[i0, 3:].reshape(len(t), -1, 3)
    r1 = p[i1, 3:].reshape(len(t), -1, 3)
    q = quat_slerp(matrix_to_quat(rotvec_to_matrix(r0)), matrix_to_quat(rotvec_to_matrix(r1)), a[:, None])
    out[:, 3:] = matrix_to_rotvec(quat_to_matrix(q)).reshape(len(t), -1)
    return out


def ground(poses: NDArray[np.float64], body: Body, percentile: float = 5.0) -> NDArray[np.float64]:
    """Shift the root height so the feet touch the floor (y = 0).

    The lowest foot surface point (ankle/toe minus the foot capsule radius) of each frame is
    computed; its ``percentile`` over frames is moved to 0 (robust to jumps).

    Parameters
    ----------
    poses : (F, P) float
    body : Body
    percentile : float

    Returns
    -------
    (F, P) float64
    """
    p = np.array(poses, dtype=np.float64, copy=True)
    joints = fk(p, body)
    feet = [JOINT_INDEX[n] for n in ("l_ankle", "l_toe", "r_ankle", "r_toe")]
    foot_r = float(body.capsule_radii[CAPSULE_INDEX["l_foot"]].min())
    low = joints[:, feet, 1].min(axis=1) - foot_r
    p[:, 1] -= float(np.percentile(low, percentile))
    return p


def load_bvh_motion(path: str | Path, *, body: Body | None = None, fps: float | None = None,
                    scale: float | None = None, source_fps: float | None = None,
                    keep_artifacts: bool = False) -> Motion:
    """Read a BVH recording and retarget it onto the shared skeleton.

    Parameters
    ----------
    path : str or Path
    body : Body, optional
        Target body (default :func:`~protocol.skeleton.default_body`).
    fps : float, optional
        Resample to this rate.
    scale : float, optional
        File units -> metres (detected when omitted, see :func:`protocol.formats.retarget.source_skeleton`).
    source_fps : float, optional
        The recording's true frame rate when the file's ``Frame Time`` is wrong (known
        converter mistakes of an armature are corrected automatically).
    keep_artifacts : bool
        Keep leading converter frames (T-pose, rest and blend frames) instead of dropping them.

    Returns
    -------
    Motion
    """
    for what, v in (("fps", fps), ("source_fps", source_fps)):
        if v is not None and not (0 < v <= MAX_FPS):
            raise ValueError(f"{path}: {what} must be in (0, {MAX_FPS:g}], got {v}")
    bvh = read_bvh(path)
    if is_native(bvh):
        m = _native_motion(bvh, scale)
        if body is not None:
            m = replace(m, body=body)
        return resample(m, fps) if fps else m
    b = body or default_body()
    arm = detect_armature(bvh.names)
    src_fps = source_fps or arm.stamped_fps_override.get(round(bvh.fps, 3), bvh.fps)
    if src_fps != bvh.fps and source_fps is None:
        log.info("%s: stamped %.3g fps, armature %s is known to be %.3g fps", path, bvh.fps, arm.name, src_fps)
    src = source_skeleton(bvh, arm, scale)
    start, valid = artifact_mask(src.positions, src_fps)
    if keep_artifacts:
        start = 0
    poses = retarget(src, b)[start:]
    poses = ground(poses, b)
    m = Motion(poses=poses, fps=float(src_fps), name=Path(path).stem, body=b, source=str(path), valid=valid[start:])
    return resample(m, fps) if fps else m


def is_native(bvh: BvhFile) -> bool:
    """True if the file was written by :func:`protocol.formats.bvh.write_bvh` for our skeleton (same joint
    names and tree, ZXY channels): it is then read exactly, without retargeting."""
    names = [j.name for j in bvh.joints]
    if names != [n for n in JOINT_NAMES if n not in END_JOINTS]:
        return False
    by_name = {n: k for k, n in enumerate(names)}
    for j in bvh.joints:
        par = PARENTS[JOINT_INDEX[j.name]]
        if (j.parent < 0) != (par < 0) or (par >= 0 and names[j.parent] != JOINT_NAMES[par]):
            return False
        if j.rotation_order != "ZXY":
            return False
    return all(n in by_name for n in ROT_JOINTS)


def _native_motion(bvh: BvhFile, scale: float | None) -> Motion:
    names = [j.name for j in bvh.joints]
    offsets = np.zeros((len(JOINT_NAMES), 3))
    for bj in bvh.joints:
        offsets[JOINT_INDEX[bj.name]] = bj.offset
        if bj.end_site is not None:
            ends = [c for c, par in enumerate(PARENTS) if par == JOINT_INDEX[bj.name] and JOINT_NAMES[c] in END_JOINTS]
            if ends:
                offsets[ends[0]] = bj.end_site
    j = JOINT_INDEX
    leg_u = float(np.linalg.norm(offsets[j["l_knee"]]) + np.linalg.norm(offsets[j["l_ankle"]]))
    s = scale if scale is not None else next((u for _, u in UNITS if 0.6 <= leg_u * u <= 1.05), 0.85 / leg_u)
    offsets *= s
    base = body_from_measurements(float(np.clip(leg_u * s / 0.49, 0.8, 2.3)))
    body = Body("bvh", offsets, base.capsule_radii, dict(base.measurements))
    n = bvh.n_frames
    poses = np.zeros((n, POSE_SIZE))
    root = bvh.joints[0]
    pos_cols = {c: root.channel_start + q for q, c in enumerate(root.channels) if c.endswith("position")}
    for ax, c in enumerate(("Xposition", "Yposition", "Zposition")):
        if c in pos_cols:
            poses[:, ax] = bvh.motion[:, pos_cols[c]] * s
    for k, bj in enumerate(bvh.joints):
        cols = [bj.channel_start + q for q, c in enumerate(bj.channels) if c.endswith("rotation")]
        m = euler_to_matrix(np.radians(bvh.motion[:, cols]), bj.rotation_order)
        slot = ROT_JOINTS.index(names[k])
        poses[:, 3 + 3 * slot: 6 + 3 * slot] = matrix_to_rotvec(m)
    return Motion(poses=poses, fps=bvh.fps, name=Path(bvh.path).stem, body=body, source=bvh.path)
