"""ELMO behind the estimator interface (:class:`tracker_service.estimators.base.Estimator`).

Per frame (the paper's Fig. 1):

1. **hypotheses** (§3.1): the observed silhouette's feature queries the PSH index over the
   database's leaves (:mod:`.hashing`); the ``n_hypotheses`` nearest colliding leaves are placed at
   the observed placement (their root where the feet line puts a standing template's). The
   previous frame's modes are hypotheses too (§3.2: "initializations from both the centers of the
   modes at the previous time step as well as pose estimates provided by a global search");
2. **screening**: every hypothesis's likelihood once; the ``n_refine`` best PSH hypotheses and
   every previous mode go on (the budget: the paper refines all ~50, at one second a frame);
3. **local refinement** (§3.2): pattern search of the silhouette likelihood (:mod:`.refine`);
4. **modes** (eq. 3): merged, covariance from the search's curvature and the members' spread,
   weights ∝ likelihood (:mod:`.modes`);
5. **temporal integration** (§3.3, eq. 6): weights times the wide prior of the previous modes;
   the ``max_modes`` heaviest are kept for the next frame.

Without a previous frame (the first, or after :meth:`Elmo.init`) the prior is one mode at the
standing pose facing the camera at the observed placement (``standing_prior``; Condensation starts
there too): the silhouette cannot tell front from back, and a wide prior around a plausible
start resolves it the way the later frames' priors do. With ``standing_prior=False`` the first
frame takes the likelihood's best mode.

The estimate: the heaviest mode is the MAP (``pose_map``), the weighted quaternion mean of the
modes the mean (``pose_mean``); ``leaf = -1``; ``evaluations = (likelihood evaluations,)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import POSE_SIZE, Body
from tracker_service.body.kinematics import fk
from tracker_service.camera import Camera
from tracker_service.estimators.base import Estimate, Observation
from tracker_service.estimators.elmo.hashing import (
    PSHIndex,
    PSHParams,
    build_index,
    leaf_joints,
    observed_mask,
    runs_features,
    silhouette_feature,
)
from tracker_service.estimators.elmo.modes import Modes, merge_modes, reweight
from tracker_service.estimators.elmo.refine import DEFAULT_SEARCH, coordinates, pattern_search
from tracker_service.estimators.likelihood import PoseLikelihood
from tracker_service.estimators.particles import make_estimate, reference_pose
from tracker_service.estimators.tree_filter.filter import mean_pose
from tracker_service.estimators.tree_filter.model import FilterDB
from tracker_service.silhouette.features import LevelFeatures
from tracker_service.silhouette.placement import placement_to_root

__all__ = ["Elmo", "ElmoParams", "ElmoState", "local_modes"]


def local_modes(starts: NDArray[np.float64], previous: Modes | None, likelihood: PoseLikelihood,
                features: list[LevelFeatures], coords: NDArray[np.int64], steps: NDArray[np.float64], body: Body,
                iterations: int, merge_m: float, sigma_eta_m: float, max_modes: int) -> tuple[Modes, int]:
    """§3.2-3.3 from hypotheses to the posterior's modes: each of ``starts (H, P)`` refined by the
    pattern search, merged into modes (eq. 3), reweighted by the wide temporal prior of ``previous``
    (eq. 6), the ``max_modes`` heaviest kept; with the likelihood evaluations spent."""
    found = pattern_search(starts, likelihood, features, coords, steps, iterations)
    modes = merge_modes(found.poses, fk(found.poses, body), found.variance, found.neg_log, found.distance, merge_m)
    post = reweight(modes, previous, sigma_eta_m)
    return post.take(np.argsort(-post.weights, kind="stable")[:max_modes]), found.evaluations


@dataclass(frozen=True)
class ElmoParams:
    """Tuning of :class:`Elmo`.

    Attributes
    ----------
    psh : PSHParams
        The hash index (§3.1).
    n_hypotheses : int
        Leaves the index returns per frame (the paper: 50).
    min_candidates : int
        Fewer colliding leaves than this: rank every leaf instead.
    n_refine : int
        Best PSH hypotheses (by likelihood) refined; the previous modes are refined as well.
    iterations : int
        Rounds of the pattern search (§3.2).
    root_step_m : float
        Initial step of the root position.
    search : dict
        Searched joints and their initial steps (radians).
    sigma : float
        Standard deviation of the Gaussian on distance (Condensation's 0.02).
    level : int
        Pyramid level of the likelihood.
    merge_m : float
        Refined hypotheses within this mean joint distance are one mode.
    sigma_eta_m : float
        ``C_eta = sigma_eta^2 I`` of eq. 4 (metres of mean joint distance): the wide temporal prior.
    max_modes : int
        Modes carried to the next frame.
    standing_prior : bool
        Without a previous frame, the prior is one mode at the standing pose (see the module).
    confidence_scale : float
        ``c`` of the reported confidence.
    """

    psh: PSHParams = field(default_factory=PSHParams)
    n_hypotheses: int = 50
    min_candidates: int = 50
    n_refine: int = 4
    iterations: int = 3
    root_step_m: float = 0.03
    search: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_SEARCH))
    sigma: float = 0.02
    level: int = 1
    merge_m: float = 0.04
    sigma_eta_m: float = 0.15
    max_modes: int = 3
    standing_prior: bool = True
    confidence_scale: float = 0.05


@dataclass(frozen=True)
class ElmoState:
    """The posterior's modes between frames (None before the first frame).

    Attributes
    ----------
    modes : Modes or None
    placement : (3,) float64 or None
        Where to start when a frame has no observed placement.
    """

    modes: Modes | None
    placement: NDArray[np.float64] | None = None


class Elmo:
    """Exploring likelihood modes (Demirdjian et al. 2005).

    Parameters
    ----------
    db : FilterDB
        The template database: its leaves (poses and full-resolution silhouettes) are indexed.
    body : Body
        The database's body (poses rendered and their joints).
    camera : Camera
        The database's camera.
    params : ElmoParams, optional
    rng : Generator, optional
        Learning the hash functions (the tracking itself is deterministic).
    """

    name = "elmo"

    def __init__(self, db: FilterDB, body: Body, camera: Camera, params: ElmoParams | None = None,
                 rng: np.random.Generator | None = None) -> None:
        self.db, self.body, self.camera = db, body, camera
        self.params = prm = params or ElmoParams()
        rng = rng if rng is not None else np.random.default_rng(0)
        feats = runs_features(db.level_runs[-1], prm.psh.grid_rows, prm.psh.grid_cols)
        self.index: PSHIndex = build_index(feats, leaf_joints(db.leaf_poses, body), prm.psh, rng,
                                           np.asarray(db.nbr_idx) if len(db.nbr_idx) else None)
        self.likelihood = PoseLikelihood(body, camera, prm.level, prm.sigma)
        self.coords, self.steps = coordinates(prm.root_step_m, prm.search)

    def init(self, placement: NDArray[np.float64] | None = None) -> ElmoState:
        """No modes yet."""
        return ElmoState(None, None if placement is None else np.asarray(placement, np.float64))

    def hypotheses(self, observation: Observation, placement: NDArray[np.float64] | None) -> NDArray[np.float64]:
        """§3.1: the PSH index's leaves for the observed silhouette, as world poses at ``placement``."""
        prm = self.params
        mask = observed_mask(observation.features[-1])  # the finest level (the leaves' runs' own)
        if not mask.any():
            return np.zeros((0, POSE_SIZE))
        x = silhouette_feature(mask, prm.psh.grid_rows, prm.psh.grid_cols)
        leaves = self.index.query(x, prm.n_hypotheses, prm.min_candidates)
        poses = np.asarray(self.db.leaf_poses[leaves], np.float64).copy()
        if placement is not None:
            for p in poses:
                p[:3] = placement_to_root(placement, p[:3], self.camera)
        return poses

    def step(self, state: ElmoState, observation: Observation) -> tuple[ElmoState, Estimate]:
        """One frame: hypotheses, refinement, modes, temporal reweighting."""
        prm = self.params
        place = observation.placement if observation.placement is not None else state.placement
        previous = state.modes
        if previous is None and prm.standing_prior:
            stand = reference_pose(self.body, self.camera, place)[None]
            previous = Modes(stand, fk(stand, self.body), np.zeros_like(stand), np.zeros(1), np.zeros(1),
                             np.ones(1), np.ones(1, np.int64))
        hyps = self.hypotheses(observation, place)
        evals = 0
        if len(hyps):
            lik = self.likelihood(hyps, observation.features)
            evals += lik.evaluations
            hyps = hyps[np.argsort(lik.neg_log, kind="stable")[: prm.n_refine]]
        starts = hyps if previous is None else np.concatenate([hyps, previous.poses])
        if len(starts) == 0:  # no silhouette and no past: the standing pose
            starts = reference_pose(self.body, self.camera, place)[None]
        post, n = local_modes(starts, previous, self.likelihood, observation.features, self.coords, self.steps,
                              self.body, prm.iterations, prm.merge_m, prm.sigma_eta_m, prm.max_modes)
        evals += n
        best = int(np.argmax(post.weights))
        est = make_estimate(post.poses[best], mean_pose(post.poses, post.weights), float(post.distance[best]),
                            prm.confidence_scale, (evals,), self.camera)
        return ElmoState(post, state.placement), est
