"""Skin colour as a second cue: where the hands are when the silhouette cannot tell.

A hand in front of the torso leaves no trace in the silhouette, so the silhouette distances of
Okada & Stenger (eq. 7-11) cannot tell "hands on the chest" from "hands behind the back" or "arm
hanging": those poses are the largest share of our held-out error (docs/TRACKER.md). Skin is the
one part of a dressed person whose colour is known in advance: its chromaticity
``(r, g) = (R, G) / (R + G + B)`` lies in a narrow band for every skin tone, away from most fabrics
and from the intensity changes of shading. This module turns a frame into a skin mask and the
mask's distance transform, and scores where a template puts the hands against it:

    cost(T) = sum over hands h of  0.5 * min(D_skin(u_h(T)), cap)^2 / sigma^2   (hand visible in T)
                                   hidden_cost                               (hand hidden in T)

``u_h(T)`` is the hand centre (mid-point of wrist and finger tips) of the template's pose, moved by
the same placement ``(dx, dy, s)`` as its silhouette. The cost is added to eq. 6's negative log
likelihood (:func:`tracker_service.estimators.tree_filter.filter.step`), i.e. the two cues are treated as
independent. The extra skin of the face, neck, forearms or legs does not hurt that term: a
template is only asked whether its hands land on skin. The reverse term (:func:`cover_cost`) asks
the opposite: skin pixels farther than a limb's width from every skin-bearing bone of the template
(arms, neck and head, legs) cost, so hands held on the chest are not explained by a template whose
arms hang at its sides. :func:`skin_cost` evaluates both in one numba kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import JOINT_INDEX, N_JOINTS, PARTS
from tracker_service.camera import Camera
from tracker_service.cues._kernels import skin_cost_kernel
from tracker_service.silhouette.features import distance_transform

__all__ = [
    "HAND_PARTS",
    "SKIN_SEGMENTS",
    "SkinModel",
    "SkinObservation",
    "cover_cost",
    "hand_cost",
    "hand_points",
    "leaf_joint_points",
    "observe_skin",
    "skin_cost",
    "skin_mask",
]

#: Parts whose visibility decides whether a template's hand is seen (left, right).
HAND_PARTS: tuple[int, int] = (PARTS.index("l_hand"), PARTS.index("r_hand"))
_HAND_JOINTS = ((JOINT_INDEX["l_wrist"], JOINT_INDEX["l_hand_tip"]),
                (JOINT_INDEX["r_wrist"], JOINT_INDEX["r_hand_tip"]))
#: Bones along which a person may show skin (arms, neck and head, legs under a skirt): the skin a
#: template cannot explain is the skin farther than a limb's width from all of them.
SKIN_SEGMENTS: tuple[tuple[int, int], ...] = tuple(
    (JOINT_INDEX[a], JOINT_INDEX[b]) for a, b in (
        ("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"), ("l_wrist", "l_hand_tip"),
        ("r_shoulder", "r_elbow"), ("r_elbow", "r_wrist"), ("r_wrist", "r_hand_tip"),
        ("neck", "head_top"), ("l_hip", "l_knee"), ("l_knee", "l_ankle"), ("r_hip", "r_knee"),
        ("r_knee", "r_ankle")))


@dataclass(frozen=True)
class SkinModel:
    """Gaussian skin locus in normalised chromaticity.

    Attributes
    ----------
    mean : (2,) float
        Mean ``(r, g)``.
    std : (2,) float
        Standard deviation of ``r`` and ``g`` (axis-aligned: the skin locus is an ellipse along r).
    max_mahalanobis : float
        Pixels within this Mahalanobis distance are skin.
    min_intensity : float
        Darker pixels (mean of B, G, R below this) have no reliable chromaticity and are not skin.

    Notes
    -----
    The defaults cover the five skin tones of the synthetic scene and published skin loci
    (r 0.36-0.52, g 0.28-0.36); the scene's fabrics, walls and floor fall outside on the measured
    frames (docs/TRACKER.md, "Skin cue").
    """

    mean: tuple[float, float] = (0.445, 0.318)
    std: tuple[float, float] = (0.042, 0.016)
    max_mahalanobis: float = 2.5
    min_intensity: float = 12.0


@dataclass(frozen=True)
class SkinObservation:
    """A frame's skin evidence.

    Attributes
    ----------
    mask : (H, W) bool
        Skin pixels inside the (dilated) silhouette.
    samples : (K, 2) float64
        ``(u, v)`` of up to ``max_samples`` skin pixels spread over the mask.
    distance : (H, W) float32
        Distance (pixels) of every pixel to the nearest skin pixel; a large constant when the frame
        has no skin at all.
    fraction : float
        Skin pixels over silhouette pixels (a shirt of skin colour makes this large, and the cue
        weak: the filter then switches the cue off, ``FilterParams.skin_max_fraction``).
    """

    mask: NDArray[np.bool_]
    samples: NDArray[np.float64]
    distance: NDArray[np.float32]
    fraction: float


def _bbox(mask: NDArray[np.bool_], pad: int) -> tuple[slice, slice]:
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    h, w = mask.shape
    return (slice(max(rows[0] - pad, 0), min(rows[-1] + 1 + pad, h)),
            slice(max(cols[0] - pad, 0), min(cols[-1] + 1 + pad, w)))


def _skin_pixels(image: NDArray[np.uint8], model: SkinModel) -> NDArray[np.bool_]:
    img = image.astype(np.float32)
    s = img.sum(axis=2)
    inv = 1.0 / np.maximum(s, 1.0)
    zr = (img[..., 2] * inv - model.mean[0]) / model.std[0]
    zg = (img[..., 1] * inv - model.mean[1]) / model.std[1]
    return (s >= 3.0 * model.min_intensity) & (zr * zr + zg * zg <= model.max_mahalanobis**2)


def skin_mask(image: NDArray[np.uint8], silhouette: NDArray[np.bool_], model: SkinModel = SkinModel()
              ) -> NDArray[np.bool_]:
    """Skin pixels of a BGR frame inside a silhouette.

    Parameters
    ----------
    image : (H, W, 3) uint8
        BGR frame.
    silhouette : (H, W) bool
        Foreground mask; it is dilated by one pixel so that thin hands at its border count.
    model : SkinModel

    Returns
    -------
    (H, W) bool
    """
    out = np.zeros(silhouette.shape, bool)
    if not silhouette.any():
        return out
    ys, xs = _bbox(silhouette, 1)  # colour only where the person is: a few times fewer pixels
    fg = cv2.dilate(silhouette[ys, xs].astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    out[ys, xs] = _skin_pixels(image[ys, xs], model) & fg
    return out


def observe_skin(image: NDArray[np.uint8], silhouette: NDArray[np.bool_], model: SkinModel = SkinModel(),
                 reach_px: int = 40, max_samples: int = 64) -> SkinObservation:
    """Skin mask, its distance transform and skin fraction of one frame.

    Parameters
    ----------
    image : (H, W, 3) uint8
    silhouette : (H, W) bool
    model : SkinModel
    reach_px : int
        Distances are exact up to this many pixels from the skin; beyond, at least ``reach_px``
        (the distance transform runs on the person's box grown by ``reach_px`` only).
    max_samples : int
        Skin pixels kept (evenly spaced in raster order) for :func:`cover_cost`.

    Returns
    -------
    SkinObservation
    """
    mask = skin_mask(image, silhouette, model)
    n_fg = int(silhouette.sum())
    dist = np.full(mask.shape, 1e3, np.float32)
    if mask.any():
        ys, xs = _bbox(mask, reach_px)
        dist[ys, xs] = distance_transform((~mask[ys, xs]).astype(np.uint8))
    idx = np.flatnonzero(mask)
    if len(idx) > max_samples:
        idx = idx[np.linspace(0, len(idx) - 1, max_samples).astype(np.int64)]
    samples = np.stack([idx % mask.shape[1], idx // mask.shape[1]], axis=1).astype(np.float64)
    return SkinObservation(mask, samples, dist, float(mask.sum()) / max(n_fg, 1))


def leaf_joint_points(leaf_joints: NDArray[np.floating], camera: Camera) -> NDArray[np.float32]:
    """Image position of every joint of each leaf template at the reference placement.

    Parameters
    ----------
    leaf_joints : (NL, J, 3) float
        The leaves' joints: forward kinematics of their poses as rendered into the database (root
        at the reference spot) with the database's body model.
    camera : Camera
        The database's full-resolution camera.

    Returns
    -------
    (NL, J, 2) float32
        ``(u, v)`` of every joint.
    """
    return np.asarray(camera.project(np.asarray(leaf_joints, np.float64)), np.float32)


def hand_points(joint_points: NDArray[np.float32]) -> NDArray[np.float32]:
    """``(..., 2, 2)`` left/right hand centres (mid-point of wrist and finger tips) from
    ``(..., J, 2)`` joint positions."""
    return np.stack([0.5 * (joint_points[..., w, :] + joint_points[..., t, :]) for w, t in _HAND_JOINTS], axis=-2)


def _transform(points: NDArray[np.float32], places: NDArray[np.float64], center: tuple[float, float]
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(n, K, 2)`` reference points moved by placements ``(n, G, 3)``: ``u, v`` each ``(n, G, K)``."""
    s = places[..., 2, None]
    u = center[0] + places[..., 0, None] + s * (points[:, None, :, 0] - center[0])
    v = center[1] + places[..., 1, None] + s * (points[:, None, :, 1] - center[1])
    return u, v


