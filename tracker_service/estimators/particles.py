"""What the particle filters share: per-dimension noise of the pose vector, the initial pose from
the observed placement, the estimate of a pose and its world pose again.

A particle is a whole pose vector (:mod:`protocol.skeleton`: world root position, root rotation
vector, 18 joint rotation vectors). The :class:`~tracker_service.estimators.base.Estimate` of a
particle filter follows the tree filter's convention: the poses carry the template root
``(0, y, 0)`` (no horizontal position, the pose's own height) and ``placement`` is the ``(dx, dy, s)``
that puts that root where the best particle's world root is
(:func:`tracker_service.estimators.likelihood.placement_of_root`), so
``placement_to_root(estimate.placement, estimate.pose_map[:3], camera)`` gives it back
(:func:`world_pose`).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import N_PARTS, POSE_SIZE, ROT_JOINTS, Body, standing_pose
from tracker_service.camera import Camera
from tracker_service.estimators.base import Estimate
from tracker_service.estimators.likelihood import placement_of_root
from tracker_service.silhouette.placement import placement_to_root

__all__ = ["joint_slice", "make_estimate", "pose_noise", "reference_pose", "world_pose"]


def joint_slice(name: str) -> slice:
    """The three pose-vector entries of a rotating joint's rotation vector (``pelvis``: the root's)."""
    k = ROT_JOINTS.index(name)
    return slice(3 + 3 * k, 6 + 3 * k)


def pose_noise(root_m: float, joint_rad: Mapping[str, float], default_rad: float = 0.0) -> NDArray[np.float64]:
    """Per-dimension standard deviations of a pose vector: ``root_m`` on the root position,
    ``joint_rad[name]`` on each rotation vector's three components (``default_rad`` for a joint
    not named; ``pelvis`` is the root orientation).

    Returns
    -------
    (P,) float64
    """
    out = np.full(POSE_SIZE, float(default_rad))
    out[:3] = root_m
    for name, v in joint_rad.items():
        out[joint_slice(name)] = v
    return out


def reference_pose(body: Body, camera: Camera, placement: NDArray[np.float64] | None) -> NDArray[np.float64]:
    """The standing pose (:func:`protocol.skeleton.standing_pose`, facing the camera) with its root
    where the observed placement puts a standing template's root (the origin without one).

    Returns
    -------
    (P,) float64
    """
    pose = standing_pose(body)
    if placement is not None:
        pose[:3] = placement_to_root(np.asarray(placement, np.float64), pose[:3], camera)
    return pose


def make_estimate(pose_map: NDArray[np.float64], pose_mean: NDArray[np.float64], distance: float,
                  confidence_scale: float, evaluations: tuple[int, ...], camera: Camera) -> Estimate:
    """The estimate of world poses: template roots, the MAP's placement, ``exp(-0.5 (d / c)^2)``
    confidence (the tree filter's), every part visible, no leaf (-1)."""
    pm, pe = np.array(pose_map, np.float64), np.array(pose_mean, np.float64)
    ref = np.array([0.0, pm[1], 0.0])
    place = placement_of_root(pm[:3], ref, camera)
    pm[:3] = ref
    pe[:3] = (0.0, pe[1], 0.0)
    return Estimate(leaf=-1, pose_map=pm, pose_mean=pe, placement=place, distance=float(distance),
                    confidence=float(np.exp(-0.5 * (distance / confidence_scale) ** 2)),
                    visibility=np.ones(N_PARTS, np.float32), evaluations=evaluations, reinitialised=False)


def world_pose(estimate: Estimate, camera: Camera, mean: bool = False) -> NDArray[np.float64]:
    """The estimate's MAP (or mean) pose with its root in the world
    (:func:`tracker_service.silhouette.placement.placement_to_root`): the same for every estimator.

    Returns
    -------
    (P,) float64
    """
    pose = np.array(estimate.pose_mean if mean else estimate.pose_map, np.float64)
    pose[:3] = placement_to_root(estimate.placement, pose[:3], camera)
    return pose
