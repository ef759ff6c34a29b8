"""Pose-database extraction (Okada & Stenger §2.1): keep only poses that differ from every kept
pose by at least a threshold (5 degrees) in some joint angle.

"Joint angle difference" is the geodesic angle between the two local joint rotations. The root's
heading (yaw) is left out -- the same body pose facing another way is the same pose; the template
database adds headings by augmentation -- but its tilt (pitch/roll) is compared.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from protocol.rotations import matrix_to_quat, rotvec_to_matrix
from protocol.skeleton import POSE_SIZE, ROT_JOINTS
from tracker_service.templates._kernels import greedy_prune_kernel

__all__ = ["PruneResult", "pose_features", "prune_poses", "prune_poses_reference"]

log = logging.getLogger(__name__)


def pose_features(poses: NDArray[np.float64], compare_heading: bool = False) -> NDArray[np.float32]:
    """Per-joint unit quaternions compared by the pruning.

    Parameters
    ----------
    poses : (N, P) float
    compare_heading : bool
        Keep the root's full orientation (heading included) instead of its tilt only.

    Returns
    -------
    (N, R, 4) float32
        ``R = len(ROT_JOINTS)``: the root's tilt (or full orientation) then every joint's local
        rotation.
    """
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != POSE_SIZE:
        raise ValueError(f"poses must be (N, {POSE_SIZE})")
    n = len(p)
    q = matrix_to_quat(rotvec_to_matrix(p[:, 3:].reshape(n, len(ROT_JOINTS), 3)))
    if compare_heading:
        return q.astype(np.float32)
    # swing-twist about Y: root = swing * twist; keep the swing (tilt) only
    r = q[:, 0]
    tw = np.stack([r[:, 0], np.zeros(n), r[:, 2], np.zeros(n)], axis=1)
    tn = np.linalg.norm(tw, axis=1, keepdims=True)
    tw = np.where(tn > 1e-9, tw / np.maximum(tn, 1e-12), np.array([1.0, 0, 0, 0]))
    # swing = r * conj(twist)
    w1, x1, y1, z1 = r.T
    w2, x2, y2, z2 = tw[:, 0], -tw[:, 1], -tw[:, 2], -tw[:, 3]
    q[:, 0] = np.stack([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ], axis=1)
    return q.astype(np.float32)


def _comparison_order(q: NDArray[np.float32]) -> NDArray[np.int64]:
    spread = 1.0 - np.abs(np.einsum("nkc,kc->nk", q, q.mean(axis=0) / np.maximum(
        np.linalg.norm(q.mean(axis=0), axis=1, keepdims=True), 1e-9)))
    return np.argsort(-spread.mean(axis=0)).astype(np.int64)


@dataclass(frozen=True)
class PruneResult:
    """Outcome of :func:`prune_poses`.

    Attributes
    ----------
    kept : (M,) int64
        Indices of the kept poses into the input, increasing.
    cover : (N,) int64
        For every input pose, the position in ``kept`` of the kept pose within the threshold of it
        (used to map recording frames onto database poses for the transition histograms).
    n_input : int
    seconds : float
        Wall time of the pruning.
    threshold_deg : float
    """

    kept: NDArray[np.int64]
    cover: NDArray[np.int64]
    n_input: int
    seconds: float
    threshold_deg: float

    @property
    def n_kept(self) -> int:
        return len(self.kept)


def prune_poses(poses: NDArray[np.float64], threshold_deg: float = 5.0, compare_heading: bool = False
                ) -> PruneResult:
    """Greedy pruning (numba kernel).

    Parameters
    ----------
    poses : (N, P) float
        Candidate poses in order (recordings concatenated frame by frame).
    threshold_deg : float
        Minimum joint-angle difference, degrees (paper: 5).
    compare_heading : bool
        Also compare the root's heading (for heading-augmented template sets).

    Returns
    -------
    PruneResult
    """
    if not threshold_deg > 0:
        raise ValueError("threshold_deg must be positive")
    t0 = time.perf_counter()
    q = pose_features(poses, compare_heading)
    if len(q) == 0:
        return PruneResult(np.zeros(0, np.int64), np.zeros(0, np.int64), 0, 0.0, threshold_deg)
    kept, cover = greedy_prune_kernel(np.ascontiguousarray(q), float(np.cos(np.radians(threshold_deg) / 2)),
                               _comparison_order(q))
    dt = time.perf_counter() - t0
    log.info("pruned %d poses to %d at %.1f deg in %.2f s", len(q), len(kept), threshold_deg, dt)
    return PruneResult(kept, cover, len(q), dt, threshold_deg)


def prune_poses_reference(poses: NDArray[np.float64], threshold_deg: float = 5.0) -> NDArray[np.int64]:
    """Plain-numpy reference of :func:`prune_poses` (same greedy order; O(N * M * R))."""
    q = pose_features(poses).astype(np.float64)
    c = np.cos(np.radians(threshold_deg) / 2)
    kept: list[int] = []
    for i in range(len(q)):
        if kept:
            d = np.abs(np.einsum("mkc,kc->mk", q[kept], q[i]))
            if np.any(np.all(d > c, axis=1)):
                continue
        kept.append(i)
    return np.asarray(kept, dtype=np.int64)
