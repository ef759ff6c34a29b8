"""Numba kernels of the tracker service. Each has a plain-numpy reference beside the code that
uses it, and a test holds the two equal."""

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


#: "No previous row" for the run kernels: outside int16, so never a template's row.
_NO_ROW = -(1 << 20)


@njit(cache=True, nogil=True, inline="always")
def _runs_sum(integral: NDArray[np.float64], data: NDArray[np.int16], r0: int, r1: int, dx: float, dy: float,
              s: float, cx: float, cy: float, outside_cost: float) -> float:
    """Sum of ``A`` under runs ``data[r0:r1]`` placed at ``(dx, dy, s)`` (eq. 12; see
    :func:`eval_runs_grid_kernel`). Indices are passed unsigned where they are known to be inside the
    arrays (no wrap-around test), a row's first target row is the previous row's end when the rows
    are consecutive (the same expression, so the same integer) and a run inside the image skips the
    outside term (which is ``+0.0`` there): the sums are bit-identical to the plain form."""
    h = integral.shape[0]
    w = integral.shape[1] - 1
    acc = 0.0
    y_prev = _NO_ROW  # not -1: a template may start on row -1
    ya = 0
    yb = 0
    for r in range(r0, r1):
        ur = np.uint64(r)
        y = data[ur, 0]
        if y != y_prev:
            if y == y_prev + 1 and y_prev >= 0:
                ya = yb
            else:
                ya = int(np.floor(cy + dy + s * (y - cy) + 0.5))
            yb = int(np.floor(cy + dy + s * (y + 1 - cy) + 0.5))
            y_prev = y
        xl = int(np.floor(cx + dx + s * (data[ur, 1] - cx) + 0.5))
        xr = int(np.floor(cx + dx + s * (data[ur, 2] - cx) + 0.5))
        if xr <= xl:
            continue
        cl = min(max(xl, 0), w)
        cr = min(max(xr, 0), w)
        if cl == xl and cr == xr and ya >= 0 and yb <= h:  # inside the image (the common case)
            ucl = np.uint64(cl)
            ucr = np.uint64(cr)
            for yy in range(ya, yb):
                uy = np.uint64(yy)
                acc += integral[uy, ucr] - integral[uy, ucl]
            continue
        for yy in range(ya, yb):
            if yy < 0 or yy >= h:
                acc += outside_cost * (xr - xl)
            else:
                acc += integral[yy, cr] - integral[yy, cl] + outside_cost * ((xr - xl) - (cr - cl))
    return acc


@njit(cache=True, nogil=True)
def eval_runs_grid_kernel(integral: NDArray[np.float64], data: NDArray[np.int16], ptr: NDArray[np.int64],
                          ids: NDArray[np.int64], transforms: NDArray[np.float64], cx: float, cy: float,
                          outside_cost: float, out: NDArray[np.float64]) -> None:
    """Sum of ``A`` under transformed templates from a horizontal integral image (eq. 12), at
    ``G`` placements per template (the coarse levels' search grids; ``G`` = 1 elsewhere).

    A run ``(y, x0, x1)`` placed at ``(dx, dy, s)`` covers rows
    ``[floor(cy + dy + s (y - cy) + 0.5), floor(cy + dy + s (y + 1 - cy) + 0.5))`` and columns
    ``[floor(cx + dx + s (x0 - cx) + 0.5), floor(cx + dx + s (x1 - cx) + 0.5))``; each covered row
    adds ``integral[row, right] - integral[row, left]``, and each template pixel outside the image
    ``outside_cost``. With ``G`` = 1 each sum is :func:`_runs_sum`; with a grid, each template's
    runs are read once and every run is placed at all ``G`` placements (a row's target rows once
    per placement), with :func:`_runs_sum`'s shortcuts: the same sums to the bit.

    Parameters
    ----------
    integral : (h, w + 1) float64
        ``integral[y, x] = sum(A[y, :x])``.
    data : (R, 3) int16
        Runs ``(y, x_start, x_end)`` of all templates.
    ptr : (T + 1,) int64
        Template ``i`` owns ``data[ptr[i]:ptr[i + 1]]``.
    ids : (n,) int64
        Template of each group.
    transforms : (n, G, 3) float64
        ``(dx, dy, s)`` of each evaluation.
    cx, cy : float
        Scaling centre.
    outside_cost : float
        Cost per template pixel outside the image.
    out : (n, G) float64
        Written with the sums (without the constant ``B`` and the ``1/|w|`` factor).
    """
    g_n = transforms.shape[1]
    if g_n == 1:  # one accumulator in a register
        for m in range(ids.shape[0]):
            t = ids[m]
            out[m, 0] = _runs_sum(integral, data, ptr[t], ptr[t + 1], transforms[m, 0, 0], transforms[m, 0, 1],
                                  transforms[m, 0, 2], cx, cy, outside_cost)
        return
    h = integral.shape[0]
    w = integral.shape[1] - 1
    acc = np.empty(g_n)
    ya_g = np.empty(g_n, np.int64)
    yb_g = np.empty(g_n, np.int64)
    for m in range(ids.shape[0]):
        t = ids[m]
        for g in range(g_n):
            acc[g] = 0.0
        y_prev = _NO_ROW
        for r in range(ptr[t], ptr[t + 1]):
            ur = np.uint64(r)
            y = data[ur, 0]
            x0 = data[ur, 1]
            x1 = data[ur, 2]
            if y != y_prev:
                for g in range(g_n):
                    dy = transforms[m, g, 1]
                    s = transforms[m, g, 2]
                    if y == y_prev + 1 and y_prev >= 0:
                        ya_g[g] = yb_g[g]
                    else:
                        ya_g[g] = int(np.floor(cy + dy + s * (y - cy) + 0.5))
                    yb_g[g] = int(np.floor(cy + dy + s * (y + 1 - cy) + 0.5))
                y_prev = y
            for g in range(g_n):
                dx = transforms[m, g, 0]
                s = transforms[m, g, 2]
                ya = ya_g[g]
                yb = yb_g[g]
                xl = int(np.floor(cx + dx + s * (x0 - cx) + 0.5))
                xr = int(np.floor(cx + dx + s * (x1 - cx) + 0.5))
                if xr <= xl:
                    continue
                cl = min(max(xl, 0), w)
                cr = min(max(xr, 0), w)
                if cl == xl and cr == xr and ya >= 0 and yb <= h:
                    ucl = np.uint64(cl)
                    ucr = np.uint64(cr)
                    a = acc[g]
                    for yy in range(ya, yb):
                        uy = np.uint64(yy)
                        a += integral[uy, ucr] - integral[uy, ucl]
                    acc[g] = a
                    continue
                for yy in range(ya, yb):
                    if yy < 0 or yy >= h:
                        acc[g] += outside_cost * (xr - xl)
                    else:
                        acc[g] += integral[yy, cr] - integral[yy, cl] + outside_cost * ((xr - xl) - (cr - cl))
        for g in range(g_n):
            out[m, g] = acc[g]


