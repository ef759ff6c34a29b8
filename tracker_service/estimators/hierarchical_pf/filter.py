"""Hierarchical particle filter with deterministic (DRS) or stratified (SRS) resampling -- the
online tracking of "upper body motion capture ... 3D cardbox model ... deterministic resampling
strategy" (the cardbox paper; its text: ``upper_body_cardbox_drs.txt`` of the shared papers), on
the whole body.

Algorithm 2 (online motion tracking) splits the pose into partitions estimated one after the
other, each with its own particle set whose particles vary only that partition; the rest of the
pose is the best estimate so far (this frame's for the partitions already done, the last frame's
for those to come):

1. **torso**: root position (Table I: 2 cm noise) and orientation, spine and chest (0.1 rad);
2. **left arm**, 3. **right arm** (independent of each other): shoulder (3 components) and elbow
   (flexion and abduction components; the twist about the bone is invisible to a capsule),
   0.25 rad;
4. **left leg**, 5. **right leg** (not in the paper, which tracks the upper body only): hip and
   knee flexion, 0.1 rad.

Each partition's particles are initialised by eq. 7 (the reference posture -- the standing pose at
the observed placement -- plus Gaussian noise) and then, per frame, resampled by

* **DRS** (Algorithm 4, eq. 11-13; :func:`tracker_service.estimators.resampling.deterministic_resample`):
  rank by cost, keep the best, perturb the best ``rho N`` (survival rate, Table I: 0.2 torso, 0.4
  arms), redraw the rest around the best; or
* **SRS** (Algorithm 3, eq. 8-10; :func:`tracker_service.estimators.resampling.stratified_resample`):
  probabilities ``exp(-c^2 / (2 sigma_c^2))`` of the costs (eq. 8, Table I: ``sigma_c`` = 8000 px
  torso, 4000 px arms), normalised (eq. 9), accumulated (eq. 10), drawn stratified, then perturbed
  by the partition's noise.

The cost of a particle is its silhouette distance (:mod:`tracker_service.estimators.likelihood`) as
full-resolution pixel counts (the paper's costs are XOR pixel counts; with a cwXOR / nwXOR
observation these are weighted pixel counts). The estimate is the best particle of each partition
("the particle with the lowest cost is considered to be the estimation result"); ``pose_mean`` is
the same pose.

Particles: 600 in all by default, as the paper (which has 3 partitions of 200): 200 torso, 150 per
arm, 50 per leg here.

Every candidate pose is clipped to the joint limits (:func:`protocol.skeleton.clamp_pose`) before it
is evaluated; joints in no partition (clavicles, wrists, neck, head, ankles) stay at the reference
posture.

The likelihood renders this project's capsule body by default; with ``HPFParams.cardbox`` (the
``drs-cardbox`` and ``srs-cardbox`` estimators) it draws the paper's 3D cardbox model
(:mod:`tracker_service.body.cardbox`), its sizes from the paper's offline initialisation
(Algorithm 1, :func:`tracker_service.body.cardbox_fit.fit_sizes`) when reference images are given.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import Body, clamp_pose
from tracker_service.body.cardbox import CardboxModel
from tracker_service.body.cardbox_fit import FitParams, fit_sizes
from tracker_service.camera import Camera
from tracker_service.estimators.base import Estimate, Observation
from tracker_service.estimators.likelihood import CardboxLikelihood, PoseLikelihood
from tracker_service.estimators.particles import joint_slice, make_estimate, reference_pose
from tracker_service.estimators.resampling import deterministic_resample, stratified_resample

__all__ = ["DEFAULT_STAGES", "HPFParams", "HPFState", "HierarchicalPF", "Stage", "stage_dims"]

Resampling = Literal["drs", "srs"]


@dataclass(frozen=True)
class Stage:
    """One partition of Algorithm 2.

    Attributes
    ----------
    name : str
    dims : tuple of int
        Pose-vector entries the partition's particles vary.
    n_particles : int
    survival : float
        DRS survival rate ``rho`` (Table I).
    rot_noise : float
        Noise of the rotation entries, radians (Table I).
    trans_noise : float
        Noise of the root position entries, metres (Table I: 2 cm, torso only).
    cost_sigma_px : float
        SRS's ``sigma`` of eq. 8, full-resolution pixels (Table I).
    dim_scale : tuple of float
        Per-entry multiplier of the noise (empty: 1): the rotations in the sagittal plane (about x:
        bending forwards and back), which a frontal silhouette hardly sees, get less, or a greedy
        search drifts along them.
    """

    name: str
    dims: tuple[int, ...]
    n_particles: int
    survival: float
    rot_noise: float
    trans_noise: float
    cost_sigma_px: float
    dim_scale: tuple[float, ...] = ()

    def noise(self) -> NDArray[np.float64]:
        """(D,) standard deviations of the partition's entries (times ``dim_scale`` when given)."""
        d = np.asarray(self.dims)
        std = np.where(d < 3, self.trans_noise, self.rot_noise)
        return std * np.asarray(self.dim_scale) if self.dim_scale else std


