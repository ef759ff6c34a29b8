"""Silhouette likelihood of arbitrary poses (not only the database's templates).

The tree filter compares the observation with *pre-rendered* template silhouettes. The particle
filters (:mod:`tracker_service.estimators.condensation`, :mod:`tracker_service.estimators.hierarchical_pf`)
propose poses anywhere in the 60-dimensional pose space, so each pose's capsule silhouette is
rendered here on the fly and compared with the observation by the very distance the tree filter
uses (Okada & Stenger eq. 7-12): with the observation's per-pixel image ``A`` and constant ``B`` of
one pyramid level (:mod:`tracker_service.silhouette.features`),

    d(S, T) = ( sum_{k: T(k)=1} A(k) + B ) / |w|                 (eq. 11, eq. 12)

which is the XOR (eq. 7), cwXOR (eq. 8-9) or nwXOR (eq. 10-11) distance -- whichever family the
observation was pre-processed for -- normalised by the fixed bounding window exactly as the tree
filter's distances are. The rendered silhouette comes as horizontal runs
(:func:`tracker_service.body.raster.silhouette_runs_batch`, the same scanline kernels that build the
template database), so ``sum A`` is two lookups per run in the level's horizontal integral image.
The negative log likelihood is the Gaussian on distance of the tree filter's eq. 6:
``0.5 (d / sigma)^2``.

The pose's world root is taken from the pose vector itself (no template placement): the camera is
the database's. Template pixels that fall outside the image are clipped by the renderer and cost
nothing (the tree filter charges ``outside_cost`` for them); a pose pushed off-screen is therefore
judged by its visible part only.

This is the numpy version (the renderer is numba, the distance is numpy); :func:`pose_distances_reference`
renders dense masks and is the test's reference.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import Body
from tracker_service.body.cardbox import CardboxModel, cardbox_quads, cardbox_sums
from tracker_service.body.kinematics import fk
from tracker_service.body.raster import render_silhouettes, silhouette_runs_batch
from tracker_service.camera import Camera
from tracker_service.silhouette.features import LevelFeatures

__all__ = [
    "CardboxLikelihood",
    "Likelihood",
    "PoseLikelihood",
    "level_camera",
    "placement_of_root",
    "pose_distances",
    "pose_distances_reference",
]


def level_camera(camera: Camera, feat: LevelFeatures) -> Camera:
    """The camera of a pyramid level: ``camera`` resampled to the level's width (the template
    database renders its coarse levels so, directly at that resolution)."""
    h, w = feat.shape
    if (w, h) == (camera.width, camera.height):
        return camera
    cam = camera.scaled(w / camera.width)
    if (cam.width, cam.height) != (w, h):
        raise ValueError(f"level {w}x{h} is not a resampling of the {camera.width}x{camera.height} camera")
    return cam


def pose_distances(poses: NDArray[np.float64], feat: LevelFeatures, body: Body, camera: Camera,
                   chunk: int = 512) -> NDArray[np.float64]:
    """Silhouette distance (eq. 11-12) of every pose's capsule silhouette to the observation.

    Parameters
    ----------
    poses : (N, P) float
        Pose vectors, world root included (:mod:`protocol.skeleton`).
    feat : LevelFeatures
        The observation at one pyramid level.
    body : Body
        The model's body (capsule radii, bone offsets).
    camera : Camera
        Full-resolution camera; resampled to the level (:func:`level_camera`).
    chunk : int
        Poses rendered per kernel call (bounds the run buffer).

    Returns
    -------
    (N,) float64
    """
    p = np.atleast_2d(np.asarray(poses, np.float64))
    cam = level_camera(camera, feat)
    out = np.empty(len(p))
    integral = feat.integral
    for i in range(0, len(p), chunk):
        joints = fk(p[i: i + chunk], body)
        data, ptr = silhouette_runs_batch(joints, body.capsule_radii, cam)
        y = data[:, 0].astype(np.int64)
        s = integral[y, data[:, 2].astype(np.int64)] - integral[y, data[:, 1].astype(np.int64)]
        owner = np.repeat(np.arange(len(ptr) - 1), np.diff(ptr))
        out[i: i + len(ptr) - 1] = np.bincount(owner, weights=s, minlength=len(ptr) - 1)
    out += feat.b
    out /= feat.window_area
    return out


def pose_distances_reference(poses: NDArray[np.float64], feat: LevelFeatures, body: Body,
                             camera: Camera) -> NDArray[np.float64]:
    """Dense reference of :func:`pose_distances`: rasterise every silhouette and sum ``A`` (recovered
    from the integral image) over its pixels."""
    p = np.atleast_2d(np.asarray(poses, np.float64))
    cam = level_camera(camera, feat)
    a = np.diff(feat.integral, axis=1)
    masks = render_silhouettes(fk(p, body), body.capsule_radii, cam)
    return np.array([(float(a[m].sum()) + feat.b) / feat.window_area for m in masks])


class Likelihood(NamedTuple):
    """The likelihood of a batch of poses."""

    distance: NDArray[np.float64]  # (N,) eq. 11's distance at the likelihood's level
    neg_log: NDArray[np.float64]  # (N,) 0.5 (d / sigma)^2 (eq. 6)
    evaluations: int  # silhouettes rendered and compared


@dataclass(frozen=True)
class PoseLikelihood:
    """eq. 6's Gaussian on the silhouette distance of rendered poses.

    Attributes
    ----------
    body : Body
        The model's body (the database's).
    camera : Camera
        The database's camera (full resolution).
    level : int
        Pyramid level of the observation (index into ``Observation.features``, coarse to fine;
        -1: the finest). 1 (160x120) by default: 4x fewer pixels than the finest for about the same
        discrimination of a whole-body pose.
    sigma : float
        Standard deviation of the Gaussian on distance (the tree filter's ``FilterParams.sigma``).
    """

    body: Body
    camera: Camera
    level: int = 1
    sigma: float = 0.01

    def __call__(self, poses: NDArray[np.float64], features: list[LevelFeatures]) -> Likelihood:
        """Distances and negative log likelihoods of ``poses`` ``(N, P)`` against the observation."""
        p = np.atleast_2d(np.asarray(poses, np.float64))
        d = pose_distances(p, features[self.level], self.body, self.camera)
        return Likelihood(d, 0.5 * (d / self.sigma) ** 2, len(p))

    def full_resolution_pixels(self, d: NDArray[np.float64], features: list[LevelFeatures]) -> NDArray[np.float64]:
        """Distances ``d`` at the likelihood's level as full-resolution pixel counts
        (``d |w|`` times the area ratio of the finest level to this one): the XOR pixel count of
        the cardbox paper's costs when the observation is XOR."""
        return _full_resolution_pixels(self.level, d, features)


def _full_resolution_pixels(level: int, d: NDArray[np.float64], features: list[LevelFeatures]) -> NDArray[np.float64]:
    feat, fine = features[level], features[-1]
    ratio = (fine.shape[0] * fine.shape[1]) / (feat.shape[0] * feat.shape[1])
    return np.asarray(d, np.float64) * feat.window_area * ratio


def placement_of_root(root: NDArray[np.float64], root_ref: NDArray[np.float64], camera: Camera) -> NDArray[np.float64]:
    """The placement ``(dx, dy, s)`` at which a template whose root is at ``root_ref`` shows a root
    at the world position ``root`` -- the inverse of
    :func:`tracker_service.silhouette.placement.placement_to_root` (exact for a pinhole camera).

    Parameters
    ----------
    root, root_ref : (3,) float
        World positions, metres (``root_ref``: ``x = z = 0`` at the template's own height).
    camera : Camera

    Returns
    -------
    (3,) float64
    """
    u, v = camera.project(np.asarray(root, np.float64))
    u_ref, v_ref = camera.project(np.asarray(root_ref, np.float64))
    s = float(camera.depth(root_ref)) / max(float(camera.depth(root)), 1e-6)
    return np.array([u - camera.cx - s * (u_ref - camera.cx), v - camera.cy - s * (v_ref - camera.cy), s])


@dataclass(frozen=True)
class CardboxLikelihood:
    """:class:`PoseLikelihood` with the cardbox paper's 3D cardbox model
    (:mod:`tracker_service.body.cardbox`) drawn instead of the capsule body: eq. 2's cost, the
    observation's per-pixel image summed over the union of the projected patches.

    Attributes
    ----------
    model : CardboxModel
    camera : Camera
    level, sigma
        As :class:`PoseLikelihood`.
    """

    model: CardboxModel
    camera: Camera
    level: int = 1
    sigma: float = 0.01

    @property
    def body(self) -> Body:
        return self.model.body

    def __call__(self, poses: NDArray[np.float64], features: list[LevelFeatures]) -> Likelihood:
        p = np.atleast_2d(np.asarray(poses, np.float64))
        feat = features[self.level]
        a = np.ascontiguousarray(np.diff(feat.integral, axis=1), np.float64)
        quads = cardbox_quads(self.model, p, level_camera(self.camera, feat))
        d = (cardbox_sums(quads, a, np.zeros(a.shape, np.bool_)) + feat.b) / feat.window_area
        return Likelihood(d, 0.5 * (d / self.sigma) ** 2, len(p))

    def full_resolution_pixels(self, d: NDArray[np.float64], features: list[LevelFeatures]) -> NDArray[np.float64]:
        """As :meth:`PoseLikelihood.full_resolution_pixels`."""
        return _full_resolution_pixels(self.level, d, features)
