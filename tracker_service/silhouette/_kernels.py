"""Numba kernels of :mod:`tracker_service.silhouette`. Each has a plain-numpy reference beside the code
that uses it, and a test holds the two equal."""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

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
    path of :func:`tracker_service.silhouette.features.preprocess`; every sum is an exact integer).

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
    rectangle, in the order the rectangles are started. Inputs as
    :func:`tracker_service.silhouette.distance.run_rectangles` (which checks them); the rectangles
    come out column-wise, ``(4, Q)`` (the layout :func:`eval_rects_sat_kernel` reads)."""
    out = np.empty((4, data.shape[0]), np.int16)
    rptr = np.zeros(ptr.shape[0], np.int64)
    most = 1  # a template's runs: a bound on one row's (the whole database's would take ~200 MB)
    for t in range(ptr.shape[0] - 1):
        most = max(most, ptr[t + 1] - ptr[t])
    prev = np.empty(most, np.int64)  # rectangles open in the previous row
    cur = np.empty(most, np.int64)
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
                    if j >= 0 and out[2, j] == x0 and out[3, j] == x1:
                        k = j
                        prev[i] = -1  # one run per rectangle and row
                        break
            if k < 0:
                k = q
                out[0, q] = y
                out[2, q] = x0
                out[3, q] = x1
                q += 1
            out[1, k] = y + 1
            cur[n_cur] = k
            n_cur += 1
        rptr[t + 1] = q
    return out[:, :q].copy(), rptr


@njit(cache=True, nogil=True)
def eval_rects_sat_kernel(sat: NDArray[np.float64], rect_cols: NDArray[np.int16], ptr: NDArray[np.int64],
                          ids: NDArray[np.int64], transforms: NDArray[np.float64], cx: float, cy: float,
                          outside_cost: float, out: NDArray[np.float64]) -> None:
    """:func:`eval_runs_grid_kernel` from a summed-area table, over rectangles
    (:func:`run_rectangles_kernel`). A run's rows and columns are the same integers as the run
    kernels' (the same expressions); a rectangle of template rows ``[y0, y1)`` covers the target
    rows ``[ya(y0), ya(y1))`` -- the union of its rows' own, since a row's end is the next row's
    start (the same expression) -- at the same columns, so it adds what its runs add, in four
    lookups instead of one difference per covered row and run.

    Each placement takes two passes over its template's rectangles: the placed corners of all of
    them first (one branch-free loop over the four coordinate columns, which the compiler turns into
    vector instructions: the rounding was most of the time), then the lookups.

    The sums are the run kernels' to the bit only when every term is an integer (XOR's ``A`` in
    {-1, +1}, an integer ``outside_cost``): any order of exact additions gives the same number.
    Callers use it only then (:func:`tracker_service.silhouette.distance.evaluate_templates`).

    Parameters
    ----------
    sat : (h + 1, w + 1) float64
        ``sat[y, x] = sum(A[:y, :x])``.
    rect_cols : (4, Q) int16
        Rows ``y_start, y_end, x_start, x_end`` of the rectangles (the columns of
        :func:`run_rectangles_kernel`'s output, each contiguous).
    ptr : (T + 1,) int64
    ids : (n,) int64
    transforms : (n, G, 3) float64
    out : (n, G) float64
    Other parameters as :func:`eval_runs_grid_kernel`.
    """
    h = sat.shape[0] - 1
    w = sat.shape[1] - 1
    g_n = transforms.shape[1]
    most = 1
    for m in range(ids.shape[0]):
        most = max(most, ptr[ids[m] + 1] - ptr[ids[m]])
    ya = np.empty(most, np.int32)
    yb = np.empty(most, np.int32)
    xl = np.empty(most, np.int32)
    xr = np.empty(most, np.int32)
    y0 = rect_cols[0]
    y1 = rect_cols[1]
    x0 = rect_cols[2]
    x1 = rect_cols[3]
    for m in range(ids.shape[0]):
        t = ids[m]
        a = ptr[t]
        n = ptr[t + 1] - a
        for g in range(g_n):
            dx = transforms[m, g, 0]
            dy = transforms[m, g, 1]
            s = transforms[m, g, 2]
            for i in range(n):  # cy + dy + s * (y - cy) + 0.5, as the run kernels round it
                ya[i] = np.int32(np.floor(cy + dy + s * (y0[a + i] - cy) + 0.5))
                yb[i] = np.int32(np.floor(cy + dy + s * (y1[a + i] - cy) + 0.5))
                xl[i] = np.int32(np.floor(cx + dx + s * (x0[a + i] - cx) + 0.5))
                xr[i] = np.int32(np.floor(cx + dx + s * (x1[a + i] - cx) + 0.5))
            acc = 0.0
            for i in range(n):
                ta = np.int64(ya[i])
                tb = np.int64(yb[i])
                tl = np.int64(xl[i])
                tr = np.int64(xr[i])
                if tr <= tl or tb <= ta:
                    continue
                if tl >= 0 and tr <= w and ta >= 0 and tb <= h:
                    acc += (sat[tb, tr] - sat[tb, tl]) - (sat[ta, tr] - sat[ta, tl])
                    continue
                cl = min(max(tl, 0), w)
                cr = min(max(tr, 0), w)
                ca = min(max(ta, 0), h)
                cb = min(max(tb, 0), h)
                acc += (sat[cb, cr] - sat[cb, cl]) - (sat[ca, cr] - sat[ca, cl])
                acc += outside_cost * ((tb - ta) * (tr - tl) - (cb - ca) * (cr - cl))
            out[m, g] = acc


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
def foreground_kernel(frame: NDArray[np.uint8], chroma_mean: NDArray[np.float32], chroma_inv_var: NDArray[np.float32],
                      bright_mean: NDArray[np.float32], bright_std: NDArray[np.float32], chroma_threshold: float,
                      shadow_ratio: float, highlight_ratio: float, brightness_sigmas: float, dark_level: float,
                      out: NDArray[np.bool_], gain: float = 1.0) -> None:
    """Per-pixel background test of :func:`tracker_service.silhouette.background.raw_foreground`, fused.

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
    gain : float
        The frame's exposure over the model's (:func:`tracker_service.silhouette.background.exposure_gain`):
        the brightness ratio is taken to ``gain`` times the model's brightness.
    """
    h, w = out.shape
    eps = np.float32(1e-6)
    g = np.float32(gain)
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
            ratio = b / (bmc * g)
            margin = ks * bright_std[y, x] / bmc
            fg = (ratio < lo - margin) or (ratio > hi + margin)
            if not fg and bm > dark and b > dark and maha > thr:
                fg = True
            out[y, x] = fg


@njit(cache=True, nogil=True, error_model="numpy")  # no zero-division checks: the divisors are floored
def update_background_kernel(frame: NDArray[np.uint8], foreground: NDArray[np.bool_], rate: float,
                             chroma_mean: NDArray[np.float32], chroma_inv_var: NDArray[np.float32],
                             bright_mean: NDArray[np.float32], bright_std: NDArray[np.float32], row0: int = 0,
                             row_step: int = 1) -> None:
    """The running mean and variance update of
    :func:`tracker_service.silhouette.background.update_background`, in place, in one pass; pixels in
    ``foreground`` are left as they are. Same float32 arithmetic as the numpy reference.

    Parameters
    ----------
    frame : (H, W, 3) uint8
        BGR, smoothed as the model's frames.
    foreground : (H, W) bool
    rate : float
    chroma_mean, chroma_inv_var : (H, W, 2) float32
    bright_mean, bright_std : (H, W) float32
    row0, row_step : int
        Only rows ``row0, row0 + row_step, ...`` are updated.
    """
    h, w = foreground.shape
    r = np.float32(rate)
    c_floor = np.float32(0.004 * 0.004)
    b_floor = np.float32(4.0)
    third = np.float32(3.0)
    eps = np.float32(1e-6)
    for y in range(row0, h, row_step):
        for x in range(w):
            if foreground[y, x]:
                continue
            bl = np.float32(frame[y, x, 0])
            g = np.float32(frame[y, x, 1])
            rd = np.float32(frame[y, x, 2])
            s = bl + g + rd
            inv_s = max(s, eps)
            for k in range(2):
                c = (g if k == 0 else rd) / inv_s
                cm = chroma_mean[y, x, k] + r * (c - chroma_mean[y, x, k])
                c_var = np.float32(1.0) / chroma_inv_var[y, x, k]
                d = c - cm
                c_var = c_var + r * (d * d - c_var)
                chroma_mean[y, x, k] = cm
                chroma_inv_var[y, x, k] = np.float32(1.0) / max(c_var, c_floor)
            b = s / third
            bm = bright_mean[y, x] + r * (b - bright_mean[y, x])
            var = bright_std[y, x] * bright_std[y, x]
            db = b - bm
            var = var + r * (db * db - var)
            bright_mean[y, x] = bm
            bright_std[y, x] = np.sqrt(max(var, b_floor))
