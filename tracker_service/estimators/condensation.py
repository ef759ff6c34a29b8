"""Condensation (Isard & Blake 1998) over the full pose vector and the global position.

The baseline the tree filter is measured against: a particle set over the whole 60-dimensional
pose (root position, root orientation, 18 joint rotations), per frame

1. **factored sampling**: ``N`` particles drawn from the previous weighted set by weight
   (multinomial, :func:`tracker_service.estimators.resampling.multinomial_resample`);
2. **prediction**: a constant-position model, each particle diffused by Gaussian noise with a
   per-joint standard deviation (:attr:`CondensationParams.noise`), then clipped to the joint limits
   (:func:`protocol.skeleton.clamp_pose`);
3. **measurement**: each particle's capsule silhouette rendered and compared with the observation
   (:class:`tracker_service.estimators.likelihood.PoseLikelihood`: the tree filter's distance and
   Gaussian on distance); the weights are the normalised likelihoods.

There is no hand start: the first frame (and the frame after :meth:`Condensation.init`) draws the
particles around the standing pose at the observed placement
(:func:`tracker_service.estimators.particles.reference_pose`), with the wider
:attr:`CondensationParams.init_noise`. The random stream is an explicit :class:`numpy.random.Generator`
held in the state (reproducible: the same seed gives the same track).

The estimate: the weighted mean pose (quaternion mean per joint, the tree filter's
:func:`~tracker_service.estimators.tree_filter.filter.mean_pose`), the best particle as the MAP,
its distance and the tree filter's confidence; every part visible; ``evaluations = (N,)``.
The distance reported is the MAP's at the likelihood's level (the tree filter reports the finest).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import Body, clamp_pose
from tracker_service.camera import Camera
from tracker_service.estimators.base import Estimate, Observation
from tracker_service.estimators.likelihood import PoseLikelihood
from tracker_service.estimators.particles import make_estimate, pose_noise, reference_pose
from tracker_service.estimators.resampling import multinomial_resample, normalised_weights
from tracker_service.estimators.tree_filter.filter import mean_pose

__all__ = ["DEFAULT_JOINT_NOISE", "Condensation", "CondensationParams", "CondensationState"]

#: Diffusion per frame (radians, each rotation-vector component) of every rotating joint; ``pelvis``
#: is the root orientation. Limbs move most (an arm is raised in about half a second).
DEFAULT_JOINT_NOISE: dict[str, float] = {
    "pelvis": 0.03, "spine": 0.03, "chest": 0.03, "neck": 0.03, "head": 0.03,
    "l_clavicle": 0.02, "r_clavicle": 0.02,
    "l_shoulder": 0.12, "r_shoulder": 0.12, "l_elbow": 0.12, "r_elbow": 0.12,
    "l_wrist": 0.05, "r_wrist": 0.05,
    "l_hip": 0.05, "r_hip": 0.05, "l_knee": 0.05, "r_knee": 0.05, "l_ankle": 0.03, "r_ankle": 0.03,
}


@dataclass(frozen=True)
class CondensationParams:
    """Tuning of :class:`Condensation`.

    Attributes
    ----------
    n_particles : int
        ``N``.
    sigma : float
        Standard deviation of the Gaussian on distance (eq. 6 of Okada & Stenger). Wider than the
        tree filter's 0.01: over 1000 particles in 60 dimensions that one leaves a single particle.
    level : int
        Pyramid level of the likelihood (index into ``Observation.features``).
    root_noise_m : float
        Diffusion of the root position per frame, metres.
    noise : dict
        Diffusion per joint (:data:`DEFAULT_JOINT_NOISE`).
    init_root_m, init_scale : float
        The initial set: root position spread (metres) and the joints' spread as a multiple of
        ``noise``.
    confidence_scale : float
        ``c`` of the reported confidence ``exp(-0.5 (d / c)^2)`` (the tree filter's).
    """

    n_particles: int = 1000
    sigma: float = 0.02
    level: int = 1
    root_noise_m: float = 0.02
    noise: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_JOINT_NOISE))
    init_root_m: float = 0.05
    init_scale: float = 2.0
    confidence_scale: float = 0.05


@dataclass(frozen=True)
class CondensationState:
    """The weighted particle set between frames (empty before the first frame).

    Attributes
    ----------
    particles : (N, P) float64
        World poses.
    weights : (N,) float64
        Normalised likelihoods (sum 1).
    rng : Generator
        The filter's random stream (advanced by every step).
    placement : (3,) float64 or None
        Where to initialise (the observed placement is used when the frame has one).
    """

    particles: NDArray[np.float64]
    weights: NDArray[np.float64]
    rng: np.random.Generator
    placement: NDArray[np.float64] | None = None

    @property
    def empty(self) -> bool:
        return len(self.particles) == 0


class Condensation:
    """Isard & Blake's Condensation behind the estimator interface
    (:class:`tracker_service.estimators.base.Estimator`).

    Parameters
    ----------
    body : Body
        The model's body (the database's).
    camera : Camera
        The database's camera.
    params : CondensationParams
    rng : Generator, optional
        Seeds every :meth:`init` (each gets a child stream, so two filters built with equal seeds
        give equal tracks).
    """

    name = "condensation"

    def __init__(self, body: Body, camera: Camera, params: CondensationParams | None = None,
                 rng: np.random.Generator | None = None) -> None:
        self.body, self.camera = body, camera
        self.params = params or CondensationParams()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.likelihood = PoseLikelihood(body, camera, self.params.level, self.params.sigma)
        self.noise = pose_noise(self.params.root_noise_m, self.params.noise)

    def init(self, placement: NDArray[np.float64] | None = None) -> CondensationState:
        """No particles yet: the next frame draws them around the standing pose."""
        p = None if placement is None else np.asarray(placement, np.float64)
        return CondensationState(np.zeros((0, self.noise.size)), np.zeros(0), self.rng.spawn(1)[0], p)

    def initial_particles(self, placement: NDArray[np.float64] | None, rng: np.random.Generator
                          ) -> NDArray[np.float64]:
        """The standing pose at ``placement`` plus Gaussian noise, within the joint limits."""
        prm = self.params
        ref = reference_pose(self.body, self.camera, placement)
        std = self.noise * prm.init_scale
        std[:3] = prm.init_root_m
        parts = ref + rng.normal(size=(prm.n_particles, ref.size)) * std
        return clamp_pose(parts)

    def step(self, state: CondensationState, observation: Observation) -> tuple[CondensationState, Estimate]:
        """One frame: factored sampling, diffusion, measurement."""
        prm, rng = self.params, state.rng
        if state.empty:
            place = observation.placement if observation.placement is not None else state.placement
            parts = self.initial_particles(place, rng)
        else:
            idx = multinomial_resample(state.weights, prm.n_particles, rng)  # factored sampling
            parts = state.particles[idx] + rng.normal(size=(prm.n_particles, self.noise.size)) * self.noise
            parts = clamp_pose(parts)
        lik = self.likelihood(parts, observation.features)
        w = normalised_weights(lik.neg_log)
        best = int(np.argmax(w))
        est = make_estimate(parts[best], mean_pose(parts, w), float(lik.distance[best]), prm.confidence_scale,
                            (lik.evaluations,), self.camera)
        return CondensationState(parts, w, rng, state.placement), est