def cover_cost(samples: NDArray[np.float64], joint_points: NDArray[np.float32], places: NDArray[np.float64],
               center: tuple[float, float], radius_px: float, sigma_px: float, cap_px: float) -> NDArray[np.float64]:
    """Cost of the observed skin a template cannot explain (the reverse of :func:`hand_cost`).

    Every skin sample farther than ``radius_px`` from all of the template's :data:`SKIN_SEGMENTS`
    costs ``0.5 * min(d - radius, cap)^2 / sigma^2``; the cost is the mean over samples times two
    (on the scale of two hands). Hands held on the chest are seen as skin where a template with
    hanging arms has no limb.

    Parameters
    ----------
    samples : (K, 2) float64
        Skin pixels (:attr:`SkinObservation.samples`).
    joint_points : (n, J, 2) float32
        Joints of each template at the reference placement (:func:`leaf_joint_points`).
    places : (n, G, 3) float64
    center : (float, float)
    radius_px, sigma_px, cap_px : float

    Returns
    -------
    (n, G) float64
    """
    n, g = places.shape[:2]
    if len(samples) == 0:
        return np.zeros((n, g))
    seg = np.array(SKIN_SEGMENTS)
    u, v = _transform(joint_points, places, center)  # (n, G, J)
    ax, ay = u[..., seg[:, 0]], v[..., seg[:, 0]]  # (n, G, S)
    bx, by = u[..., seg[:, 1]] - ax, v[..., seg[:, 1]] - ay
    px = samples[:, 0][None, None, :, None] - ax[:, :, None, :]  # (n, G, K, S)
    py = samples[:, 1][None, None, :, None] - ay[:, :, None, :]
    ll = np.maximum(bx * bx + by * by, 1e-9)[:, :, None, :]
    t = np.clip((px * bx[:, :, None, :] + py * by[:, :, None, :]) / ll, 0.0, 1.0)
    dx, dy = px - t * bx[:, :, None, :], py - t * by[:, :, None, :]
    d = np.sqrt(np.where(np.isnan(dx + dy), np.inf, dx * dx + dy * dy).min(axis=-1))  # (n, G, K); unknown bones skipped
    c = 0.5 * (np.clip(d - radius_px, 0.0, cap_px) / sigma_px) ** 2
    return np.asarray(2.0 * c.mean(axis=-1), np.float64)


