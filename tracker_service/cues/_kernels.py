"""Numba kernels of :mod:`tracker_service.cues`. Each has a plain-numpy reference beside the code
that uses it, and a test holds the two equal."""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True, nogil=True)
def skin_cost_kernel(distance: NDArray[np.float32], samples: NDArray[np.float64], points: NDArray[np.float32],
                     rows: NDArray[np.int64], segments: NDArray[np.int64], hands: NDArray[np.int64],
                     visible: NDArray[np.float32], hand_parts: NDArray[np.int64], min_visible: np.float32,
                     places: NDArray[np.float64], cx: float, cy: float, sigma: float, cap: float, hidden: float,
                     cover_weight: float, radius: float, out: NDArray[np.float64]) -> None:
    """Skin cue of templates at placements: hand term plus ``cover_weight`` times the cover term
    (:func:`tracker_service.cues.skin.hand_cost` + :func:`tracker_service.cues.skin.cover_cost`, their
    numpy references). Templates are read through ``rows`` (no gathered copies); only the hand
    joints are placed unless the cover term needs the bones.

    Parameters
    ----------
    distance : (H, W) float32
        Distance to the nearest skin pixel.
    samples : (K, 2) float64
        Skin pixels ``(u, v)``.
    points : (L, J, 2) float32
        Joints of every template at the reference placement.
    rows : (n,) int64
        Template (row of ``points`` and ``visible``) of each evaluation.
    segments : (S, 2) int64
        Joint pairs of the skin-bearing bones.
    hands : (2, 2) int64
        ``(wrist, hand_tip)`` joints of the left and right hand.
    visible : (L, P) float32
        Visible fraction of each part of each template.
    hand_parts : (2,) int64
        Columns of ``visible`` of the left and right hand.
    min_visible : float32
        A hand counts as shown where its visible fraction exceeds this (compared in float32, as
        numpy compares a float32 array with a Python float).
    places : (n, G, 3) float64
        Placements ``(dx, dy, s)``.
    cx, cy, sigma, cap, hidden, cover_weight, radius : float
    out : (n, G) float64
        Written.
    """
    h, w = distance.shape
    n, g = places.shape[0], places.shape[1]
    nj = points.shape[1]
    k = samples.shape[0]
    cover = cover_weight > 0.0 and k > 0
    u = np.empty(nj)
    v = np.empty(nj)
    n_seg = segments.shape[0]
    su = np.ascontiguousarray(samples[:, 0])
    sv = np.ascontiguousarray(samples[:, 1])
    best = np.empty(k)
    for i in range(n):
        r = rows[i]
        for j in range(g):
            dx, dy, s = places[i, j, 0], places[i, j, 1], places[i, j, 2]
            if cover:
                for q in range(nj):
                    u[q] = cx + dx + s * (points[r, q, 0] - cx)
                    v[q] = cy + dy + s * (points[r, q, 1] - cy)
            else:
                for hh in range(2):
                    for end in range(2):
                        q = hands[hh, end]
                        u[q] = cx + dx + s * (points[r, q, 0] - cx)
                        v[q] = cy + dy + s * (points[r, q, 1] - cy)
            acc = 0.0
            for hh in range(2):
                if not visible[r, hand_parts[hh]] > min_visible:  # float32 both
                    acc += hidden
                    continue
                hu = 0.5 * (u[hands[hh, 0]] + u[hands[hh, 1]])
                hv = 0.5 * (v[hands[hh, 0]] + v[hands[hh, 1]])
                d = cap
                if np.isfinite(hu) and np.isfinite(hv):
                    iu = int(np.rint(hu))
                    iv = int(np.rint(hv))
                    if 0 <= iu < w and 0 <= iv < h:
                        d = min(float(distance[iv, iu]), cap)
                acc += 0.5 * (d / sigma) ** 2
            if cover:
                for m in range(k):
                    best[m] = np.inf
                for t in range(n_seg):  # bone by bone over all samples: a loop the compiler vectorises
                    ax, ay = u[segments[t, 0]], v[segments[t, 0]]
                    bx, by = u[segments[t, 1]] - ax, v[segments[t, 1]] - ay
                    ll = max(bx * bx + by * by, 1e-9)
                    for m in range(k):
                        px, py = su[m] - ax, sv[m] - ay
                        tt = min(max((px * bx + py * by) / ll, 0.0), 1.0)
                        ex, ey = px - tt * bx, py - tt * by
                        d2 = ex * ex + ey * ey
                        if d2 < best[m]:
                            best[m] = d2
                cov = 0.0
                for m in range(k):
                    e = cap if not np.isfinite(best[m]) else min(max(np.sqrt(best[m]) - radius, 0.0), cap)
                    cov += 0.5 * (e / sigma) ** 2
                acc += cover_weight * 2.0 * cov / k
            out[i, j] = acc


