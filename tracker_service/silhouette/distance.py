"""Silhouette distances between an observed silhouette S and model templates T (Okada & Stenger
§2.2): XOR (eq. 7), core-weighted XOR (eq. 8-9) and normalised core-weighted XOR (eq. 10-11).

Templates are stored as horizontal runs ``(y, x_start, x_end)`` (``x_end`` exclusive) -- the
left/right contour points of every row (Fig. 5). A template is evaluated at a 2D offset
``(dx, dy)`` and scale ``s`` about a centre ``(cx, cy)`` without re-rendering: template pixel
``(x, y)`` lands on ``(cx + dx + s (x - cx), cy + dy + s (y - cy))``. Its distance is

    d = ( sum_runs I(y, x_r) - I(y, x_l) + B ) / |w|          (eq. 11 and eq. 12)

with the horizontal integral image ``I`` of :mod:`tracker_service.silhouette.features`. Template pixels
that fall outside the image cost ``outside_cost`` each (no observation there; by default the
level's width / 16, a typical ``D(S)`` for a limb pushed off-screen).

:func:`evaluate_templates` is the numba kernel path; :func:`evaluate_templates_reference` the
plain numpy reference (it rasterises each transformed template and sums ``A`` densely).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from tracker_service.silhouette._kernels import eval_rects_sat_kernel, eval_runs_grid_kernel, run_rectangles_kernel
from tracker_service.silhouette.features import Distance, LevelFeatures, core_weight

__all__ = [
    "RunSet",
    "dense_distance",
    "evaluate_template_grid",
    "evaluate_templates",
    "evaluate_templates_reference",
    "mask_to_runs",
    "placed_run",
    "runs_to_mask",
]


def mask_to_runs(mask: NDArray[np.bool_]) -> NDArray[np.int16]:
    """Horizontal runs of a binary mask.

    Parameters
    ----------
    mask : (H, W) bool

    Returns
    -------
    (R, 3) int16
        ``(y, x_start, x_end)`` per run, ``x_end`` exclusive, sorted by ``y`` then ``x``.
    """
    m = np.asarray(mask, dtype=np.int8)
    pad = np.zeros((m.shape[0], m.shape[1] + 2), np.int8)
    pad[:, 1:-1] = m
    d = np.diff(pad, axis=1)
    ys, xs = np.nonzero(d == 1)
    ye, xe = np.nonzero(d == -1)
    assert np.array_equal(ys, ye)
    return np.stack([ys, xs, xe], axis=1).astype(np.int16)


def runs_to_mask(runs: NDArray[np.int16], shape: tuple[int, int]) -> NDArray[np.bool_]:
    """Rasterise runs back into a ``(H, W)`` bool mask (runs outside are clipped)."""
    out = np.zeros(shape, bool)
    for y, x0, x1 in runs:
        if 0 <= y < shape[0]:
            out[y, max(int(x0), 0): max(min(int(x1), shape[1]), 0)] = True
    return out


class RunSet:
    """Many templates' runs packed into flat arrays (the template database's storage form).

    Parameters
    ----------
    runs : list of (R_i, 3) int16
        Runs of each template.

    Attributes
    ----------
    data : (sum R_i, 3) int16
    ptr : (T + 1,) int64
        Runs of template ``i`` are ``data[ptr[i]:ptr[i + 1]]``. Not to be changed after
        construction: :meth:`rectangles` caches what it derives from them.
    """

    def __init__(self, runs: list[NDArray[np.int16]] | None = None, *, data: NDArray[np.int16] | None = None,
                 ptr: NDArray[np.int64] | None = None) -> None:
        if data is not None and ptr is not None:
            self.data = np.ascontiguousarray(data, dtype=np.int16)
            self.ptr = np.ascontiguousarray(ptr, dtype=np.int64)
        else:
            runs = runs or []
            self.ptr = np.zeros(len(runs) + 1, np.int64)
            self.ptr[1:] = np.cumsum([len(r) for r in runs])
            self.data = (np.concatenate(runs).astype(np.int16) if runs and self.ptr[-1]
                         else np.zeros((0, 3), np.int16))
        if self.data.ndim != 2 or self.data.shape[1] != 3 or self.ptr[-1] != len(self.data):
            raise ValueError("inconsistent run set")
        self._rects: tuple[NDArray[np.int16], NDArray[np.int64]] | None = None

    def __len__(self) -> int:
        return len(self.ptr) - 1

    def runs(self, i: int) -> NDArray[np.int16]:
        return self.data[self.ptr[i]: self.ptr[i + 1]]

    def rectangles(self) -> tuple[NDArray[np.int16], NDArray[np.int64]]:
        """The runs merged into rectangles (:func:`run_rectangles`), computed on first use and kept.

        Returns
        -------
        rects : (Q, 4) int16
            ``(y_start, y_end, x_start, x_end)``.
        rect_ptr : (T + 1,) int64
        """
        cols, ptr = self.rectangle_columns()
        return cols.T, ptr

    def rectangle_columns(self) -> tuple[NDArray[np.int16], NDArray[np.int64]]:
        """:meth:`rectangles` as four contiguous columns, the layout the summed-area kernel reads
        (the rectangles are kept in this one copy; :meth:`rectangles` is its transposed view).

        Returns
        -------
        rect_cols : (4, Q) int16
            Rows ``y_start, y_end, x_start, x_end``.
        rect_ptr : (T + 1,) int64
        """
        if self._rects is None:
            rects, ptr = run_rectangles(self.data, self.ptr)
            self._rects = (rects.T, ptr)  # the kernel's own (4, Q) array
        return self._rects


def run_rectangles(data: NDArray[np.int16], ptr: NDArray[np.int64]) -> tuple[NDArray[np.int16], NDArray[np.int64]]:
    """Each template's runs merged into rectangles: a run continues the rectangle of the row above
    when that row has a run with the same columns (about half the runs of the database's templates
    do). The summed-area kernel adds a rectangle in four lookups, as it adds one run (numba:
    :func:`tracker_service.silhouette._kernels.run_rectangles_kernel`; reference: :func:`run_rectangles_reference`).

    Parameters
    ----------
    data : (R, 3) int16
        Runs ``(y, x_start, x_end)``, each template's rows in increasing order.
    ptr : (T + 1,) int64

    Returns
    -------
    rects : (Q, 4) int16
        ``(y_start, y_end, x_start, x_end)``: rows ``[y_start, y_end)``, columns ``[x_start, x_end)``
        (the transposed view of the kernel's column-wise ``(4, Q)`` array).
    rect_ptr : (T + 1,) int64
    """
    d = np.ascontiguousarray(data, np.int16)
    p = np.ascontiguousarray(ptr, np.int64)
    if d.ndim != 2 or d.shape[1] != 3 or p.ndim != 1 or len(p) < 1 or p[0] != 0 or p[-1] != len(d) \
            or np.any(np.diff(p) < 0):
        raise ValueError(f"runs must be (R, 3) with a pointer array ending at R, got {d.shape} and {p.shape}")
    if len(d) and (int(d[:, 0].min()) < 0 or int(d[:, 0].max()) >= np.iinfo(np.int16).max):
        raise ValueError("run rows must be in [0, 32767) (a rectangle's end row is stored as int16)")
    cols, rptr = run_rectangles_kernel(d, p)
    return cols.T, rptr


def run_rectangles_reference(runs: NDArray[np.int16]) -> NDArray[np.int16]:
    """:func:`run_rectangles` of one template in plain Python (the same merge, the same order).

    Parameters
    ----------
    runs : (R, 3) int16
        ``(y, x_start, x_end)``, rows in increasing order.

    Returns
    -------
    (Q, 4) int16
        ``(y_start, y_end, x_start, x_end)``.
    """
    rects: list[list[int]] = []
    prev: list[int] = []
    cur: list[int] = []
    y_cur = y_prev = -2
    for y, x0, x1 in np.asarray(runs, np.int64):
        if y != y_cur:
            prev, cur, y_prev, y_cur = cur, [], y_cur, int(y)
        k = next((j for j in prev if y_prev == y - 1 and rects[j][2:] == [x0, x1]), -1)
        if k >= 0:
            prev.remove(k)
        else:
            k = len(rects)
            rects.append([int(y), int(y) + 1, int(x0), int(x1)])
        rects[k][1] = int(y) + 1
        cur.append(k)
    return np.array(rects, np.int16).reshape(-1, 4)


def _exact_sat(feat: LevelFeatures, outside_cost: float) -> NDArray[np.float64] | None:
    """The level's summed-area table where the summed-area kernel gives the row kernel's sums to
    the bit (integer ``A``, XOR, and an integer outside cost small enough that every sum stays an
    exact float64 integer); otherwise None."""
    oc = float(outside_cost)
    return feat.sat if feat.sat is not None and oc.is_integer() and abs(oc) <= 2.0**20 else None


def evaluate_templates(feat: LevelFeatures, runset: RunSet, ids: NDArray[np.int64],
                       transforms: NDArray[np.float64], center: tuple[float, float],
                       outside_cost: float | None = None) -> NDArray[np.float64]:
    """Distances of templates at given offsets and scales (numba kernel).

    Parameters
    ----------
    feat : LevelFeatures
        Observation at this pyramid level.
    runset : RunSet
        Templates at this level.
    ids : (M,) int64
        Template index of each evaluation.
    transforms : (M, 3) float64
        ``(dx, dy, s)`` of each evaluation, pixels of this level.
    center : (float, float)
        ``(cx, cy)``, the scaling centre, pixels of this level.
    outside_cost : float, optional
        Cost per template pixel outside the image.

    Returns
    -------
    (M,) float64
        Distances ``d(S, T)``.
    """
    tr = np.asarray(transforms, np.float64).reshape(-1, 1, 3)  # one placement per template
    return evaluate_template_grid(feat, runset, ids, tr, center, outside_cost)[:, 0]


def evaluate_template_grid(feat: LevelFeatures, runset: RunSet, ids: NDArray[np.int64],
                           transforms: NDArray[np.float64], center: tuple[float, float],
                           outside_cost: float | None = None) -> NDArray[np.float64]:
    """:func:`evaluate_templates` for a grid of placements per template (each template's runs are
    read once for its whole grid; the same numbers).

    Parameters
    ----------
    ids : (n,) int64
        Template of each group.
    transforms : (n, G, 3) float64
        ``(dx, dy, s)`` of each evaluation, pixels of this level.
    Other parameters as :func:`evaluate_templates`.

    Returns
    -------
    (n, G) float64
    """
    oc = feat.shape[1] / 16.0 if outside_cost is None else float(outside_cost)
    tr = np.ascontiguousarray(transforms, np.float64)
    out = np.empty(tr.shape[:2])
    idx = np.ascontiguousarray(ids, np.int64)
    if (sat := _exact_sat(feat, oc)) is not None:
        cols, rptr = runset.rectangle_columns()
        eval_rects_sat_kernel(sat, cols, rptr, idx, tr, float(center[0]), float(center[1]), oc, out)
    else:
        eval_runs_grid_kernel(feat.integral, runset.data, runset.ptr, idx, tr, float(center[0]), float(center[1]),
                              oc, out)
    out += feat.b
    out /= feat.window_area
    return out


def placed_run(y: int, x0: int, x1: int, dx: float, dy: float, s: float, cx: float,
               cy: float) -> tuple[int, int, int, int]:
    """Rows ``[ya, yb)`` and columns ``[xl, xr)`` a run ``(y, x0, x1)`` covers when its template is
    placed at ``(dx, dy, s)`` about the centre ``(cx, cy)`` (the kernels' rounding, eq. 12)."""
    ya = int(np.floor(cy + dy + s * (y - cy) + 0.5))
    yb = int(np.floor(cy + dy + s * (y + 1 - cy) + 0.5))
    xl = int(np.floor(cx + dx + s * (x0 - cx) + 0.5))
    xr = int(np.floor(cx + dx + s * (x1 - cx) + 0.5))
    return ya, yb, xl, xr


def _transformed_mask(runs: NDArray[np.int16], shape: tuple[int, int], dx: float, dy: float, s: float,
                      cx: float, cy: float) -> tuple[NDArray[np.bool_], int]:
    """Rasterise transformed runs exactly as the kernel does; returns (mask, outside pixel count)."""
    h, w = shape
    m = np.zeros(shape, bool)
    outside = 0
    for y, x0, x1 in runs.astype(np.int64):
        ya, yb, xl, xr = placed_run(y, x0, x1, dx, dy, s, cx, cy)
        for yy in range(ya, yb):
            if xr <= xl:
                continue
            if not 0 <= yy < h:
                outside += xr - xl
                continue
            cl, cr = min(max(xl, 0), w), min(max(xr, 0), w)
            outside += (xr - xl) - (cr - cl)
            m[yy, cl:cr] = True
    return m, outside


def evaluate_templates_reference(feat: LevelFeatures, a_image: NDArray[np.float32], runset: RunSet,
                                 ids: NDArray[np.int64], transforms: NDArray[np.float64],
                                 center: tuple[float, float], outside_cost: float | None = None) -> NDArray[np.float64]:
    """Plain-numpy reference of :func:`evaluate_templates`: rasterise, then sum ``A`` densely.

    Parameters
    ----------
    a_image : (h, w) float32
        The per-pixel image ``A`` of this level (``features.match_image``).
    Other parameters as :func:`evaluate_templates`.
    """
    oc = feat.shape[1] / 16.0 if outside_cost is None else float(outside_cost)
    out = np.empty(len(ids))
    for k, (i, (dx, dy, s)) in enumerate(zip(ids, transforms, strict=True)):
        m, outside = _transformed_mask(runset.runs(int(i)), feat.shape, dx, dy, s, center[0], center[1])
        out[k] = (float(a_image[m].sum(dtype=np.float64)) + oc * outside + feat.b) / feat.window_area
    return out


def dense_distance(observed: NDArray[np.bool_], template: NDArray[np.bool_], distance: Distance = "nwxor",
                   alpha: float = 5.0, beta: float = 1.0, window_area: float | None = None) -> float:
    """The definition, pixel by pixel: eq. 7 (XOR), eq. 8 with eq. 9 (cwXOR) or with eq. 10
    (nwXOR): ``sum_k XOR(S, T)(k) g(k) / |w|``, before the rewriting of eq. 11.

    Parameters
    ----------
    observed, template : (H, W) bool
    distance : {'xor', 'cwxor', 'nwxor'}
    alpha, beta : float
    window_area : float, optional
        ``|w|`` (default: the image area).
    """
    s = np.asarray(observed, bool)
    t = np.asarray(template, bool)
    d_s, inner = core_weight(s, distance, alpha, beta)
    g = d_s + inner  # eq. 9 / eq. 10 (for XOR: 1 everywhere)
    total = float(np.where(s != t, g, 0.0).sum(dtype=np.float64))
    return total / (s.size if window_area is None else window_area)