@njit(cache=True, nogil=True)
def xor_level_kernel(mask: NDArray[np.bool_], integral: NDArray[np.float64], sat: NDArray[np.float64]
                     ) -> tuple[int, int, int, int, int]:
    """XOR's matching image of one pyramid level in one pass: ``A = 1 - 2 S`` summed along rows
    (eq. 12) and over rectangles, the silhouette's area and bounding box (reference: the numpy
    path of :func:`tracker_service.features.preprocess`; every sum is an exact integer).

    Parameters
    ----------
    mask : (h, w) bool
    integral : (h, w + 1) float64
        Written: ``integral[y, x] = sum(A[y, :x])``.
    sat : (h + 1, w + 1) float64
        Written: ``sat[y, x] = sum(A[:y, :x])``.

    Returns
    -------
    count, y_min, y_max, x_min, x_max : int
        Pixels of ``S`` and their bounding box (zeros when ``S`` is empty).
    """
    h, w = mask.shape
    count = 0
    y0 = h
    y1 = -1
    x0 = w
    x1 = -1
    for x in range(w + 1):
        sat[0, x] = 0.0
    for y in range(h):
        acc = 0.0
        integral[y, 0] = 0.0
        sat[y + 1, 0] = 0.0
        for x in range(w):
            if mask[y, x]:
                acc -= 1.0
                count += 1
                if y < y0:
                    y0 = y
                y1 = y
                if x < x0:
                    x0 = x
                if x > x1:
                    x1 = x
            else:
                acc += 1.0
            integral[y, x + 1] = acc
            sat[y + 1, x + 1] = sat[y, x + 1] + acc
    if count == 0:
        return 0, 0, 0, 0, 0
    return count, y0, y1, x0, x1


@njit(cache=True, nogil=True)
def run_rectangles_kernel(data: NDArray[np.int16], ptr: NDArray[np.int64]
                          ) -> tuple[NDArray[np.int16], NDArray[np.int64]]:
    """Merge each template's runs into rectangles: a run continues the rectangle of the row above
    when that row has a run with the same ``(x_start, x_end)``; every run lies in exactly one
    rectangle, in the order the rectangles are started. Inputs and outputs as
    :func:`tracker_service.silhouette_distance.run_rectangles` (which checks them)."""
    out = np.empty((data.shape[0], 4), np.int16)
    rptr = np.zeros(ptr.shape[0], np.int64)
    prev = np.empty(max(data.shape[0], 1), np.int64)  # rectangles open in the previous row
    cur = np.empty(max(data.shape[0], 1), np.int64)
    q = 0
    for t in range(ptr.shape[0] - 1):
        n_prev = 0
        n_cur = 0
        y_cur = -2
        y_prev = -2
        for r in range(ptr[t], ptr[t + 1]):
            y = data[r, 0]
            x0 = data[r, 1]
            x1 = data[r, 2]
            if y != y_cur:
                for i in range(n_cur):
                    prev[i] = cur[i]
                n_prev = n_cur
                y_prev = y_cur
                n_cur = 0
                y_cur = y
            k = -1
            if y_prev == y - 1:
                for i in range(n_prev):
                    j = prev[i]
                    if j >= 0 and out[j, 2] == x0 and out[j, 3] == x1:
                        k = j
                        prev[i] = -1  # one run per rectangle and row
                        break
            if k < 0:
                k = q
                out[q, 0] = y
                out[q, 2] = x0
                out[q, 3] = x1
                q += 1
            out[k, 1] = y + 1
            cur[n_cur] = k
            n_cur += 1
        rptr[t + 1] = q
    return out[:q].copy(), rptr