def hand_cost(distance: NDArray[np.float32], points: NDArray[np.float32], visible: NDArray[np.bool_],
              places: NDArray[np.float64], center: tuple[float, float], sigma_px: float, cap_px: float,
              hidden_cost: float) -> NDArray[np.float64]:
    """Negative log likelihood of the skin observation for templates at placements.

    Parameters
    ----------
    distance : (H, W) float32
        :attr:`SkinObservation.distance`.
    points : (n, 2, 2) float32
        Hand centres of each template at the reference placement (:func:`hand_points`).
    visible : (n, 2) bool
        Whether each hand is visible in each template.
    places : (n, G, 3) float64
        Placements ``(dx, dy, s)`` (full-resolution pixels) at which each template is evaluated.
    center : (float, float)
        Scaling centre of the placements.
    sigma_px, cap_px : float
        Standard deviation and cap of the hand-to-skin distance (full-resolution pixels).
    hidden_cost : float
        Cost of a hand the template hides (a template must not win by hiding its hands).

    Returns
    -------
    (n, G) float64
    """
    h, w = distance.shape
    u, v = _transform(points, places, center)  # (n, G, 2)
    iu = np.rint(np.nan_to_num(u, nan=-1.0)).astype(np.int64)
    iv = np.rint(np.nan_to_num(v, nan=-1.0)).astype(np.int64)
    inside = (iu >= 0) & (iu < w) & (iv >= 0) & (iv < h)
    d = np.where(inside, distance[np.clip(iv, 0, h - 1), np.clip(iu, 0, w - 1)], cap_px)
    c = 0.5 * (np.minimum(d, cap_px) / sigma_px) ** 2
    c = np.where(visible[:, None, :], c, hidden_cost)
    return np.asarray(c.sum(axis=-1), np.float64)