@njit(cache=True, nogil=True)
def feet_cost_kernel(su: NDArray[np.int64], sv: NDArray[np.int64], feet: NDArray[np.float64], height: int,
                     width: int, cap: float, dead: float, forward: float, reverse: float) -> NDArray[np.float64]:
    """The shoe cue's cost of templates' feet (:func:`tracker_service.cues.shoes.feet_cost`; numpy
    reference :func:`tracker_service.cues.shoes.feet_cost_reference`).

    Parameters
    ----------
    su, sv : (N,) int64
        Columns and rows of the shoe pixels (N > 0).
    feet : (K, 2, 2) float64
        Left/right foot centres ``(u, v)`` of K templates.
    height, width : int
        The image's size: a foot rounded to a pixel outside it is ``cap`` from every shoe.
    cap, dead, forward, reverse : float

    Returns
    -------
    (K,) float64
        ``forward * sum_f min(d(round(u_f)), cap)^2 + reverse * mean_p max(min(|p - u_f*|, cap) - dead, 0)^2``,
        ``d`` the distance to the nearest shoe pixel and ``u_f*`` the foot nearest pixel ``p``.
    """
    k, n = feet.shape[0], su.shape[0]
    out = np.empty(k)
    for i in range(k):
        fwd = 0.0
        for f in range(2):
            ui, vi = np.rint(feet[i, f, 0]), np.rint(feet[i, f, 1])
            best = np.inf
            if not (0.0 <= ui < width and 0.0 <= vi < height):
                n_in = 0
            else:
                n_in = n
            for p in range(n_in):
                du, dv = ui - su[p], vi - sv[p]
                d2 = du * du + dv * dv
                if d2 < best:
                    best = d2
            d = min(np.sqrt(best), cap)
            fwd += d * d
        rev = 0.0
        l_u, l_v, r_u, r_v = feet[i, 0, 0], feet[i, 0, 1], feet[i, 1, 0], feet[i, 1, 1]
        for p in range(n):
            du, dv = l_u - su[p], l_v - sv[p]
            eu, ev = r_u - su[p], r_v - sv[p]
            # one root of the smaller square (a rounded root never reverses an order; fmin: a foot
            # that is NaN is no nearer than the other)
            near = np.sqrt(np.fmin(du * du + dv * dv, eu * eu + ev * ev))
            e = max(min(near, cap) - dead, 0.0)
            rev += e * e
        out[i] = forward * fwd + reverse * (rev / n)
    return out


