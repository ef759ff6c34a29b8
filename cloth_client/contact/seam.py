"""A seam's pins moved out of the body: plain numpy references of the seam kernels.

A garment's pinned row (the cape's collar, the skirt's waistband) follows its joint frames; a body
part moving over it (a shrug under the collar, a thigh in a crouch under the waistband) would put
pins inside the body. :class:`cloth_client.avatar.capsules.AvatarKeys` finds and moves them with the
numba kernels of :mod:`cloth_client.contact.seam_kernels`, which document the rules; these
functions are their references, held equal by ``tests/cloth/test_collision.py``:

* :func:`covered_reference` - which points lie within a reach of the body at some key;
* :func:`push_out_reference` - every pin projected out of its nearest capsule, twice;
* :func:`slide_seam_reference` - each body part's covered pins carried together along one
  direction, the move spread along the seam, pushed out, then the length pass;
* :func:`keep_seam_length_reference` - the length pass: segments still longer than their rest
  length (plus a slack) shortened by Gauss-Seidel rounds, each followed by a projection of the
  pins it moved.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cloth_client.contact.collision import CapsuleTrack, round_cone_reference
from cloth_client.contact.seam_kernels import (
    SEAM_LENGTH_ROUNDS,
    SEAM_LENGTH_SLACK,
    SEAM_MIN_COS,
    SEAM_RING_STRIDE,
    SEAM_SHARED_PASSES,
)

__all__ = ["check_seam_rest", "covered_reference", "keep_seam_length_reference", "push_out_reference",
           "slide_seam_reference"]

F64 = NDArray[np.float64]


def check_seam_rest(n_pins: int, rest: F64 | None, wrap: bool) -> F64:
    """Segment rest lengths of a seam of ``n_pins`` pins as a contiguous ``(S,)`` float64.

    ``S = n_pins`` when ``wrap`` (the last segment closes the ring), else ``n_pins - 1``; None gives an
    empty array (no length pass).

    Raises
    ------
    ValueError
        On another shape or a length that is not positive.
    """
    if rest is None:
        return np.zeros(0)
    seg = np.ascontiguousarray(rest, dtype=np.float64)
    want = n_pins if wrap else n_pins - 1
    if seg.shape != (want,) or not np.all(seg > 0.0):
        raise ValueError(f"rest must be ({want},) positive segment lengths for {n_pins} pins "
                         f"(wrap={wrap}), got shape {seg.shape}")
    return seg


def covered_reference(track: CapsuleTrack, points: F64, margin: float | F64) -> NDArray[np.bool_]:
    """Which of ``points (K + 1, P, 3)`` lie within ``margin`` (metres, or one per capsule ``(C,)``) of
    the capsules of ``track`` at their key, ``(P,)`` (true if at any key): reference of
    :func:`cloth_client.contact.seam_kernels.covered`."""
    out = np.zeros(points.shape[1], dtype=bool)
    for k in range(points.shape[0]):
        d, _, _ = round_cone_reference(points[k], track.a[k], track.b[k], track.radii[:, 0], track.radii[:, 1])
        out |= (d < margin).any(axis=1)
    return out


def push_out_reference(track: CapsuleTrack, points: F64, clearance: float) -> F64:
    """``points (K + 1, P, 3)`` moved to at least ``clearance`` outside the capsules of ``track`` at
    their key: two projections along the normal of the nearest capsule (reference of
    :func:`cloth_client.contact.seam_kernels.push_out`)."""
    out = np.array(points, dtype=np.float64)
    radii = track.radii
    for k in range(len(out)):
        for _ in range(2):
            d, n, _t = round_cone_reference(out[k], track.a[k], track.b[k], radii[:, 0], radii[:, 1])
            c = np.argmin(d, axis=1)
            depth = clearance - d[np.arange(len(c)), c]
            inside = depth > 0
            out[k, inside] += depth[inside, None] * n[inside, c[inside]]
    return out


def slide_seam_reference(track: CapsuleTrack, points: F64, clearance: float, spread: int, wrap: bool,
                         rest: F64) -> F64:
    """``points (K + 1, P, 3)``, pins in seam order, slid out of the body parts covering them
    (reference of :func:`cloth_client.contact.seam_kernels.slide_seam`); ``rest (S,)`` the segment rest
    lengths (empty: no length pass)."""
    start = np.array(points, dtype=np.float64)
    out = start.copy()
    r0, r1 = track.radii[:, 0], track.radii[:, 1]
    for k in range(len(out)):
        a, b = track.a[k], track.b[k]
        d, n, _t = round_cone_reference(start[k], a, b, r0, r1)  # (P, C)
        near = np.argmin(d, axis=1)
        depth = clearance - d[np.arange(len(near)), near]
        for c in np.unique(near[depth > 0.0]):
            sel = (near == c) & (depth > 0.0)
            u = (depth[sel, None] * n[sel, c]).sum(axis=0)
            norm = float(np.linalg.norm(u))
            if not norm > 0.0:
                continue
            u /= norm
            for _ in range(SEAM_SHARED_PASSES):
                dd, nn, _t = round_cone_reference(out[k, sel], a[c:c + 1], b[c:c + 1], r0[c:c + 1], r1[c:c + 1])
                step = np.maximum(clearance - dd[:, 0], 0.0) / np.maximum(nn[:, 0] @ u, SEAM_MIN_COS)
                out[k, sel] += step[:, None] * u
    out = push_out_reference(track, out, clearance)
    if spread > 0:
        delta = out - start
        idx = np.arange(start.shape[1])
        gap = np.abs(idx[:, None] - idx[None, :])
        if wrap:
            gap = np.minimum(gap, len(idx) - gap)
        w = np.maximum(0.0, 1.0 - gap / (spread + 1.0))  # (P, P)
        for k in range(len(out)):
            j = np.argmax(w * np.linalg.norm(delta[k], axis=1)[None, :], axis=1)
            out[k] = start[k] + w[idx, j][:, None] * delta[k, j]
        out = push_out_reference(track, out, clearance)
    if len(rest):
        out = keep_seam_length_reference(track, out, clearance, rest, SEAM_LENGTH_ROUNDS, SEAM_LENGTH_SLACK)
    return out


def keep_seam_length_reference(track: CapsuleTrack, points: F64, clearance: float, rest: F64,
                               rounds: int = SEAM_LENGTH_ROUNDS, slack: float = SEAM_LENGTH_SLACK) -> F64:
    """``points (K + 1, P, 3)``, a seam's pins in order, with every segment longer than
    ``(1 + slack) rest`` shortened and the pins kept ``clearance`` outside the body
    (reference of :func:`cloth_client.contact.seam_kernels.keep_seam_length`; ``rest (S,)``, ``S = P``
    closes the ring)."""
    out = np.array(points, dtype=np.float64)
    n_pins, n_seg = out.shape[1], len(rest)
    r0, r1 = track.radii[:, 0], track.radii[:, 1]
    for k in range(len(out)):
        for r in range(rounds):
            moved = np.zeros(n_pins, dtype=bool)
            start = (r * SEAM_RING_STRIDE) % n_seg if n_seg == n_pins else 0
            order = np.arange(n_seg) if r % 2 == 0 else np.arange(n_seg - 1, -1, -1)
            for i in (start + order) % n_seg:
                j = (i + 1) % n_pins
                d = out[k, j] - out[k, i]
                length = float(np.sqrt(d @ d))
                limit = (1.0 + slack) * rest[i]
                if length > limit:
                    h = 0.5 * (length - limit) / length
                    out[k, i] += h * d
                    out[k, j] -= h * d
                    moved[i] = moved[j] = True
            if not moved.any():
                break
            p = np.flatnonzero(moved)
            dist, n, _t = round_cone_reference(out[k, p], track.a[k], track.b[k], r0, r1)
            c = np.argmin(dist, axis=1)
            depth = clearance - dist[np.arange(len(p)), c]
            inside = depth > 0.0
            out[k, p[inside]] += depth[inside, None] * n[inside, c[inside]]
    return out
