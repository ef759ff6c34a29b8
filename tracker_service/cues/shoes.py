"""Shoes as a third cue: which foot is nearer the camera, from where the shoes are.

Walking towards the camera, the legs overlap in the image and a short stride fills the silhouette
about as well as the true long one: the back foot of a short-stride template lands inside the
front leg. The camera looks down on the floor, so a foot farther away is *higher* in the image (at
3 m, 0.4 m of depth moves a foot on the floor by 12-16 px at 320 x 240), and unlike the trousers
above them, shoes usually differ in colour from the legs. This module learns the shoes' colour
while the tracker initialises (the person stands facing the camera: the lowest rows of the
silhouette are the shoes), finds the shoe pixels of every frame in the lowest part of the
silhouette, and scores where the filter's support leaves put the feet:

    cost(T) = forward * sum over feet f of min(D_shoe(u_f(T)), cap)^2
            + reverse * mean over shoe pixels p of max(min(|p - nearest u_f(T)|, cap) - dead, 0)^2

``u_f`` is a foot's centre (mid-point of ankle and toe) moved by the leaf's placement. The forward
term asks whether the template's feet stand on shoes, the reverse term whether every shoe is
explained by a foot (the back shoe of a long stride, left bare by a short-stride template). The cost
enters the filter's leaf likelihood with a small weight (``FilterParams.shoe_weight``), and the
published pose's legs are the support's posterior mean re-weighted by ``exp(-weight * cost)``
(:func:`reweight_legs`).
When the shoes' colour is too close to the legs' (e.g. black shoes under black trousers) the cue
is off for that person (:func:`learn_shoes` returns None). Measured in ``docs/TRACKER.md``
("Shoes, given measurements, warm-up").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from protocol.skeleton import JOINT_INDEX, ROT_JOINTS
from tracker_service.cues._kernels import feet_cost_kernel, shoe_pixels_kernel
from tracker_service.estimators.tree_filter.filter import mean_pose, tempered

__all__ = ["LEG_POSE_INDEX", "ShoeModel", "ShoeParams", "band_pixels", "feet_cost", "feet_cost_reference",
           "foot_points", "learn_shoes", "reweight_legs", "shoe_mask", "shoe_pixels"]

_FOOT_JOINTS = ((JOINT_INDEX["l_ankle"], JOINT_INDEX["l_toe"]), (JOINT_INDEX["r_ankle"], JOINT_INDEX["r_toe"]))
#: Entries of the pose vector that place the legs below the hip joints (hip, knee, ankle rotations).
LEG_POSE_INDEX: NDArray[np.int64] = np.array(
    [3 + 3 * ROT_JOINTS.index(n) + c for n in ("l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle")
     for c in range(3)], np.int64)


@dataclass(frozen=True)
class ShoeParams:
    """Parameters of the shoe cue (pixels at 320 x 240; colours in 0-255 BGR units).

    Attributes
    ----------
    band_frac, band_min_px : float, int
        Shoe samples while initialising: the silhouette's lowest ``max(band_frac * height,
        band_min_px)`` rows.
    shin_frac : (float, float)
        The legs' samples: rows between these fractions of the height above the silhouette's bottom.
    min_samples : int
        Fewer shoe samples than this: no model.
    cov_floor : float
        Added to the colour covariance's diagonal (sensor noise, units²).
    threshold : float
        Squared Mahalanobis distance under which a pixel is shoe.
    distinct : float
        The legs' median squared Mahalanobis distance must exceed this, or the cue is off.
    region_frac : float
        Shoes are looked for in this lowest fraction of the silhouette's height.
    min_pixels : int
        Fewer shoe pixels in a frame than this: no cue for that frame.
    cap_px, dead_px : float
        Distances are capped at ``cap_px``; the reverse term forgives ``dead_px`` (half a shoe).
    forward, reverse : float
        Weights of the two terms.
    weight : float
        ``lambda`` of the legs' re-weighting ``exp(-lambda * (cost - min cost))``.
    """

    band_frac: float = 0.03
    band_min_px: int = 3
    shin_frac: tuple[float, float] = (0.08, 0.16)
    min_samples: int = 30
    cov_floor: float = 25.0
    threshold: float = 9.0
    distinct: float = 9.0
    region_frac: float = 0.3
    min_pixels: int = 4
    cap_px: float = 16.0
    dead_px: float = 3.0
    forward: float = 0.5
    reverse: float = 4.0
    weight: float = 0.05


@dataclass(frozen=True)
class ShoeModel:
    """A Gaussian of the shoes' colour: ``mean`` (3,) float64 and ``inv_cov`` (3, 3) float64 (BGR)."""

    mean: NDArray[np.float64]
    inv_cov: NDArray[np.float64]