@njit(cache=True, nogil=True)
def eval_rects_sat_kernel(sat: NDArray[np.float64], rects: NDArray[np.int16], ptr: NDArray[np.int64],
                          ids: NDArray[np.int64], transforms: NDArray[np.float64], cx: float, cy: float,
                          outside_cost: float, out: NDArray[np.float64]) -> None:
    """:func:`eval_runs_grid_kernel` from a summed-area table, over rectangles
    (:func:`run_rectangles_kernel`). A run's rows and columns are the same integers as the run
    kernels' (the same expressions); a rectangle of template rows ``[y0, y1)`` covers the target
    rows ``[ya(y0), ya(y1))`` -- the union of its rows' own, since a row's end is the next row's
    start (the same expression) -- at the same columns, so it adds what its runs add, in four
    lookups instead of one difference per covered row and run.

    The sums are the run kernels' to the bit only when every term is an integer (XOR's ``A`` in
    {-1, +1}, an integer ``outside_cost``): any order of exact additions gives the same number.
    Callers use it only then (:func:`tracker_service.silhouette_distance.evaluate_templates`).

    Parameters
    ----------
    sat : (h + 1, w + 1) float64
        ``sat[y, x] = sum(A[:y, :x])``.
    rects : (Q, 4) int16
        ``(y_start, y_end, x_start, x_end)``.
    ptr : (T + 1,) int64
    ids : (n,) int64
    transforms : (n, G, 3) float64
    out : (n, G) float64
    Other parameters as :func:`eval_runs_grid_kernel`.
    """
    h = sat.shape[0] - 1
    w = sat.shape[1] - 1
    g_n = transforms.shape[1]
    for m in range(ids.shape[0]):
        t = ids[m]
        for g in range(g_n):
            dx = transforms[m, g, 0]
            dy = transforms[m, g, 1]
            s = transforms[m, g, 2]
            acc = 0.0
            for r in range(ptr[t], ptr[t + 1]):
                ur = np.uint64(r)
                ya = int(np.floor(cy + dy + s * (rects[ur, 0] - cy) + 0.5))
                yb = int(np.floor(cy + dy + s * (rects[ur, 1] - cy) + 0.5))
                xl = int(np.floor(cx + dx + s * (rects[ur, 2] - cx) + 0.5))
                xr = int(np.floor(cx + dx + s * (rects[ur, 3] - cx) + 0.5))
                if xr <= xl or yb <= ya:
                    continue
                if xl >= 0 and xr <= w and ya >= 0 and yb <= h:
                    ua = np.uint64(ya)
                    ub = np.uint64(yb)
                    ul = np.uint64(xl)
                    uq = np.uint64(xr)
                    acc += (sat[ub, uq] - sat[ub, ul]) - (sat[ua, uq] - sat[ua, ul])
                    continue
                cl = min(max(xl, 0), w)
                cr = min(max(xr, 0), w)
                ca = min(max(ya, 0), h)
                cb = min(max(yb, 0), h)
                acc += (sat[cb, cr] - sat[cb, cl]) - (sat[ca, cr] - sat[ca, cl])
                acc += outside_cost * ((yb - ya) * (xr - xl) - (cb - ca) * (cr - cl))
            out[m, g] = acc


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


