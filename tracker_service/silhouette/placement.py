"""Global position (Okada & Stenger §2: "3D global position" in the state) as an image placement.

Templates are rendered with the subject's root at the reference spot (world ``x = z = 0``). A
subject elsewhere on the floor appears shifted by ``(dx, dy)`` and scaled by ``s`` about the
principal point (exactly so for a level camera: ``s = d_ref / d``). This module converts between
that placement and the world root position, and measures a placement directly from a silhouette
(its foot line gives the scale, its column median the shift).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from tracker_service.camera import Camera
from tracker_service.silhouette._kernels import lower_column_kernel
from tracker_service.silhouette.distance import RunSet, runs_to_mask

__all__ = [
    "LOWER_FRAC",
    "TOE_AHEAD_M",
    "feet_in_view",
    "feet_scale",
    "height_scale",
    "lower_body_column",
    "lower_body_column_reference",
    "observed_placement",
    "placement_columns",
    "placement_rows",
    "placement_to_root",
    "reference_floor_row",
    "scaled_placement",
    "template_bottoms",
    "template_columns",
    "template_columns_reference",
]


#: Where the lowest silhouette point of a person standing at the reference spot touches the floor:
#: the toe tips, 16 cm in front of the root for the family's adult men facing the camera (their
#: standing templates' lowest row; women's are 1 pixel higher, children's 2 at 3 m). The earlier
#: 9 cm (the toe joint) put every observed placement 2.6 % too large.
TOE_AHEAD_M = 0.16


#: The body's centre column is the median column of the silhouette below this fraction of its
#: height (legs rarely swing as far as arms).
LOWER_FRAC = 0.45


def lower_body_column(mask: NDArray[np.bool_]) -> float:
    """Median column of a silhouette's lower part (:data:`LOWER_FRAC`); NaN when empty.

    Parameters
    ----------
    mask : (H, W) bool

    Returns
    -------
    float
    """
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0:
        return float("nan")
    top, bottom = int(rows[0]), int(rows[-1])
    first = int(np.ceil(top + LOWER_FRAC * (bottom - top)))
    # the median of the lower pixels' columns from a column histogram (the reference sorts the
    # pixels: 10x slower, the same value)
    cum = np.cumsum(np.count_nonzero(mask[first: bottom + 1], axis=0))
    n = int(cum[-1])
    lo = int(np.searchsorted(cum, (n + 1) // 2))
    hi = int(np.searchsorted(cum, n // 2 + 1))
    return 0.5 * (lo + hi)


def lower_body_column_reference(mask: NDArray[np.bool_]) -> float:
    """Plain :func:`lower_body_column`: ``np.median`` of the lower pixels' columns (for tests)."""
    ys, xs = np.nonzero(mask)
    if len(ys) == 0:
        return float("nan")
    top = ys.min()
    lower = ys >= top + LOWER_FRAC * (ys.max() - top)
    return float(np.median(xs[lower]))


def template_columns(runs: RunSet, level_scale: float) -> NDArray[np.float64]:
    """:func:`lower_body_column` of every template of a run set, in full-resolution pixels.

    The per-template counterpart of the observed column: a template whose arm hangs on one side
    has its column off the root's, and :func:`observed_placement`'s shift is corrected by that
    (see :func:`tracker_service.estimators.tree_filter.filter.step`).

    Parameters
    ----------
    runs : RunSet
        Templates at a pyramid level.
    level_scale : float
        That level's pixel scale relative to full resolution.

    Returns
    -------
    (T,) float64
        Column (full-resolution pixel index, reference placement); NaN for an empty template.
    """
    out = np.empty(len(runs))
    lower_column_kernel(np.ascontiguousarray(runs.data), np.ascontiguousarray(runs.ptr), LOWER_FRAC, out)
    return (out + 0.5) / level_scale - 0.5


def template_columns_reference(runs: RunSet, level_scale: float, shape: tuple[int, int]) -> NDArray[np.float64]:
    """Plain-numpy :func:`template_columns` (rasterises every template; for tests)."""
    col = np.array([lower_body_column(runs_to_mask(runs.runs(i), shape)) for i in range(len(runs))])
    return (col + 0.5) / level_scale - 0.5


def placement_columns(level_runs: tuple[RunSet, ...], level_scale: tuple[float, ...], camera: Camera
                      ) -> tuple[tuple[NDArray[np.float64], ...], float]:
    """The ``level_column`` and ``ref_column`` fields of a
    :class:`~tracker_service.estimators.tree_filter.filter.FilterDB`.

    Parameters
    ----------
    level_runs : tuple of RunSet
        Node templates per level.
    level_scale : tuple of float
    camera : Camera
        The templates' camera.

    Returns
    -------
    level_column : tuple of (n_L,) float64
    ref_column : float
    """
    cols = tuple(template_columns(r, sc) for r, sc in zip(level_runs, level_scale, strict=True))
    return cols, float(camera.project(np.zeros(3))[0])