def stage_dims(*parts: str | tuple[str, tuple[int, ...]], root: bool = False) -> tuple[int, ...]:
    """Pose-vector entries of joints (all three rotation-vector components, or ``(name, components)``),
    with the root position first when ``root``."""
    out: list[int] = [0, 1, 2] if root else []
    for p in parts:
        name, comps = (p, (0, 1, 2)) if isinstance(p, str) else p
        s = joint_slice(name)
        out += [s.start + c for c in comps]
    return tuple(out)


#: Table I's torso and arms (N = 200 each in the paper; 200 / 150 / 150 here, with 50 per leg).
DEFAULT_STAGES: tuple[Stage, ...] = (
    Stage("torso", stage_dims("pelvis", "spine", "chest", root=True), 200, 0.2, 0.1, 0.02, 8000.0),
    Stage("l_arm", stage_dims("l_shoulder", ("l_elbow", (1, 2))), 150, 0.4, 0.25, 0.0, 4000.0),
    Stage("r_arm", stage_dims("r_shoulder", ("r_elbow", (1, 2))), 150, 0.4, 0.25, 0.0, 4000.0),
    Stage("l_leg", stage_dims("l_hip", ("l_knee", (0,))), 50, 0.4, 0.1, 0.0, 4000.0),
    Stage("r_leg", stage_dims("r_hip", ("r_knee", (0,))), 50, 0.4, 0.1, 0.0, 4000.0),
)


@dataclass(frozen=True)
class HPFParams:
    """Tuning of :class:`HierarchicalPF`.

    Attributes
    ----------
    resampling : {'drs', 'srs'}
    stages : tuple of Stage
        The partitions, in the order they are estimated (:data:`DEFAULT_STAGES`).
    level : int
        Pyramid level of the likelihood.
    systematic : bool
        SRS with one offset for every stratum (systematic) instead of one per stratum.
    cycles : int
        Estimation cycles (Algorithm 2's loop over the partitions) per frame; the paper runs one
        per camera frame.
    confidence_scale : float
        ``c`` of the reported confidence (the tree filter's).
    cardbox : CardboxModel, optional
        Draw the paper's 3D cardbox model (:mod:`tracker_service.body.cardbox`) instead of the
        capsule body.
    fit : FitParams, optional
        With the cardbox: on the first frame its sizes are fitted by the paper's Algorithm 1
        (:func:`tracker_service.body.cardbox_fit.fit_sizes`) with that frame as the reference
        image and the reference posture (standing, at the observed placement) as its known
        posture, as the paper's person stands in it to start; None: the initial guess is kept.
    """

    resampling: Resampling = "drs"
    stages: tuple[Stage, ...] = DEFAULT_STAGES
    level: int = 1
    systematic: bool = False
    cycles: int = 1
    confidence_scale: float = 0.05
    cardbox: CardboxModel | None = None
    fit: FitParams | None = field(default_factory=FitParams)

    @property
    def n_particles(self) -> int:
        return sum(s.n_particles for s in self.stages)


@dataclass(frozen=True)
class HPFState:
    """The partitions' particle sets between frames (empty before the first frame).

    Attributes
    ----------
    pose : (P,) float64 or None
        The best pose of the last frame (world root).
    particles : tuple of (n_k, D_k) float64
        Each partition's particles (its entries only).
    costs : tuple of (n_k,) float64
        Their costs, full-resolution pixels.
    rng : Generator
    placement : (3,) float64 or None
        Where to initialise when a frame has no observed placement.
    cardbox : CardboxModel or None
        The cardbox model as fitted on the first frame (None: the filter's own).
    """

    pose: NDArray[np.float64] | None
    particles: tuple[NDArray[np.float64], ...]
    costs: tuple[NDArray[np.float64], ...]
    rng: np.random.Generator
    placement: NDArray[np.float64] | None = None
    cardbox: CardboxModel | None = None


