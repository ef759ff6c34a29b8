"""Numba kernels of the tracker service. Each has a plain-numpy reference beside the code that
uses it, and a test holds the two equal."""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True, nogil=True)
def greedy_prune_kernel(q: NDArray[np.float32], cos_half: float, order: NDArray[np.int64]) -> NDArray[np.int64]:
    """Greedy §2.1 pose pruning on per-joint unit quaternions.

    Parameters
    ----------
    q : (N, K, 4) float32
        Unit quaternions of the K compared rotations of every pose (sign irrelevant).
    cos_half : float
        ``cos(threshold / 2)``: two rotations are within the threshold iff ``|q1 . q2| > cos_half``.
    order : (K,) int64
        Order in which joints are compared (most variable first, for early exits).

    Returns
    -------
    (M,) int64
        Indices of the kept poses, increasing. Pose ``i`` is kept iff for every earlier kept
        pose some joint differs by at least the threshold.
    """
    n, k = q.shape[0], q.shape[1]
    kept = np.empty(n, np.int64)
    buf = np.empty((n, k, 4), np.float32)  # kept features, compact, in comparison order
    nk = 0
    for i in range(n):
        redundant = False
        for m in range(nk - 1, -1, -1):  # recent poses first: neighbours in time are likeliest
            same = True
            for kk in range(k):
                j = order[kk]
                d = (q[i, j, 0] * buf[m, kk, 0] + q[i, j, 1] * buf[m, kk, 1]
                     + q[i, j, 2] * buf[m, kk, 2] + q[i, j, 3] * buf[m, kk, 3])
                if abs(d) <= cos_half:
                    same = False
                    break
            if same:
                redundant = True
                break
        if not redundant:
            kept[nk] = i
            for kk in range(k):
                for c in range(4):
                    buf[nk, kk, c] = q[i, order[kk], c]
            nk += 1
    return kept[:nk].copy()