@njit(cache=True, nogil=True)
def shoe_pixels_kernel(frame: NDArray[np.uint8], mask: NDArray[np.bool_], y0: int, y1: int, x0: int, x1: int,
                       mean: NDArray[np.float64], inv_cov: NDArray[np.float64],
                       threshold: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Shoe pixels of the box ``[y0, y1) x [x0, x1)``: silhouette pixels whose colour is within
    ``threshold`` (squared Mahalanobis) of the shoes', opened once with the 4-neighbour cross
    (pixels outside the box count as background), in row-major order. Numpy reference:
    :func:`tracker_service.cues.shoes.shoe_mask`.

    Parameters
    ----------
    frame : (H, W, 3) uint8
    mask : (H, W) bool
    y0, y1, x0, x1 : int
    mean : (3,) float64
    inv_cov : (3, 3) float64
    threshold : float

    Returns
    -------
    su, sv : (N,) int64
        Columns and rows.
    """
    hh, ww = y1 - y0, x1 - x0
    hit = np.zeros((hh + 2, ww + 2), np.bool_)
    for y in range(hh):
        for x in range(ww):
            if mask[y0 + y, x0 + x]:
                d0 = frame[y0 + y, x0 + x, 0] - mean[0]
                d1 = frame[y0 + y, x0 + x, 1] - mean[1]
                d2 = frame[y0 + y, x0 + x, 2] - mean[2]
                q = (d0 * (inv_cov[0, 0] * d0 + inv_cov[0, 1] * d1 + inv_cov[0, 2] * d2)
                     + d1 * (inv_cov[1, 0] * d0 + inv_cov[1, 1] * d1 + inv_cov[1, 2] * d2)
                     + d2 * (inv_cov[2, 0] * d0 + inv_cov[2, 1] * d1 + inv_cov[2, 2] * d2))
                hit[y + 1, x + 1] = q < threshold
    ero = np.zeros((hh + 2, ww + 2), np.bool_)
    for y in range(1, hh + 1):
        for x in range(1, ww + 1):
            ero[y, x] = hit[y, x] and hit[y - 1, x] and hit[y + 1, x] and hit[y, x - 1] and hit[y, x + 1]
    su = np.empty(hh * ww, np.int64)
    sv = np.empty(hh * ww, np.int64)
    n = 0
    for y in range(1, hh + 1):
        for x in range(1, ww + 1):
            if ero[y, x] or ero[y - 1, x] or ero[y + 1, x] or ero[y, x - 1] or ero[y, x + 1]:
                su[n] = x0 + x - 1
                sv[n] = y0 + y - 1
                n += 1
    return su[:n], sv[:n]


@njit(cache=True, nogil=True, fastmath={"reassoc", "contract", "arcp"})
def proposal_cost_kernel(joints: NDArray[np.float32], inv_var: NDArray[np.float64], mu: NDArray[np.float64],
                         heading: NDArray[np.float32], centre: float, half_width: float, max_abs: float
                         ) -> NDArray[np.float64]:
    """Every leaf's cost under the appearance network's Gaussian, ``inf`` outside the heading window.

    Reference: :func:`tracker_service.cues.appearance.propose_leaves` with
    :meth:`tracker_service.cues.appearance.HeadingWindow.mask` (``sum (x^2 - 2 x mu) / var`` over every
    coordinate; one pass over the joints instead of a matrix product over the joints and their
    squares; re-association lets the inner sum vectorise; NaN and infinity keep their IEEE meaning, so
    a NaN heading or centre is outside the window, never a hang).

    Parameters
    ----------
    joints : (NL, K) float32
        Every leaf's joint coordinates, flattened.
    inv_var, mu : (K,) float64
    heading : (NL,) float32
        Leaf headings (radians, in [-pi, pi]).
    centre, half_width : float
        A leaf is allowed when its heading is within ``half_width`` of ``centre`` on the circle...
    max_abs : float
        ... and ``|heading| <= max_abs``.

    Returns
    -------
    (NL,) float64
    """
    nl, k = joints.shape
    a = np.empty(k, np.float32)
    b = np.empty(k, np.float32)
    for j in range(k):
        a[j] = inv_var[j]
        b[j] = -2.0 * mu[j] * inv_var[j]
    out = np.empty(nl)
    two_pi = 2.0 * np.pi
    for i in range(nl):
        h = float(heading[i])
        # the angle between them, in [-pi, pi): fmod(x, 2 pi), without its cost where x lies in
        # [0, 4 pi) (headings in [-pi, pi]); x - 2 pi is exact there (Sterbenz), as fmod's remainder is
        x = h - centre + np.pi
        if 0.0 <= x < two_pi:
            d = x
        elif two_pi <= x < 2.0 * two_pi:
            d = x - two_pi
        else:
            d = np.fmod(x, two_pi)
        if d < 0.0:
            d += two_pi
        d -= np.pi
        if not (abs(d) <= half_width and abs(h) <= max_abs):  # NaN: outside
            out[i] = np.inf
            continue
        s = np.float32(0.0)
        for j in range(k):
            v = joints[i, j]
            s += v * (a[j] * v + b[j])
        out[i] = s
    return out