# ------------------------------------------------------------------------------------------------
# Capsule silhouette rasteriser (tracker_service.silhouette_render). A projected tapered capsule is
# the convex hull of two circles; each image row meets it in one interval, found from the two
# circles and the two outer tangent segments. ``caps`` rows hold
# ``(x1, y1, r1, x2, y2, r2, z1, z2, R1, R2)``: circle centres and radii in pixels (OpenCV
# pixel-centre convention), the depth of each end's centre and its radius (metres); ``r1 <= 0``
# marks a capsule to skip.
# ------------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def capsule_hull_kernel(cap: NDArray[np.float64], hull: NDArray[np.float64]) -> int:
    """Outer tangent points of one projected capsule.

    Parameters
    ----------
    cap : (10,) float64
        ``(x1, y1, r1, x2, y2, r2, z1, z2, R1, R2)``.
    hull : (8,) float64
        Written with the tangent segments ``(ax1, ay1, ax2, ay2, bx1, by1, bx2, by2)``.

    Returns
    -------
    int
        0: skip the capsule; 1: circle 1 alone covers it; 2: circle 2 alone; 3: two circles and
        two tangent segments.
    """
    x1, y1, r1, x2, y2, r2 = cap[0], cap[1], cap[2], cap[3], cap[4], cap[5]
    if not (r1 > 0.0 and r2 > 0.0):
        return 0
    dx = x2 - x1
    dy = y2 - y1
    d = np.sqrt(dx * dx + dy * dy)
    if d <= abs(r1 - r2) + 1e-9:
        return 1 if r1 >= r2 else 2
    ux = dx / d
    uy = dy / d
    s = (r1 - r2) / d
    c = np.sqrt(max(1.0 - s * s, 0.0))
    for k in range(2):
        sign = 1.0 if k == 0 else -1.0
        mx = s * ux - sign * c * uy
        my = s * uy + sign * c * ux
        hull[4 * k + 0] = x1 + r1 * mx
        hull[4 * k + 1] = y1 + r1 * my
        hull[4 * k + 2] = x2 + r2 * mx
        hull[4 * k + 3] = y2 + r2 * my
    return 3


@njit(cache=True, nogil=True)
def capsule_span_kernel(cap: NDArray[np.float64], hull: NDArray[np.float64], kind: int,
                        y: float) -> tuple[float, float]:
    """Interval ``[lo, hi]`` (pixels) of a projected capsule on image row ``y``; ``lo > hi`` if empty."""
    lo = np.inf
    hi = -np.inf
    for k in range(2):
        if (kind == 1 and k == 1) or (kind == 2 and k == 0):
            continue
        cx = cap[3 * k]
        cy = cap[3 * k + 1]
        r = cap[3 * k + 2]
        ddy = y - cy
        if abs(ddy) <= r:
            w = np.sqrt(r * r - ddy * ddy)
            lo = min(lo, cx - w)
            hi = max(hi, cx + w)
    if kind == 3:
        for k in range(2):
            ax = hull[4 * k]
            ay = hull[4 * k + 1]
            bx = hull[4 * k + 2]
            by = hull[4 * k + 3]
            if (ay - y) * (by - y) <= 0.0 and ay != by:
                x = ax + (y - ay) * (bx - ax) / (by - ay)
                lo = min(lo, x)
                hi = max(hi, x)
    return lo, hi


@njit(cache=True, nogil=True)
def _capsule_rows(cap: NDArray[np.float64], height: int) -> tuple[int, int]:
    top = min(cap[1] - cap[2], cap[4] - cap[5])
    bot = max(cap[1] + cap[2], cap[4] + cap[5])
    return max(int(np.ceil(top)), 0), min(int(np.floor(bot)), height - 1)


@njit(cache=True, nogil=True)
def fill_capsules_kernel(caps: NDArray[np.float64], mask: NDArray[np.bool_]) -> None:
    """OR-fill projected capsules into a binary mask (pixel centres inside the hull).

    Parameters
    ----------
    caps : (C, 10) float64
        Projected capsules (see the section comment).
    mask : (H, W) bool
        Filled in place (not cleared first).
    """
    h, w = mask.shape
    hull = np.empty(8)
    for c in range(caps.shape[0]):
        kind = capsule_hull_kernel(caps[c], hull)
        if kind == 0:
            continue
        r0, r1 = _capsule_rows(caps[c], h)
        for i in range(r0, r1 + 1):
            lo, hi = capsule_span_kernel(caps[c], hull, kind, float(i))
            j0 = max(int(np.ceil(lo)), 0)
            j1 = min(int(np.floor(hi)), w - 1)
            for j in range(j0, j1 + 1):
                mask[i, j] = True


@njit(cache=True, nogil=True)
def fill_capsules_batch_kernel(caps: NDArray[np.float64], masks: NDArray[np.bool_]) -> None:
    """:func:`fill_capsules_kernel` over a batch: ``caps (N, C, 10)``, ``masks (N, H, W)`` (cleared here)."""
    for n in range(caps.shape[0]):
        masks[n, :, :] = False
        fill_capsules_kernel(caps[n], masks[n])


