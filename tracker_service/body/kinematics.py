"""Forward kinematics compiled for the tracker's per-frame path.

The published pose goes through forward kinematics several times a frame, one pose at a time
(the refinement's confidence, the feet offset, the ghost and plausibility checks, the floor
contact). :func:`protocol.kinematics.fk_global`, the reference, is vectorised over a batch; on a
single pose its 23 numpy matrix products and Rodrigues' formula cost ~0.1-0.3 ms of per-call
overhead. The kernel (:func:`tracker_service.body._kernels.fk_global_kernel`) does the same
arithmetic in one compiled loop; a test holds the two equal.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.kinematics import pose_batch
from protocol.skeleton import N_JOINTS, PARENTS, ROT_SLOT, Body
from tracker_service.body._kernels import fk_global_kernel

__all__ = ["fk", "fk_global"]

_PARENTS = np.asarray(PARENTS, np.int64)
_SLOTS = np.asarray(ROT_SLOT, np.int64)


def fk_global(poses: ArrayLike, body: Body) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Joint positions and global joint orientations (as :func:`protocol.kinematics.fk_global`).

    Parameters
    ----------
    poses : (N, P) or (P,) float
    body : Body

    Returns
    -------
    joints : (N, J, 3) float64
        World positions, metres (``(J, 3)`` for a single pose).
    rotations : (N, J, 3, 3) float64
        Global orientation of each joint's frame.
    """
    p, single = pose_batch(poses)
    pos = np.empty((p.shape[0], N_JOINTS, 3))
    rot = np.empty((p.shape[0], N_JOINTS, 3, 3))
    fk_global_kernel(p, np.ascontiguousarray(body.offsets, np.float64), _PARENTS, _SLOTS, pos, rot)
    if single:
        return pos[0], rot[0]
    return pos, rot


def fk(poses: ArrayLike, body: Body) -> NDArray[np.float64]:
    """Joint positions (as :func:`protocol.kinematics.fk`): ``(N, J, 3)``, or ``(J, 3)`` for one pose."""
    return fk_global(poses, body)[0]