_SEGMENTS = np.array(SKIN_SEGMENTS, np.int64)
_HANDS = np.array(_HAND_JOINTS, np.int64)


def skin_cost(obs: SkinObservation, joint_points: NDArray[np.float32], visible: NDArray[np.float32],
              rows: NDArray[np.int64], places: NDArray[np.float64], center: tuple[float, float], sigma_px: float,
              cap_px: float, hidden_cost: float, cover_weight: float, radius_px: float, min_visible: float,
              hand_parts: tuple[int, int] = HAND_PARTS) -> NDArray[np.float64]:
    """``hand_cost + cover_weight * cover_cost`` in one numba pass (:func:`hand_cost` and
    :func:`cover_cost` are its references), templates read through ``rows``.

    Parameters
    ----------
    obs : SkinObservation
    joint_points : (L, J, 2) float32
        Joints of every template at the reference placement (the database's leaf points).
    visible : (L, P) float32
        Visible fraction of each part of every template.
    rows : (n,) int64
        Template of each evaluation (index into ``joint_points`` and ``visible``).
    places : (n, G, 3) float64
    center : (float, float)
    sigma_px, cap_px, hidden_cost, cover_weight, radius_px : float
    min_visible : float
        A hand counts as shown where its part's visible fraction exceeds this (a hidden hand costs
        ``hidden_cost``).
    hand_parts : (int, int)
        Columns of ``visible`` of the left and right hand.

    Returns
    -------
    (n, G) float64
    """
    idx = np.ascontiguousarray(rows, np.int64)
    pts = np.ascontiguousarray(joint_points, np.float32)
    vis = np.ascontiguousarray(visible, np.float32)
    hp = np.array(hand_parts, np.int64)
    pl = np.ascontiguousarray(places, np.float64)
    smp = np.ascontiguousarray(obs.samples, np.float64)
    # the kernel has no bounds checks: every index it follows is checked here
    if (pts.ndim != 3 or pts.shape[1:] != (N_JOINTS, 2) or vis.ndim != 2 or len(vis) != len(pts)
            or hp.shape != (2,) or hp.min() < 0 or hp.max() >= vis.shape[1] or pl.ndim != 3 or pl.shape[2] != 3
            or smp.ndim != 2 or smp.shape[1] != 2):
        raise ValueError(f"skin_cost: joint points must be (L, {N_JOINTS}, 2), visible (L, P) with the hand "
                         f"columns {tuple(hand_parts)}, places (n, G, 3), samples (K, 2); got {pts.shape}, "
                         f"{vis.shape}, {pl.shape}, {smp.shape}")
    if idx.ndim != 1 or pl.shape[:1] != idx.shape or (len(idx) and not (0 <= idx.min() and idx.max() < len(pts))):
        raise ValueError(f"rows must index the {len(pts)} templates, one per placement group "
                         f"(rows {idx.shape}, places {pl.shape})")
    out = np.empty(pl.shape[:2])
    skin_cost_kernel(obs.distance, smp, pts, idx, _SEGMENTS, _HANDS, vis, hp, np.float32(min_visible), pl,
                     float(center[0]), float(center[1]), float(sigma_px), float(cap_px), float(hidden_cost),
                     float(cover_weight), float(radius_px), out)
    return out