def template_bottoms(runs: RunSet, level_scale: float) -> NDArray[np.float64]:
    """Lowest row of every template of a run set, in full-resolution pixels (reference placement).

    A template whose feet are off the floor (a leap, a running stride, a raised knee) has its
    lowest row above :func:`reference_floor_row`; the observed feet line then means a larger
    scale for it than for a standing template (see :func:`tracker_service.estimators.tree_filter.filter.step`).

    Parameters
    ----------
    runs : RunSet
    level_scale : float

    Returns
    -------
    (T,) float64
        Row index; NaN for an empty template.
    """
    return _extreme_rows(runs, level_scale, np.maximum)


def template_tops(runs: RunSet, level_scale: float) -> NDArray[np.float64]:
    """Highest (smallest) row of every template of a run set, full-resolution pixels; with
    :func:`template_bottoms`, the template's height in the image (leap-invariant, unlike the feet
    line).

    Returns
    -------
    (T,) float64
        Row index; NaN for an empty template.
    """
    return _extreme_rows(runs, level_scale, np.minimum)


def _extreme_rows(runs: RunSet, level_scale: float, op: np.ufunc) -> NDArray[np.float64]:
    ptr = np.asarray(runs.ptr, np.int64)
    rows = np.asarray(runs.data[:, 0], np.float64)
    out = np.full(len(ptr) - 1, np.nan)
    full = ptr[1:] > ptr[:-1]
    if rows.size:
        out[full] = op.reduceat(rows, ptr[:-1][full])
    return (out + 0.5) / level_scale - 0.5


def placement_rows(level_runs: tuple[RunSet, ...], level_scale: tuple[float, ...], camera: Camera
                   ) -> tuple[tuple[NDArray[np.float64], ...], tuple[NDArray[np.float64], ...], float]:
    """The ``level_bottom``, ``level_top`` and ``ref_bottom`` fields of a
    :class:`~tracker_service.estimators.tree_filter.filter.FilterDB`: each node's lowest and highest template rows and
    the floor row a standing template's lowest row lies on."""
    pairs = tuple(zip(level_runs, level_scale, strict=True))
    bottoms = tuple(template_bottoms(r, sc) for r, sc in pairs)
    tops = tuple(template_tops(r, sc) for r, sc in pairs)
    return bottoms, tops, reference_floor_row(camera)


def silhouette_rows(mask: NDArray[np.bool_]) -> NDArray[np.float64] | None:
    """``(top, bottom)`` rows of a silhouette (None when empty)."""
    ys = np.flatnonzero(mask.any(axis=1))
    return None if len(ys) == 0 else np.array([float(ys[0]), float(ys[-1])])


def feet_in_view(mask: NDArray[np.bool_], margin_px: int = 2) -> bool:
    """Whether the silhouette's lowest row is inside the image (the feet line measures depth only
    then; a person close to the camera has the feet cut off by the bottom border)."""
    ys = np.flatnonzero(mask.any(axis=1))
    return bool(len(ys)) and int(ys[-1]) < mask.shape[0] - margin_px


def reference_floor_row(camera: Camera) -> float:
    """Image row of the lowest silhouette point of a person standing at the reference spot."""
    return float(camera.project(np.array([0.0, 0.0, TOE_AHEAD_M]))[1])


def observed_placement(mask: NDArray[np.bool_], camera: Camera, foot_margin_px: float = 1.5
                       ) -> NDArray[np.float64] | None:
    """Placement ``(dx, dy, s)`` measured from a full-resolution silhouette.

    Parameters
    ----------
    mask : (H, W) bool
    camera : Camera
        The templates' camera (its size must match the mask).
    foot_margin_px : float
        Pixels between the lowest silhouette row and the floor contact (foot sole thickness).

    Returns
    -------
    (3,) float64 or None
        None for an empty silhouette, one whose feet are above the horizon or cut off by the
        image's bottom border.
    """
    ys = np.flatnonzero(mask.any(axis=1))
    if len(ys) == 0 or not feet_in_view(mask):
        return None
    floor_ref = reference_floor_row(camera)
    foot = float(ys.max()) + foot_margin_px
    if foot <= camera.cy + 1 or floor_ref <= camera.cy + 1:
        return None
    s = (foot - camera.cy) / (floor_ref - camera.cy)
    x_obs = lower_body_column(mask)
    x_ref = float(camera.project(np.zeros(3))[0])
    dx = x_obs - (camera.cx + s * (x_ref - camera.cx))
    return np.array([dx, 0.0, s])