def _rows(mask: NDArray[np.bool_]) -> tuple[int, int] | None:
    ys = np.flatnonzero(mask.any(axis=1))
    return (int(ys[0]), int(ys[-1])) if len(ys) else None


def band_pixels(frame: NDArray[np.uint8], mask: NDArray[np.bool_], params: ShoeParams
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Colour samples of a standing person's shoes and legs.

    Parameters
    ----------
    frame : (H, W, 3) uint8
    mask : (H, W) bool
        The silhouette (feet in view, the caller checks).
    params : ShoeParams

    Returns
    -------
    shoes, legs : (N, 3) float64 and (M, 3) float64
    """
    rows = _rows(mask)
    if rows is None:
        return np.zeros((0, 3)), np.zeros((0, 3))
    top, bottom = rows
    height = bottom - top + 1
    band = max(round(params.band_frac * height), params.band_min_px)
    shoe_rows = np.zeros(mask.shape[0], bool)
    shoe_rows[max(bottom - band + 1, 0): bottom + 1] = True
    leg_rows = np.zeros(mask.shape[0], bool)
    lo, hi = (max(bottom - int(f * height), 0) for f in (params.shin_frac[1], params.shin_frac[0]))
    leg_rows[lo:hi] = True
    return (frame[mask & shoe_rows[:, None]].astype(np.float64),
            frame[mask & leg_rows[:, None]].astype(np.float64))


def learn_shoes(shoes: NDArray[np.float64], legs: NDArray[np.float64], params: ShoeParams) -> ShoeModel | None:
    """The shoes' colour model from samples (:func:`band_pixels` of the initialising frames);
    None when there are too few samples or the legs have the same colour."""
    if len(shoes) < params.min_samples:
        return None
    mean = shoes.mean(axis=0)
    inv = np.asarray(np.linalg.inv(np.cov(shoes.T) + params.cov_floor * np.eye(3)), np.float64)
    if len(legs):
        d = legs - mean
        if float(np.median(np.einsum("ni,ij,nj->n", d, inv, d))) <= params.distinct:
            return None
    return ShoeModel(mean, inv)


def _shoe_box(mask: NDArray[np.bool_], params: ShoeParams) -> tuple[int, int, int, int] | None:
    """``(y0, y1, x0, x1)``: the lowest ``region_frac`` of the silhouette's rows, its columns grown
    by one pixel."""
    rows = _rows(mask)
    if rows is None:
        return None
    top, bottom = rows
    y0 = top + int((1.0 - params.region_frac) * (bottom - top + 1))
    xs = np.flatnonzero(mask[y0: bottom + 1].any(axis=0))
    return y0, bottom + 1, max(int(xs[0]) - 1, 0), min(int(xs[-1]) + 2, mask.shape[1])


def shoe_pixels(frame: NDArray[np.uint8], mask: NDArray[np.bool_], model: ShoeModel, params: ShoeParams
                ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The pixels of :func:`shoe_mask` as columns and rows ``(su, sv)``, each ``(N,) int64`` in
    row-major order (numba kernel; :func:`shoe_mask` is its numpy reference)."""
    box = _shoe_box(mask, params)
    if box is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    su, sv = shoe_pixels_kernel(frame, mask, *box, np.ascontiguousarray(model.mean, np.float64),
                                np.ascontiguousarray(model.inv_cov, np.float64), params.threshold)
    return su, sv


def shoe_mask(frame: NDArray[np.uint8], mask: NDArray[np.bool_], model: ShoeModel, params: ShoeParams
              ) -> NDArray[np.bool_]:
    """Shoe pixels: silhouette pixels of the shoes' colour in the lowest ``region_frac`` of the
    silhouette, opened once (isolated pixels removed). ``(H, W) bool``."""
    out = np.zeros(mask.shape, bool)
    box = _shoe_box(mask, params)
    if box is None:
        return out
    y0, y1, x0, x1 = box
    sub = mask[y0:y1, x0:x1]
    d = frame[y0:y1, x0:x1][sub].astype(np.float64) - model.mean
    hit = np.zeros(sub.shape, bool)
    hit[sub] = np.einsum("ni,ij,nj->n", d, model.inv_cov, d) < params.threshold
    out[y0:y1, x0:x1] = ndimage.binary_opening(hit)
    return out


def foot_points(joint_points: NDArray[np.float32], places: NDArray[np.float64], center: tuple[float, float]
                ) -> NDArray[np.float64]:
    """``(K, 2, 2)`` left/right foot centres (mid-point of ankle and toe) of ``K`` templates
    (``joint_points`` ``(K, J, 2)`` at the reference placement) moved by ``places`` ``(K, 3)``."""
    feet = np.stack([0.5 * (joint_points[:, a] + joint_points[:, t]) for a, t in _FOOT_JOINTS], axis=1)
    s = places[:, 2, None]
    out = np.empty(feet.shape, np.float64)
    out[..., 0] = center[0] + places[:, 0, None] + s * (feet[..., 0] - center[0])
    out[..., 1] = center[1] + places[:, 1, None] + s * (feet[..., 1] - center[1])
    return out


def feet_cost(shoes: NDArray[np.bool_] | tuple[NDArray[np.int64], NDArray[np.int64]], feet: NDArray[np.float64],
              params: ShoeParams, shape: tuple[int, int] | None = None) -> NDArray[np.float64] | None:
    """The module docstring's cost of each template's feet against the shoes (numba kernel;
    reference: :func:`feet_cost_reference`).

    Parameters
    ----------
    shoes : (H, W) bool, or (su, sv) each (N,) int64
        :func:`shoe_mask`, or the same pixels from :func:`shoe_pixels` (then ``shape`` is needed).
    feet : (K, 2, 2) float64
        :func:`foot_points`.
    params : ShoeParams
    shape : (int, int), optional
        ``(H, W)`` of the image when ``shoes`` are pixel coordinates.

    Returns
    -------
    (K,) float64 or None
        None when the frame shows fewer than ``params.min_pixels`` shoe pixels. A foot outside
        the image is ``cap_px`` from every shoe.
    """
    if isinstance(shoes, tuple):
        su, sv = shoes
        if shape is None:
            raise ValueError("feet_cost: give the image shape with shoe pixel coordinates")
    else:
        sv, su = np.nonzero(shoes)
        shape = shoes.shape
    if len(sv) < max(params.min_pixels, 1):
        return None
    out: NDArray[np.float64] = feet_cost_kernel(su.astype(np.int64), sv.astype(np.int64),
                                                np.ascontiguousarray(feet, np.float64), shape[0],
                                                shape[1], params.cap_px,
                                                params.dead_px, params.forward, params.reverse)
    return out


def feet_cost_reference(shoes: NDArray[np.bool_], feet: NDArray[np.float64], params: ShoeParams
                        ) -> NDArray[np.float64] | None:
    """Plain numpy :func:`feet_cost`: the forward term from a distance transform of the shoes'
    box, the reverse term from every pixel-to-foot distance."""
    sv, su = np.nonzero(shoes)
    if len(sv) < max(params.min_pixels, 1):
        return None
    # the distance transform of a box around the shoes, grown by the cap: farther feet are capped
    pad = int(np.ceil(params.cap_px)) + 1
    h, w = shoes.shape
    ya, yb = max(int(sv.min()) - pad, 0), min(int(sv.max()) + pad + 1, h)
    xa, xb = max(int(su.min()) - pad, 0), min(int(su.max()) + pad + 1, w)
    dist = ndimage.distance_transform_edt(~shoes[ya:yb, xa:xb])
    ui = np.rint(feet[..., 0]).astype(np.int64) - xa
    vi = np.rint(feet[..., 1]).astype(np.int64) - ya
    inside = (ui >= 0) & (ui < xb - xa) & (vi >= 0) & (vi < yb - ya)
    d_feet = np.full(ui.shape, params.cap_px)
    d_feet[inside] = dist[vi[inside], ui[inside]]
    fwd = (np.minimum(d_feet, params.cap_px) ** 2).sum(axis=1)
    du = feet[:, :, None, 0] - su[None, None, :]
    dv = feet[:, :, None, 1] - sv[None, None, :]
    near = np.sqrt(du * du + dv * dv).min(axis=1)  # (K, N): each shoe pixel's nearest foot
    rev = (np.maximum(np.minimum(near, params.cap_px) - params.dead_px, 0.0) ** 2).mean(axis=1)
    out: NDArray[np.float64] = params.forward * fwd + params.reverse * rev
    return out


def reweight_legs(pose: NDArray[np.float64], leaf_poses: NDArray[np.float64], weights: NDArray[np.float64],
                  cost: NDArray[np.float64], temperature: float, params: ShoeParams) -> NDArray[np.float64]:
    """The pose with its legs (:data:`LEG_POSE_INDEX`) taken from the support's tempered posterior
    mean re-weighted by ``exp(-weight * (cost - min cost))``.

    Parameters
    ----------
    pose : (P,) float64
        The published pose (the support's tempered mean).
    leaf_poses : (K, P) float64
        The support leaves' poses.
    weights : (K,) float64
        Their posterior weights.
    cost : (K,) float64
        :func:`feet_cost` of each.
    temperature : float
        The mean pose's temperature (``FilterParams.mean_temperature``).
    params : ShoeParams

    Returns
    -------
    (P,) float64
    """
    w = tempered(weights, temperature) * np.exp(-params.weight * (cost - cost.min()))
    legs = mean_pose(leaf_poses, w / w.sum())
    out = pose.copy()
    out[LEG_POSE_INDEX] = legs[LEG_POSE_INDEX]
    return out