@njit(cache=True, nogil=True)
def label_capsules_kernel(caps: NDArray[np.float64], parts: NDArray[np.int64],
                          labels: NDArray[np.int8], zbuf: NDArray[np.float32], cover: NDArray[np.uint16],
                          visible: NDArray[np.int64], areas: NDArray[np.int64]) -> None:
    """Z-buffered part labels of projected capsules.

    The depth of a capsule at a pixel is that of its front surface: with ``t`` the pixel's clamped
    position along the projected axis, ``q`` its image distance from the axis point at ``t`` and
    ``rho``, ``R``, ``z`` the projected radius, radius and centre depth interpolated at ``t``,
    ``z - R sqrt(1 - (q / rho)^2)``.

    Parameters
    ----------
    caps : (C, 10) float64
        Projected capsules.
    parts : (C,) int64
        Part index (< 16) of each capsule.
    labels : (H, W) int8
        Written: -1 background, else the part in front. Must be filled with -1 on entry.
    zbuf : (H, W) float32
        Depth buffer, ``inf`` on entry.
    cover : (H, W) uint16
        Bit ``p`` set where part ``p`` covers the pixel; zeros on entry.
    visible, areas : (N_PARTS,) int64
        Written: pixels where each part is in front / covers the pixel regardless of occlusion.
    """
    h, w = labels.shape
    hull = np.empty(8)
    top, bot, left, right = h, -1, w, -1
    for c in range(caps.shape[0]):
        kind = capsule_hull_kernel(caps[c], hull)
        if kind == 0:
            continue
        x1, y1, x2, y2 = caps[c, 0], caps[c, 1], caps[c, 3], caps[c, 4]
        z1, z2 = caps[c, 6], caps[c, 7]
        rr1, rr2 = caps[c, 2], caps[c, 5]
        w1, w2 = caps[c, 8], caps[c, 9]
        ax = x2 - x1
        ay = y2 - y1
        l2 = ax * ax + ay * ay
        inv = 1.0 / l2 if l2 > 1e-12 else 0.0
        bit = np.uint16(1 << parts[c])
        lab = np.int8(parts[c])
        r0, r1 = _capsule_rows(caps[c], h)
        for i in range(r0, r1 + 1):
            lo, hi = capsule_span_kernel(caps[c], hull, kind, float(i))
            j0 = max(int(np.ceil(lo)), 0)
            j1 = min(int(np.floor(hi)), w - 1)
            if j1 < j0:
                continue
            top = min(top, i)
            bot = max(bot, i)
            left = min(left, j0)
            right = max(right, j1)
            for j in range(j0, j1 + 1):
                t = ((j - x1) * ax + (i - y1) * ay) * inv
                t = min(max(t, 0.0), 1.0)
                qx = j - (x1 + t * ax)
                qy = i - (y1 + t * ay)
                rho = rr1 + t * (rr2 - rr1)
                f = max(1.0 - (qx * qx + qy * qy) / (rho * rho), 0.0)
                z = np.float32(z1 + t * (z2 - z1) - (w1 + t * (w2 - w1)) * np.sqrt(f))
                cover[i, j] |= bit
                if z < zbuf[i, j]:
                    zbuf[i, j] = z
                    labels[i, j] = lab
    visible[:] = 0
    areas[:] = 0
    for i in range(top, bot + 1):
        for j in range(left, right + 1):
            lab = labels[i, j]
            if lab >= 0:
                visible[lab] += 1
            b = int(cover[i, j])
            p = 0
            while b:
                if b & 1:
                    areas[p] += 1
                b >>= 1
                p += 1


@njit(cache=True, nogil=True)
def capsule_runs_kernel(caps: NDArray[np.float64], height: int, width: int,
                        out: NDArray[np.int16]) -> int:
    """Horizontal runs of the union of projected capsules, without rasterising.

    Parameters
    ----------
    caps : (C, 10) float64
    height, width : int
        Image size (runs are clipped to it).
    out : (M, 3) int16
        Written with ``(y, x_start, x_end)`` runs (``x_end`` exclusive), sorted by ``y`` then ``x``;
        ``M >= height * C`` always suffices.

    Returns
    -------
    int
        Number of runs written.
    """
    n_caps = caps.shape[0]
    hulls = np.empty((n_caps, 8))
    kinds = np.empty(n_caps, np.int64)
    rows = np.empty((n_caps, 2), np.int64)
    top, bot = height, -1
    for c in range(n_caps):
        kinds[c] = capsule_hull_kernel(caps[c], hulls[c])
        r0, r1 = _capsule_rows(caps[c], height)
        rows[c, 0] = r0
        rows[c, 1] = r1
        if kinds[c] > 0 and r1 >= r0:
            top = min(top, r0)
            bot = max(bot, r1)
    lo_buf = np.empty(n_caps, np.int64)
    hi_buf = np.empty(n_caps, np.int64)
    n_out = 0
    for i in range(top, bot + 1):
        m = 0
        for c in range(n_caps):
            if kinds[c] == 0 or i < rows[c, 0] or i > rows[c, 1]:
                continue
            lo, hi = capsule_span_kernel(caps[c], hulls[c], kinds[c], float(i))
            j0 = max(int(np.ceil(lo)), 0)
            j1 = min(int(np.floor(hi)), width - 1)
            if j1 < j0:
                continue
            k = m  # insertion sort by start
            while k > 0 and lo_buf[k - 1] > j0:
                lo_buf[k] = lo_buf[k - 1]
                hi_buf[k] = hi_buf[k - 1]
                k -= 1
            lo_buf[k] = j0
            hi_buf[k] = j1
            m += 1
        k = 0
        while k < m:
            s = lo_buf[k]
            e = hi_buf[k]
            k += 1
            while k < m and lo_buf[k] <= e + 1:
                e = max(e, hi_buf[k])
                k += 1
            out[n_out, 0] = i
            out[n_out, 1] = s
            out[n_out, 2] = e + 1
            n_out += 1
    return n_out