class HierarchicalPF:
    """The cardbox paper's hierarchical particle filter behind the estimator interface; named
    ``"drs"`` or ``"srs"`` after its resampling.

    Parameters
    ----------
    body : Body
        The model's body (the database's).
    camera : Camera
        The database's camera.
    params : HPFParams
    rng : Generator, optional
        Seeds every :meth:`init` (a child stream each).
    """

    def __init__(self, body: Body, camera: Camera, params: HPFParams | None = None,
                 rng: np.random.Generator | None = None) -> None:
        self.body, self.camera = body, camera
        self.params = params or HPFParams()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.name = self.params.resampling + ("-cardbox" if self.params.cardbox is not None else "")
        self.likelihood: PoseLikelihood | CardboxLikelihood = (
            PoseLikelihood(body, camera, self.params.level) if self.params.cardbox is None
            else CardboxLikelihood(self.params.cardbox, camera, self.params.level))

    def init(self, placement: NDArray[np.float64] | None = None) -> HPFState:
        """No particles yet: the next frame initialises every partition by eq. 7."""
        p = None if placement is None else np.asarray(placement, np.float64)
        return HPFState(None, (), (), self.rng.spawn(1)[0], p)

    def _candidates(self, stage: Stage, prev: NDArray[np.float64] | None, cost: NDArray[np.float64] | None,
                    ref: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.float64]:
        """The partition's new particles: eq. 7 on the first frame, else DRS or SRS of ``prev``."""
        std = stage.noise()
        n = stage.n_particles
        if prev is None or cost is None:  # eq. 7: the reference posture plus noise (the first one unperturbed)
            x = ref[list(stage.dims)] + rng.normal(size=(n, len(std))) * std
            x[0] = ref[list(stage.dims)]
            return x
        if self.params.resampling == "drs":  # Algorithm 4, eq. 11-13
            return deterministic_resample(prev, cost, stage.survival, std, rng, n)
        # Algorithm 3: eq. 8 (Gaussian of the cost), eq. 9-10 in stratified_resample, then noise
        log_p = -0.5 * (np.where(np.isfinite(cost), cost, np.inf) / stage.cost_sigma_px) ** 2
        p = np.exp(log_p - log_p.max())
        idx = stratified_resample(p, n, rng, self.params.systematic)
        return prev[idx] + rng.normal(size=(n, len(std))) * std

    def step(self, state: HPFState, observation: Observation) -> tuple[HPFState, Estimate]:
        """One frame: the partitions in order, each resampled, evaluated, its best kept."""
        rng = state.rng
        likelihood, cardbox = self.likelihood, state.cardbox
        if state.pose is None:
            place = observation.placement if observation.placement is not None else state.placement
            pose = reference_pose(self.body, self.camera, place)
            if self.params.cardbox is not None and self.params.fit is not None:  # Algorithm 1
                cardbox, _ = fit_sizes(self.params.cardbox, [(observation.features, pose)], self.camera, rng,
                                       self.params.fit)
        else:
            pose = state.pose.copy()
        if cardbox is not None and isinstance(likelihood, CardboxLikelihood):
            likelihood = replace(likelihood, model=cardbox)
        stages = self.params.stages
        parts: list[NDArray[np.float64] | None] = list(state.particles) if state.particles else [None] * len(stages)
        costs: list[NDArray[np.float64] | None] = list(state.costs) if state.costs else [None] * len(stages)
        evals = [0] * len(stages)
        dist = np.inf
        for _ in range(max(1, self.params.cycles)):  # Algorithm 2's loop over the partitions
            for k, stage in enumerate(stages):
                dims = list(stage.dims)
                cand = self._candidates(stage, parts[k], costs[k], pose, rng)
                full = np.repeat(pose[None], len(cand), axis=0)
                full[:, dims] = cand
                full = clamp_pose(full)
                lik = likelihood(full, observation.features)
                c = likelihood.full_resolution_pixels(lik.distance, observation.features)
                best = int(np.argmin(c))
                pose = full[best]
                dist = float(lik.distance[best])
                parts[k], costs[k] = full[:, dims], c
                evals[k] += lik.evaluations
        est = make_estimate(pose, pose, dist, self.params.confidence_scale, tuple(evals), self.camera)
        new_parts = tuple(x for x in parts if x is not None)
        new_costs = tuple(x for x in costs if x is not None)
        return HPFState(pose, new_parts, new_costs, rng, state.placement, cardbox), est
