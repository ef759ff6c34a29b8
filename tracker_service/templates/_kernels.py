"""Numba kernels of :mod:`tracker_service.templates`. Each has a plain-numpy reference beside the code
that uses it, and a test holds the two equal."""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True, nogil=True)
def greedy_prune_kernel(q: NDArray[np.float32], cos_half: float,
                        order: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
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
    kept : (M,) int64
        Indices of the kept poses, increasing. Pose ``i`` is kept iff for every earlier kept
        pose some joint differs by at least the threshold.
    cover : (N,) int64
        For every pose, the position in ``kept`` of the kept pose that covers it (itself if kept;
        the most recently kept one within the threshold otherwise).
    """
    n, k = q.shape[0], q.shape[1]
    kept = np.empty(n, np.int64)
    cover = np.empty(n, np.int64)
    buf = np.empty((n, k, 4), np.float32)  # kept features, compact, in comparison order
    nk = 0
    for i in range(n):
        hit = -1
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
                hit = m
                break
        if hit >= 0:
            cover[i] = hit
        else:
            kept[nk] = i
            cover[i] = nk
            for kk in range(k):
                for c in range(4):
                    buf[nk, kk, c] = q[i, order[kk], c]
            nk += 1
    return kept[:nk].copy(), cover


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