@njit(cache=True, nogil=True)
def capsule_runs_batch_kernel(caps: NDArray[np.float64], height: int,
                              width: int) -> tuple[NDArray[np.int16], NDArray[np.int64]]:
    """:func:`capsule_runs_kernel` over ``caps (N, C, 10)``: packed ``data (R, 3) int16`` and ``ptr (N + 1,)``."""
    n = caps.shape[0]
    scratch = np.empty((height * caps.shape[1] + 1, 3), np.int16)
    data = np.empty((max(n * 64, 64), 3), np.int16)
    ptr = np.zeros(n + 1, np.int64)
    total = 0
    for p in range(n):
        k = capsule_runs_kernel(caps[p], height, width, scratch)
        if total + k > data.shape[0]:
            grown = np.empty((max(2 * data.shape[0], total + k), 3), np.int16)
            grown[:total] = data[:total]
            data = grown
        data[total:total + k] = scratch[:k]
        total += k
        ptr[p + 1] = total
    return data[:total].copy(), ptr

# ---- end of the capsule silhouette rasteriser ----


@njit(cache=True, nogil=True)
def lower_column_kernel(data: NDArray[np.int16], ptr: NDArray[np.int64], lower_frac: float,
                        out: NDArray[np.float64]) -> None:
    """Median pixel column of each template's lower part (rows at or below
    ``top + lower_frac * (bottom - top)``), as ``np.median`` of the pixels' x would give.

    Parameters
    ----------
    data : (R, 3) int16
        Runs ``(y, x_start, x_end)`` of all templates.
    ptr : (T + 1,) int64
    lower_frac : float
    out : (T,) float64
        Written with the medians (NaN for an empty template).
    """
    width = 1
    for r in range(data.shape[0]):
        width = max(width, int(data[r, 2]) + 1)
    hist = np.zeros(width + 1, np.int64)
    for t in range(ptr.shape[0] - 1):
        a, b = ptr[t], ptr[t + 1]
        if b <= a:
            out[t] = np.nan
            continue
        top = data[a, 0]
        bot = data[a, 0]
        for r in range(a, b):
            top = min(top, data[r, 0])
            bot = max(bot, data[r, 0])
        thr = top + lower_frac * (bot - top)
        hist[:] = 0
        n = 0
        for r in range(a, b):
            if data[r, 0] >= thr and data[r, 2] > data[r, 1]:
                x0 = max(int(data[r, 1]), 0)
                x1 = max(int(data[r, 2]), 0)
                hist[x0] += 1
                hist[x1] -= 1
                n += x1 - x0
        if n == 0:
            out[t] = np.nan
            continue
        k1 = (n - 1) // 2
        k2 = n // 2
        run = 0
        cum = 0
        v1 = -1.0
        v2 = -1.0
        for x in range(width):
            run += hist[x]
            if run <= 0:
                continue
            if v1 < 0 and cum + run > k1:
                v1 = x
            if cum + run > k2:
                v2 = x
                break
            cum += run
        out[t] = 0.5 * (v1 + v2)


