"""Forward kinematics of the shared skeleton, vectorised over a batch of poses."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.rotations import rotvec_to_matrix
from protocol.skeleton import N_JOINTS, PARENTS, POSE_SIZE, ROT_SLOT, Body

__all__ = ["fk", "fk_global", "pose_batch"]

_CHUNK = 256


def pose_batch(poses: ArrayLike) -> tuple[NDArray[np.float64], bool]:
    """``poses`` as a C-contiguous ``(N, P)`` float64 batch, and whether it was one ``(P,)`` pose.

    Raises
    ------
    ValueError
        Any other shape.
    """
    p = np.ascontiguousarray(poses, dtype=np.float64)
    single = p.ndim == 1
    if single:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != POSE_SIZE:
        raise ValueError(f"poses must have shape (N, {POSE_SIZE}), got {np.shape(poses)}")
    return p, single


def fk_global(poses: ArrayLike, body: Body) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Joint positions and global joint orientations.

    Parameters
    ----------
    poses : (N, P) or (P,) float
        Pose vectors (layout in :mod:`protocol.skeleton`).
    body : Body
        Rest offsets of the skeleton.

    Returns
    -------
    joints : (N, J, 3) float64
        World positions, metres (``(J, 3)`` for a single pose).
    rotations : (N, J, 3, 3) float64
        Global orientation of each joint's frame (end joints inherit their parent's).
    """
    p, single = pose_batch(poses)
    n = p.shape[0]
    if n > _CHUNK:  # cache-sized blocks: ~3x faster than one pass over a large batch
        parts = [fk_global(p[i: i + _CHUNK], body) for i in range(0, n, _CHUNK)]
        return np.concatenate([a for a, _ in parts]), np.concatenate([b for _, b in parts])
    local = rotvec_to_matrix(p[:, 3:].reshape(n, -1, 3))  # (N, R, 3, 3)
    pos = np.empty((n, N_JOINTS, 3))
    rot = np.empty((n, N_JOINTS, 3, 3))
    pos[:, 0] = p[:, :3]
    rot[:, 0] = local[:, 0]
    off = body.offsets
    for j in range(1, N_JOINTS):
        par = PARENTS[j]
        pos[:, j] = pos[:, par] + rot[:, par] @ off[j]
        slot = ROT_SLOT[j]
        rot[:, j] = rot[:, par] @ local[:, slot] if slot >= 0 else rot[:, par]
    if single:
        return pos[0], rot[0]
    return pos, rot


def fk(poses: ArrayLike, body: Body) -> NDArray[np.float64]:
    """Joint positions of a batch of poses.

    Parameters
    ----------
    poses : (N, P) or (P,) float
    body : Body

    Returns
    -------
    (N, J, 3) float64
        World joint positions in metres (``(J, 3)`` for a single pose).
    """
    return fk_global(poses, body)[0]