def scaled_placement(observed: NDArray[np.float64], body_scale: float, camera: Camera) -> NDArray[np.float64]:
    """Placement of the templates for a subject ``body_scale`` times their body's size.

    The templates are scaled about the principal point, which is right for a person of the
    templates' own size; a subject ``k`` times larger at the same depth stands on the same floor
    row but is ``k`` times taller, so the templates are drawn at scale ``k s`` and shifted down
    by ``dy = s (1 - k) (floor_row - c_y)`` to keep their feet on the observed floor row.

    Parameters
    ----------
    observed : (3,) float
        ``(dx, dy, s)`` from :func:`observed_placement` (templates' own size; ``dy`` is added to).
    body_scale : float
        ``k``: subject height / template body height.
    camera : Camera

    Returns
    -------
    (3,) float64
    """
    dx, dy, s = (float(v) for v in observed)
    k = float(body_scale)
    return np.array([dx, dy + s * (1.0 - k) * (reference_floor_row(camera) - camera.cy), k * s])


def feet_scale(mask: NDArray[np.bool_], template_runs: NDArray[np.int16], center_y: float,
               foot_margin_px: float = 0.0) -> float | None:
    """Template scale that puts the template's lowest row on the silhouette's lowest row.

    Both rows belong to the same body point (the sole or toes touching the floor), so their ratio
    about the principal point's row gives the depth ratio without the bias of comparing the toes
    with the root's floor point.

    Parameters
    ----------
    mask : (H, W) bool
    template_runs : (R, 3) int16
        The matched template's full-resolution runs (reference placement).
    center_y : float
        Principal point row.

    Returns
    -------
    float or None
        None when either bottom is not below the principal point.
    """
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0 or len(template_runs) == 0 or not feet_in_view(mask):
        return None
    obs = float(rows[-1]) + foot_margin_px
    tpl = float(template_runs[:, 0].max())
    if obs <= center_y + 1 or tpl <= center_y + 1:
        return None
    return (obs - center_y) / (tpl - center_y)


def height_scale(mask: NDArray[np.bool_], template_runs: NDArray[np.int16], template_column: float,
                 band: float = 0.05) -> float | None:
    """Template scale that gives the template the silhouette's height, from the lowest row to the
    highest row near the body's centre column (the head, not a hand raised beside it).

    Unlike :func:`feet_scale` it does not move when the whole body leaves the floor: in a leap the
    feet line rises while the silhouette's height stays, so the feet line reads farther than this.

    Parameters
    ----------
    mask : (H, W) bool
    template_runs : (R, 3) int16
        The matched template's full-resolution runs ``(row, x0, x1)`` (reference placement).
    template_column : float
        The template's :func:`lower_body_column` (:func:`template_columns`).
    band : float
        Half-width of the centre band, as a fraction of each silhouette's whole height.

    Returns
    -------
    float or None
        None for an empty silhouette or template.
    """
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0 or len(template_runs) == 0 or not np.isfinite(template_column):
        return None
    col = lower_body_column(mask[rows[0]: rows[-1] + 1])
    hw = max(band * float(rows[-1] - rows[0] + 1), 1.0)
    top = np.flatnonzero(mask[:, max(round(col - hw), 0): max(round(col + hw) + 1, 0)].any(axis=1))
    h_sil = float(rows[-1] - (top[0] if len(top) else rows[0]) + 1)
    r = template_runs.astype(np.int64)
    t_lo, t_hi = int(r[:, 0].min()), int(r[:, 0].max())
    hw_t = max(band * float(t_hi - t_lo + 1), 1.0)
    near = (r[:, 2] > template_column - hw_t) & (r[:, 1] <= template_column + hw_t)  # x1 exclusive
    h_tpl = float(t_hi - (int(r[near, 0].min()) if near.any() else t_lo) + 1)
    return h_sil / h_tpl


def placement_to_root(placement: NDArray[np.float64], root_ref: NDArray[np.float64], camera: Camera,
                      body_scale: float = 1.0) -> NDArray[np.float64]:
    """World root position of a template root drawn at ``root_ref`` and seen at ``placement``.

    Parameters
    ----------
    placement : (3,) float
        ``(dx, dy, s)``.
    root_ref : (3,) float
        The template's root in the world (``x = z = 0``, its own height).
    camera : Camera
    body_scale : float
        Size of the subject relative to the templates' body: a subject ``k`` times larger seen at
        template scale ``s`` stands at depth ``k d_ref / s``.

    Returns
    -------
    (3,) float64
        World position, metres.
    """
    dx, dy, s = (float(v) for v in placement)
    u_ref, v_ref = camera.project(root_ref)
    d_ref = float(camera.depth(root_ref))
    u = camera.cx + dx + s * (u_ref - camera.cx)
    v = camera.cy + dy + s * (v_ref - camera.cy)
    d = body_scale * d_ref / max(s, 1e-6)
    cam_pt = np.array([(u - camera.cx) * d / camera.fx, -(v - camera.cy) * d / camera.fy, -d, 1.0])
    return (camera.pose @ cam_pt)[:3]