@njit(cache=True, nogil=True)
def skin_cost_kernel(distance: NDArray[np.float32], samples: NDArray[np.float64], points: NDArray[np.float32],
                     rows: NDArray[np.int64], segments: NDArray[np.int64], hands: NDArray[np.int64],
                     visible: NDArray[np.float32], hand_parts: NDArray[np.int64], min_visible: np.float32,
                     places: NDArray[np.float64], cx: float, cy: float, sigma: float, cap: float, hidden: float,
                     cover_weight: float, radius: float, out: NDArray[np.float64]) -> None:
    """Skin cue of templates at placements: hand term plus ``cover_weight`` times the cover term
    (:func:`tracker_service.skin.hand_cost` + :func:`tracker_service.skin.cover_cost`, their
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
def foreground_kernel(frame: NDArray[np.uint8], chroma_mean: NDArray[np.float32], chroma_inv_var: NDArray[np.float32],
                      bright_mean: NDArray[np.float32], bright_std: NDArray[np.float32], chroma_threshold: float,
                      shadow_ratio: float, highlight_ratio: float, brightness_sigmas: float, dark_level: float,
                      out: NDArray[np.bool_]) -> None:
    """Per-pixel background test of :func:`tracker_service.background.raw_foreground`, fused.

    Same arithmetic in float32 as the numpy reference (chromaticity Mahalanobis distance, brightness
    ratio with its noise margin, dark pixels by brightness only).

    Parameters
    ----------
    frame : (H, W, 3) uint8
        BGR.
    chroma_mean, chroma_inv_var : (H, W, 2) float32
    bright_mean, bright_std : (H, W) float32
    chroma_threshold, shadow_ratio, highlight_ratio, brightness_sigmas, dark_level : float
    out : (H, W) bool
        Written.
    """
    h, w = out.shape
    eps = np.float32(1e-6)
    one = np.float32(1.0)
    thr = np.float32(chroma_threshold)
    lo = np.float32(shadow_ratio)
    hi = np.float32(highlight_ratio)
    ks = np.float32(brightness_sigmas)
    dark = np.float32(dark_level)
    three = np.float32(3.0)
    for y in range(h):
        for x in range(w):
            b0 = np.float32(frame[y, x, 0])
            g0 = np.float32(frame[y, x, 1])
            r0 = np.float32(frame[y, x, 2])
            s = b0 + g0 + r0
            den = max(s, eps)
            d1 = g0 / den - chroma_mean[y, x, 0]
            d2 = r0 / den - chroma_mean[y, x, 1]
            maha = np.sqrt(d1 * d1 * chroma_inv_var[y, x, 0] + d2 * d2 * chroma_inv_var[y, x, 1])
            bm = bright_mean[y, x]
            bmc = max(bm, one)
            b = s / three
            ratio = b / bmc
            margin = ks * bright_std[y, x] / bmc
            fg = (ratio < lo - margin) or (ratio > hi + margin)
            if not fg and bm > dark and b > dark and maha > thr:
                fg = True
            out[y, x] = fg


@njit(cache=True, nogil=True)
def leaf_prior_kernel(leaves: NDArray[np.int64], weights: NDArray[np.float64], nbr_idx: NDArray[np.int64],
                      nbr_dpart: NDArray[np.float32], inv_var: NDArray[np.float64], trans_ptr: NDArray[np.int64],
                      trans_idx: NDArray[np.int64], trans_p: NDArray[np.float32], hist_weight: float,
                      prior: NDArray[np.float64]) -> None:
    """Add the motion prior of the supported leaves to ``prior`` (eq. 13 with eq. 14's variances, and
    the transition histograms of eq. 5): the loop of :func:`tracker_service.tree_filter.predict_leaves`.

    Parameters
    ----------
    leaves : (M,) int64
    weights : (M,) float64
    nbr_idx : (NL, K) int64
        Pose-space neighbours of every leaf.
    nbr_dpart : (NL, K, N_PARTS) float32
        Their squared per-part pose differences.
    inv_var : (N_PARTS,) float64
        Inverse variances per part.
    trans_ptr, trans_idx, trans_p
        CSR transition histograms.
    hist_weight : float
    prior : (NL,) float64
        Accumulated into.
    """
    k = nbr_idx.shape[1]
    npart = inv_var.shape[0]
    g = np.empty(k)
    for m in range(leaves.shape[0]):
        leaf = leaves[m]
        w = weights[m]
        tot = 0.0
        for j in range(k):
            e = 0.0
            for p in range(npart):
                e += np.float64(nbr_dpart[leaf, j, p]) * inv_var[p]
            g[j] = np.exp(-0.5 * e)
            tot += g[j]
        a, b = trans_ptr[leaf], trans_ptr[leaf + 1]
        hw = hist_weight if b > a else 0.0
        f = w * (1.0 - hw) / tot
        for j in range(k):
            prior[nbr_idx[leaf, j]] += f * g[j]
        if hw != 0.0:
            for t in range(a, b):
                prior[trans_idx[t]] += w * hw * np.float64(trans_p[t])


@njit(cache=True, nogil=True)
def feet_cost_kernel(su: NDArray[np.int64], sv: NDArray[np.int64], feet: NDArray[np.float64], height: int,
                     width: int, cap: float, dead: float, forward: float, reverse: float) -> NDArray[np.float64]:
    """The shoe cue's cost of templates' feet (:func:`tracker_service.shoes.feet_cost`; numpy
    reference :func:`tracker_service.shoes.feet_cost_reference`).

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
        for p in range(n):
            near = np.inf
            for f in range(2):
                du, dv = feet[i, f, 0] - su[p], feet[i, f, 1] - sv[p]
                near = min(near, np.sqrt(du * du + dv * dv))
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
    :func:`tracker_service.shoes.shoe_mask`.

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

    Reference: :func:`tracker_service.appearance.propose_leaves` with
    :meth:`tracker_service.appearance.HeadingWindow.mask` (``sum (x^2 - 2 x mu) / var`` over every
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
        d = np.fmod(h - centre + np.pi, two_pi)  # the angle between them, in [-pi, pi)
        if d < 0.0:
            d += two_pi
        d -= np.pi
        if not (abs(d) <= half_width and abs(h) <= max_abs):  # NaN: outside
            out[i] = np.inf
            continue
        s = np.float32(0.0)
        for j in range(k):
            x = joints[i, j]
            s += x * (a[j] * x + b[j])
        out[i] = s
    return out


@njit(cache=True, nogil=True)
def _swing_into(ax: float, ay: float, az: float, bx: float, by: float, bz: float,
                out: NDArray[np.float64]) -> None:
    """The smallest rotation turning direction a onto direction b, written to ``out`` (3, 3).
    Reference: :func:`tracker_service.pose_refinement.swing_rotation`."""
    for i in range(3):
        for j in range(3):
            out[i, j] = 1.0 if i == j else 0.0
    na = np.sqrt(ax * ax + ay * ay + az * az)
    nb = np.sqrt(bx * bx + by * by + bz * bz)
    if not (na > 1e-12 and nb > 1e-12):
        return
    ux, uy, uz = ax / na, ay / na, az / na
    wx, wy, wz = bx / nb, by / nb, bz / nb
    cx, cy, cz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
    s = np.sqrt(cx * cx + cy * cy + cz * cz)
    c = ux * wx + uy * wy + uz * wz
    if s < 1e-12:
        if c > 0.0:
            return
        # antiparallel: pi about an axis perpendicular to u (the cross with the smallest axis of u)
        m = 0
        if abs(uy) < abs(ux):
            m = 1
        if abs(uz) < min(abs(ux), abs(uy)):
            m = 2
        e = np.zeros(3)
        e[m] = 1.0
        px, py, pz = uy * e[2] - uz * e[1], uz * e[0] - ux * e[2], ux * e[1] - uy * e[0]
        n = np.sqrt(px * px + py * py + pz * pz)
        k = (px / n, py / n, pz / n)
        for i in range(3):
            for j in range(3):
                out[i, j] = 2.0 * k[i] * k[j] - (1.0 if i == j else 0.0)
        return
    kx, ky, kz = cx / s, cy / s, cz / s
    kk = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    k2 = kk @ kk
    for i in range(3):
        for j in range(3):
            out[i, j] += s * kk[i, j] + (1.0 - c) * k2[i, j]


@njit(cache=True, nogil=True)
def refine_rotations_kernel(local: NDArray[np.float64], cam_rot: NDArray[np.float64], offsets: NDArray[np.float64],
                            parents: NDArray[np.int64], slots: NDArray[np.int64], child_ptr: NDArray[np.int64],
                            child_idx: NDArray[np.int64], target: NDArray[np.float64], gain: NDArray[np.float64],
                            weight: NDArray[np.float64], prior: float) -> NDArray[np.float64]:
    """The pose refinement's walk down the kinematic tree (reference:
    :func:`tracker_service.pose_refinement.refine_rotations`, same arguments plus the skeleton's
    ``parents`` (J,), rotation ``slots`` (J,) and children in CSR form ``child_ptr`` (J + 1,),
    ``child_idx``).

    Returns
    -------
    (R, 3, 3) float64
        The refined local rotations.
    """
    nj = parents.shape[0]
    r = cam_rot
    rt = np.ascontiguousarray(r.T)
    out = local.copy()
    glob_c = np.empty((nj, 3, 3))
    pos = np.zeros((nj, 3))
    turn = np.empty((3, 3))
    for j in range(nj):
        par = parents[j]
        slot = slots[j]
        if par < 0:
            glob_c[j] = rt @ local[slot]
        else:
            pos[j] = pos[par] + glob_c[par] @ offsets[j]
            if slot >= 0:
                glob_c[j] = glob_c[par] @ local[slot]
            else:
                glob_c[j] = glob_c[par]
        n = child_ptr[j + 1] - child_ptr[j]
        if n == 0:
            continue
        a = np.empty((n, 3))
        tgt = np.empty((n, 3))
        for q in range(n):
            c = child_idx[child_ptr[j] + q]
            a[q] = glob_c[j] @ offsets[c]
            for d in range(3):
                tgt[q, d] = a[q, d] + gain[c, d] * (target[c, d] - (pos[j, d] + a[q, d]))
        if n == 1:
            _swing_into(a[0, 0], a[0, 1], a[0, 2], tgt[0, 0], tgt[0, 1], tgt[0, 2], turn)
        else:
            h = np.zeros((3, 3))
            spread = 0.0
            for q in range(n):
                w = weight[child_idx[child_ptr[j] + q]]
                spread += w * (a[q, 0] * a[q, 0] + a[q, 1] * a[q, 1] + a[q, 2] * a[q, 2])
                for d in range(3):
                    for e in range(3):
                        h[d, e] += w * a[q, d] * tgt[q, e]
            for d in range(3):
                h[d, d] += prior * spread
            u, _, vt = np.linalg.svd(h)
            v = np.ascontiguousarray(vt.T)
            ut = np.ascontiguousarray(u.T)
            if np.linalg.det(v @ ut) < 0.0:
                for d in range(3):
                    v[d, 2] = -v[d, 2]
            turn[:, :] = v @ ut
        glob_c[j] = turn @ glob_c[j]
        if par < 0:
            out[slot] = r @ glob_c[j]
        else:
            out[slot] = np.ascontiguousarray(glob_c[par].T) @ glob_c[j]
    return out
