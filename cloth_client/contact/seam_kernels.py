"""Numba kernels of a seam's pins against the body: push-out, seam slide, length pass, coverage.

A garment's pinned row (the cape's collar, the skirt's waistband) follows its joint frames; these
kernels move its pin targets out of the body parts that cover them
(:class:`cloth_client.avatar.capsules.AvatarKeys` calls them). The plain numpy references are in
:mod:`cloth_client.contact.seam` (``*_reference``); tests hold both equal.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from cloth_client._jit import inline_kernel as _inline
from cloth_client._jit import jit_kernel as _jit
from cloth_client.contact.cone_kernels import GEO_COLS, capsule_geometry, round_cone_geo

__all__ = ["SEAM_LENGTH_ROUNDS", "SEAM_LENGTH_SLACK", "SEAM_MIN_COS", "SEAM_RING_STRIDE", "SEAM_SHARED_PASSES",
           "covered", "keep_seam_length", "push_out", "slide_seam"]

F64 = NDArray[np.float64]


@_jit
def covered(points: F64, a: F64, b: F64, radii: F64, reach: F64, out: NDArray[np.bool_]) -> None:  # pragma: no cover
    """``out[p]``: point ``p`` is within ``reach[c]`` metres of some capsule ``c`` (endpoints per
    key in ``a, b``) at some key (reference: :func:`cloth_client.contact.seam.covered_reference`).

    Parameters
    ----------
    points : (K + 1, P, 3) float64
    a, b : (K + 1, C, 3) float64
    radii : (C, 2) float64
    reach : (C,) float64
    out : (P,) bool
    """
    geo = np.empty((a.shape[1], GEO_COLS))
    out[:] = False
    for k in range(points.shape[0]):
        capsule_geometry(a[k], b[k], radii, 0.0, geo)
        for p in range(points.shape[1]):
            for c in range(a.shape[1]):
                if out[p]:
                    break
                d = round_cone_geo(points[k, p, 0], points[k, p, 1], points[k, p, 2], geo, c)[0]
                out[p] = d < reach[c]


@_inline
def _push_point(points: F64, k: int, p: int, geo: F64, n_caps: int, clearance: float) -> None:  # pragma: no cover
    """One projection of ``points[k, p]`` to ``clearance`` outside the nearest capsule of ``geo``
    (least signed distance, the first on a tie; a NaN distance wins, as numpy's argmin: not moved)."""
    px, py, pz = points[k, p, 0], points[k, p, 1], points[k, p, 2]
    best, bx, by, bz = np.inf, 0.0, 0.0, 0.0
    for c in range(n_caps):
        d, nx, ny, nz, _t = round_cone_geo(px, py, pz, geo, c)
        if d != d:
            best = d
            break
        if d < best:
            best, bx, by, bz = d, nx, ny, nz
    depth = clearance - best
    if depth > 0.0:
        points[k, p, 0] = px + depth * bx
        points[k, p, 1] = py + depth * by
        points[k, p, 2] = pz + depth * bz


@_jit
def push_out(points: F64, a: F64, b: F64, radii: F64, clearance: float, passes: int) -> None:  # pragma: no cover
    """Move ``points`` in place to at least ``clearance`` metres outside the body at their key:
    ``passes`` projections along the normal of the nearest capsule (the one of least signed
    distance; the first on a tie). Reference: :func:`cloth_client.contact.seam.push_out_reference`.

    Parameters
    ----------
    points : (K + 1, P, 3) float64
        Modified in place.
    a, b : (K + 1, C, 3) float64
    radii : (C, 2) float64
    clearance : float
    passes : int
    """
    geo = np.empty((a.shape[1], GEO_COLS))
    for k in range(points.shape[0]):
        capsule_geometry(a[k], b[k], radii, 0.0, geo)
        for p in range(points.shape[1]):
            for _ in range(passes):
                _push_point(points, k, p, geo, a.shape[1], clearance)


#: Passes of the shared push of a slid seam's covered pins (:func:`slide_seam`).
SEAM_SHARED_PASSES = 3
#: Floor of the cosine between a pin's own normal and its capsule's shared push direction: a pin on
#: the side of the body part moves at most twice its depth along that direction.
SEAM_MIN_COS = 0.5
#: Rounds of the slid seam's length pass (:func:`keep_seam_length`), and the stretch over rest it
#: leaves a seam segment (the cloth's own strain limit lets a spring reach 3 %).
SEAM_LENGTH_ROUNDS = 32
SEAM_LENGTH_SLACK = 0.02
#: Segments a ring's sweep start moves on each round, modulo the ring (:func:`keep_seam_length`): a
#: sweep round a closed ring ends where it started and leaves there what the body does not let it
#: shorten. A prime larger than any seam, so the start moves on every round on rings of any size.
SEAM_RING_STRIDE = 1009


@_jit
def slide_seam(points: F64, a: F64, b: F64, radii: F64, clearance: float, spread: int,
               wrap: bool, rest: F64) -> None:  # pragma: no cover
    """Slide a seam's pins (a cape's collar) out of the body parts covering them, in place, keeping
    the seam's length: reference :func:`cloth_client.contact.seam.slide_seam_reference`.

    Pushing each covered pin along its own normal spreads the pins under a body part round its
    surface, and the pinned springs between them stretch (the cape's collar under a head thrown
    back: 62 % on `dance-short`, every frame over 10 % a collar spring next to the skull). Per key:

    1. each pin's nearest capsule (least signed distance, the first on a tie) and its depth
       ``clearance - d``; the pins with a positive depth are covered;
    2. the covered pins of each capsule move together along one direction ``u`` (the depth-weighted
       sum of their normals, normalised), :data:`SEAM_SHARED_PASSES` times by
       ``max(clearance - d, 0) / max(n . u, SEAM_MIN_COS)``: the covered stretch is carried, not
       spread round the body part; then two radial projections (:func:`push_out`);
    3. the move ``delta`` of every pin is spread along the seam with a linear fall-off over
       ``spread`` pins, ``w(k) = max(0, 1 - k / (spread + 1))`` at ``k`` pins away (round the seam
       when ``wrap``): pin ``i`` moves by ``w(|i - j|) delta_j`` for the ``j`` of largest
       ``w(|i - j|) |delta_j|`` (the first on a tie), so the step between held and carried pins is
       shared by their neighbours;
    4. two radial projections again leave every pin at least ``clearance`` outside;
    5. when ``rest`` is given, :func:`keep_seam_length` shortens what the moves still stretched (the
       boundary between two body parts' groups, a stretch carried round a thigh in a crouch:
       `dance-short`'s waistband slid with a pin-to-pin spring at 10.3 %).

    Parameters
    ----------
    points : (K + 1, P, 3) float64
        Pin targets in seam order, modified in place.
    a, b : (K + 1, C, 3) float64
    radii : (C, 2) float64
    clearance : float
    spread : int
        Fall-off length in pins (0: no spreading).
    wrap : bool
        The seam is closed (a waistband).
    rest : (S,) float64
        Rest length of each seam segment ``i -> i + 1`` (``S = P`` when ``wrap``, the last closing
        the ring, else ``P - 1``); empty: no length pass.
    """
    n_keys, n_pins, n_caps = points.shape[0], points.shape[1], a.shape[1]
    geo = np.empty((n_caps, GEO_COLS))
    near = np.empty(n_pins, dtype=np.int64)
    depth = np.empty(n_pins)
    start = points.copy()
    for k in range(n_keys):
        capsule_geometry(a[k], b[k], radii, 0.0, geo)
        for p in range(n_pins):
            best, cb = np.inf, 0
            for c in range(n_caps):
                d = round_cone_geo(start[k, p, 0], start[k, p, 1], start[k, p, 2], geo, c)[0]
                if d < best:
                    best, cb = d, c
            near[p], depth[p] = cb, clearance - best
        for c in range(n_caps):
            ux, uy, uz, any_in = 0.0, 0.0, 0.0, False
            for p in range(n_pins):
                if near[p] == c and depth[p] > 0.0:
                    _d, nx, ny, nz, _t = round_cone_geo(start[k, p, 0], start[k, p, 1], start[k, p, 2], geo, c)
                    ux += depth[p] * nx
                    uy += depth[p] * ny
                    uz += depth[p] * nz
                    any_in = True
            norm = math.sqrt(ux * ux + uy * uy + uz * uz)
            if not any_in or not norm > 0.0:
                continue
            ux, uy, uz = ux / norm, uy / norm, uz / norm
            for _ in range(SEAM_SHARED_PASSES):
                for p in range(n_pins):
                    if near[p] == c and depth[p] > 0.0:
                        d, nx, ny, nz, _t = round_cone_geo(points[k, p, 0], points[k, p, 1], points[k, p, 2], geo, c)
                        need = clearance - d
                        if need > 0.0:
                            step = need / max(nx * ux + ny * uy + nz * uz, SEAM_MIN_COS)
                            points[k, p, 0] += step * ux
                            points[k, p, 1] += step * uy
                            points[k, p, 2] += step * uz
    push_out(points, a, b, radii, clearance, 2)
    if spread > 0:
        _spread_moves(points, start, spread, wrap)
        push_out(points, a, b, radii, clearance, 2)
    if rest.shape[0] > 0:
        keep_seam_length(points, a, b, radii, clearance, rest, SEAM_LENGTH_ROUNDS, SEAM_LENGTH_SLACK)


@_jit
def _spread_moves(points: F64, start: F64, spread: int, wrap: bool) -> None:  # pragma: no cover
    """Step 3 of :func:`slide_seam`: each pin moved by the largest fall-off-weighted move near it."""
    n_keys, n_pins = points.shape[0], points.shape[1]
    delta = points - start
    mag = np.empty(n_pins)
    for k in range(n_keys):
        for p in range(n_pins):
            mag[p] = math.sqrt(delta[k, p, 0] ** 2 + delta[k, p, 1] ** 2 + delta[k, p, 2] ** 2)
        for i in range(n_pins):
            top, jb, wb = -1.0, 0, 0.0
            for j in range(n_pins):
                gap = abs(i - j)
                if wrap:
                    gap = min(gap, n_pins - gap)
                w = max(0.0, 1.0 - gap / (spread + 1.0))
                if w * mag[j] > top:
                    top, jb, wb = w * mag[j], j, w
            for e in range(3):
                points[k, i, e] = start[k, i, e] + wb * delta[k, jb, e]


@_jit
def keep_seam_length(points: F64, a: F64, b: F64, radii: F64, clearance: float, rest: F64, rounds: int,
                     slack: float) -> None:  # pragma: no cover
    """Shorten a slid seam's stretched segments, in place, keeping the pins outside the body:
    reference :func:`cloth_client.contact.seam.keep_seam_length_reference`.

    Per key, up to ``rounds`` rounds, each a Gauss-Seidel sweep over the segments (forwards, then
    backwards on the next round; round a closed ring each round starts :data:`SEAM_RING_STRIDE`
    segments further on) that moves both ends of a segment longer than
    ``(1 + slack) rest`` half-way each towards the other, then one projection
    (:func:`push_out`'s rule) of every pin it moved. It stops after a round that moved nothing, so
    the body has the last word; a seam the body cannot leave room for keeps its stretch, spread
    over the segments instead of in one. A seam whose pins were not slid is at its rest lengths and
    is not touched.

    Parameters
    ----------
    points : (K + 1, P, 3) float64
        Pins in seam order, modified in place.
    a, b : (K + 1, C, 3) float64
    radii : (C, 2) float64
    clearance : float
    rest : (S,) float64
        Segment rest lengths, segment ``i`` from pin ``i`` to ``i + 1``; ``S = P`` closes the ring
        (the last segment joins the last pin to the first), else ``S = P - 1``.
    rounds : int
    slack : float
    """
    n_keys, n_pins, n_caps = points.shape[0], points.shape[1], a.shape[1]
    n_seg = rest.shape[0]
    geo = np.empty((n_caps, GEO_COLS))
    moved = np.zeros(n_pins, dtype=np.bool_)
    for k in range(n_keys):
        geo_ready = False
        for r in range(rounds):
            any_move = False
            start = (r * SEAM_RING_STRIDE) % n_seg if n_seg == n_pins else 0
            for q in range(n_seg):
                i = start + q if r % 2 == 0 else start + n_seg - 1 - q
                if i >= n_seg:
                    i -= n_seg
                j = i + 1
                if j == n_pins:
                    j = 0
                dx = points[k, j, 0] - points[k, i, 0]
                dy = points[k, j, 1] - points[k, i, 1]
                dz = points[k, j, 2] - points[k, i, 2]
                length = math.sqrt(dx * dx + dy * dy + dz * dz)
                limit = (1.0 + slack) * rest[i]
                if length > limit:
                    h = 0.5 * (length - limit) / length
                    points[k, i, 0] += h * dx
                    points[k, i, 1] += h * dy
                    points[k, i, 2] += h * dz
                    points[k, j, 0] -= h * dx
                    points[k, j, 1] -= h * dy
                    points[k, j, 2] -= h * dz
                    moved[i] = True
                    moved[j] = True
                    any_move = True
            if not any_move:
                break
            if not geo_ready:
                capsule_geometry(a[k], b[k], radii, 0.0, geo)
                geo_ready = True
            for p in range(n_pins):
                if moved[p]:
                    _push_point(points, k, p, geo, n_caps, clearance)
                    moved[p] = False
