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


@njit(cache=True, nogil=True)
def eval_runs_kernel(integral: NDArray[np.float64], data: NDArray[np.int16], ptr: NDArray[np.int64],
                     ids: NDArray[np.int64], transforms: NDArray[np.float64], cx: float, cy: float,
                     outside_cost: float, out: NDArray[np.float64]) -> None:
    """Sum of ``A`` under transformed templates from a horizontal integral image (eq. 12).

    Parameters
    ----------
    integral : (h, w + 1) float64
        ``integral[y, x] = sum(A[y, :x])``.
    data : (R, 3) int16
        Runs ``(y, x_start, x_end)`` of all templates.
    ptr : (T + 1,) int64
        Template ``i`` owns ``data[ptr[i]:ptr[i + 1]]``.
    ids : (M,) int64
        Template of each evaluation.
    transforms : (M, 3) float64
        ``(dx, dy, s)`` of each evaluation.
    cx, cy : float
        Scaling centre.
    outside_cost : float
        Cost per template pixel outside the image.
    out : (M,) float64
        Written with the sums (without the constant ``B`` and the ``1/|w|`` factor).
    """
    h = integral.shape[0]
    w = integral.shape[1] - 1
    for m in range(ids.shape[0]):
        t = ids[m]
        dx = transforms[m, 0]
        dy = transforms[m, 1]
        s = transforms[m, 2]
        acc = 0.0
        for r in range(ptr[t], ptr[t + 1]):
            y = data[r, 0]
            ya = int(np.floor(cy + dy + s * (y - cy) + 0.5))
            yb = int(np.floor(cy + dy + s * (y + 1 - cy) + 0.5))
            xl = int(np.floor(cx + dx + s * (data[r, 1] - cx) + 0.5))
            xr = int(np.floor(cx + dx + s * (data[r, 2] - cx) + 0.5))
            if xr <= xl:
                continue
            cl = min(max(xl, 0), w)
            cr = min(max(xr, 0), w)
            for yy in range(ya, yb):
                if yy < 0 or yy >= h:
                    acc += outside_cost * (xr - xl)
                else:
                    acc += integral[yy, cr] - integral[yy, cl] + outside_cost * ((xr - xl) - (cr - cl))
        out[m] = acc


@njit(cache=True, nogil=True)
def _popcount64(x: np.uint64) -> np.uint64:
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (x * np.uint64(0x0101010101010101)) >> np.uint64(56)


@njit(cache=True, nogil=True)
def hamming_to_many(packed: NDArray[np.uint64], proto: int, members: NDArray[np.int64]) -> NDArray[np.int64]:
    """Number of differing bits between template ``proto`` and each of ``members``.

    Parameters
    ----------
    packed : (N, words) uint64
        Bit-packed masks.
    proto : int
    members : (n,) int64

    Returns
    -------
    (n,) int64
    """
    words = packed.shape[1]
    out = np.empty(members.shape[0], np.int64)
    for i in range(members.shape[0]):
        m = members[i]
        acc = np.uint64(0)
        for w in range(words):
            acc += _popcount64(packed[proto, w] ^ packed[m, w])
        out[i] = np.int64(acc)
    return out
