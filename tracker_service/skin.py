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
likelihood (:func:`tracker_service.tree_filter.step`), i.e. the two cues are treated as
independent. The extra skin of the face, neck, forearms or legs does not hurt: a template is only
asked whether its hands land on skin.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from protocol import fk
from protocol.skeleton import JOINT_INDEX, PARTS, Body

from .camera import Camera

__all__ = [
    "HAND_PARTS",
    "SkinModel",
    "SkinObservation",
    "hand_cost",
    "leaf_hand_points",
    "observe_skin",
    "skin_mask",
]

#: Parts whose visibility decides whether a template's hand is seen (left, right).
HAND_PARTS: tuple[int, int] = (PARTS.index("l_hand"), PARTS.index("r_hand"))
_HAND_JOINTS = ((JOINT_INDEX["l_wrist"], JOINT_INDEX["l_hand_tip"]),
                (JOINT_INDEX["r_wrist"], JOINT_INDEX["r_hand_tip"]))


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
    distance : (H, W) float32
        Distance (pixels) of every pixel to the nearest skin pixel; a large constant when the frame
        has no skin at all.
    fraction : float
        Skin pixels over silhouette pixels (a shirt of skin colour makes this large, and the cue
        weak: :func:`hand_cost` is then switched off by the caller's ``max_fraction``).
    """

    mask: NDArray[np.bool_]
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
                 reach_px: int = 40) -> SkinObservation:
    """Skin mask, its distance transform and skin fraction of one frame.

    Parameters
    ----------
    image : (H, W, 3) uint8
    silhouette : (H, W) bool
    model : SkinModel
    reach_px : int
        Distances are exact up to this many pixels from the skin; beyond, at least ``reach_px``
        (the distance transform runs on the person's box grown by ``reach_px`` only).

    Returns
    -------
    SkinObservation
    """
    mask = skin_mask(image, silhouette, model)
    n_fg = int(silhouette.sum())
    dist = np.full(mask.shape, 1e3, np.float32)
    if mask.any():
        ys, xs = _bbox(mask, reach_px)
        dist[ys, xs] = cv2.distanceTransform((~mask[ys, xs]).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return SkinObservation(mask, dist, float(mask.sum()) / max(n_fg, 1))


def leaf_hand_points(leaf_poses: NDArray[np.floating], body: Body, camera: Camera, chunk: int = 8192
                     ) -> NDArray[np.float32]:
    """Image position of each leaf template's hand centres at the reference placement.

    Parameters
    ----------
    leaf_poses : (NL, P) float
        Poses as rendered into the database (root at the reference spot).
    body : Body
        The database's body model.
    camera : Camera
        The database's full-resolution camera.
    chunk : int
        Poses per forward-kinematics batch.

    Returns
    -------
    (NL, 2, 2) float32
        ``(u, v)`` of the left and right hand centre (mid-point of wrist and finger tips).
    """
    out = np.empty((len(leaf_poses), 2, 2), np.float32)
    for i in range(0, len(leaf_poses), chunk):
        j = fk(np.asarray(leaf_poses[i: i + chunk], np.float64), body)
        for h, (w, t) in enumerate(_HAND_JOINTS):
            out[i: i + chunk, h] = camera.project(0.5 * (j[:, w] + j[:, t]))
    return out


def hand_cost(distance: NDArray[np.float32], points: NDArray[np.float32], visible: NDArray[np.bool_],
              places: NDArray[np.float64], center: tuple[float, float], sigma_px: float, cap_px: float,
              hidden_cost: float) -> NDArray[np.float64]:
    """Negative log likelihood of the skin observation for templates at placements.

    Parameters
    ----------
    distance : (H, W) float32
        :attr:`SkinObservation.distance`.
    points : (n, 2, 2) float32
        Hand centres of each template at the reference placement (:func:`leaf_hand_points`).
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
    s = places[..., 2, None]  # (n, G, 1)
    u = center[0] + places[..., 0, None] + s * (points[:, None, :, 0] - center[0])  # (n, G, 2)
    v = center[1] + places[..., 1, None] + s * (points[:, None, :, 1] - center[1])
    iu = np.rint(np.nan_to_num(u, nan=-1.0)).astype(np.int64)
    iv = np.rint(np.nan_to_num(v, nan=-1.0)).astype(np.int64)
    inside = (iu >= 0) & (iu < w) & (iv >= 0) & (iv < h)
    d = np.where(inside, distance[np.clip(iv, 0, h - 1), np.clip(iu, 0, w - 1)], cap_px)
    c = 0.5 * (np.minimum(d, cap_px) / sigma_px) ** 2
    c = np.where(visible[:, None, :], c, hidden_cost)
    return np.asarray(c.sum(axis=-1), np.float64)
