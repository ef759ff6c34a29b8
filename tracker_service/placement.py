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

from .camera import Camera

__all__ = ["TOE_AHEAD_M", "feet_scale", "observed_placement", "placement_to_root", "reference_floor_row"]


#: Where the lowest silhouette point of a person standing at the reference spot touches the floor:
#: the toes, about 9 cm in front of the root for an adult facing the camera.
TOE_AHEAD_M = 0.09


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
        None for an empty silhouette or one whose feet are above the horizon.
    """
    ys, xs = np.nonzero(mask)
    if len(ys) == 0:
        return None
    floor_ref = reference_floor_row(camera)
    foot = float(ys.max()) + foot_margin_px
    if foot <= camera.cy + 1 or floor_ref <= camera.cy + 1:
        return None
    s = (foot - camera.cy) / (floor_ref - camera.cy)
    # the body's centre column: median over the lower body (legs rarely swing as far as arms)
    top = ys.min()
    lower = ys >= top + 0.45 * (ys.max() - top)
    x_obs = float(np.median(xs[lower])) if lower.any() else float(np.median(xs))
    x_ref = float(camera.project(np.zeros(3))[0])
    dx = x_obs - (camera.cx + s * (x_ref - camera.cx))
    return np.array([dx, 0.0, s])


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
    if len(rows) == 0 or len(template_runs) == 0:
        return None
    obs = float(rows[-1]) + foot_margin_px
    tpl = float(template_runs[:, 0].max())
    if obs <= center_y + 1 or tpl <= center_y + 1:
        return None
    return (obs - center_y) / (tpl - center_y)


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
