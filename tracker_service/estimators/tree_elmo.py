"""The tree filter's estimate refined to the nearest likelihood mode (Okada & Stenger + ELMO).

The combination the estimator benchmark suggested: the tree filter (Okada & Stenger's Algorithm 1
search with every cue) is by far the best *global* search measured, but its poses are the
database's discrete leaves (joint angles on a grid, the nearest template), while ELMO's local
refinement (§3.2, :mod:`tracker_service.estimators.elmo.refine`) moves a pose continuously to the
nearest mode of the silhouette likelihood. Per frame:

1. the tree filter's step (:class:`~tracker_service.estimators.tree_filter.filter.TreeFilter`), its
   posterior and dynamics unchanged;
2. hypotheses (ELMO §3.2, "initializations from both the centers of the modes at the previous time
   step as well as pose estimates provided by a global search"): the tree's MAP leaf and its
   posterior mean, in the world at the tree's placement, and the previous frame's modes;
3. each refined by the pattern search of the rendered body's silhouette likelihood, merged into
   modes (eq. 3) and reweighted by the wide temporal prior of the previous modes (§3.3, eq. 6):
   ELMO's own steps (:func:`~tracker_service.estimators.elmo.filter.local_modes`); the heaviest
   mode is the estimate (``pose_map`` and ``pose_mean``).

The tree's posterior (its leaves, weights, occlusion, support) stays the tree's: the publishing
stages that read it (the shoe cue's legs, depth from the feet line) see the same leaf and support
as with ``tree``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import Body
from tracker_service.camera import Camera
from tracker_service.estimators.base import Estimate, Observation
from tracker_service.estimators.elmo.filter import local_modes
from tracker_service.estimators.elmo.modes import Modes
from tracker_service.estimators.elmo.refine import DEFAULT_SEARCH, coordinates
from tracker_service.estimators.likelihood import PoseLikelihood, placement_of_root
from tracker_service.estimators.particles import world_pose
from tracker_service.estimators.tree_filter.filter import FilterDB, FilterParams, FilterState, initial_state, step

__all__ = ["TreeElmo", "TreeElmoParams", "TreeElmoState"]


@dataclass(frozen=True)
class TreeElmoParams:
    """Tuning of :class:`TreeElmo`.

    Attributes
    ----------
    iterations : int
        Rounds of the pattern search (each ``2 C + 1`` likelihood evaluations per hypothesis).
    root_step_m : float
        Initial step of the root position (0: the tree's placement is kept).
    search : dict
        Searched joints and their initial steps (radians).
    sigma : float
        Standard deviation of the Gaussian on distance.
    level : int
        Pyramid level of the likelihood.
    merge_m : float
        Refined hypotheses within this mean joint distance are one mode.
    sigma_eta_m : float
        The wide temporal prior's ``sigma_eta`` (metres of mean joint distance).
    max_modes : int
        Modes carried to the next frame.
    """

    iterations: int = 2
    root_step_m: float = 0.02
    search: dict[str, float] = field(default_factory=lambda: {k: v / 2 for k, v in DEFAULT_SEARCH.items()})
    sigma: float = 0.02
    level: int = 1
    merge_m: float = 0.04
    sigma_eta_m: float = 0.15
    max_modes: int = 2


@dataclass(frozen=True)
class TreeElmoState(FilterState):
    """The tree filter's posterior and the refined modes of the last frame.

    Attributes
    ----------
    modes : Modes or None
        The previous frame's refined modes (None after a re-initialisation).
    """

    modes: Modes | None = None


def _with_modes(state: FilterState, modes: Modes | None) -> TreeElmoState:
    return TreeElmoState(**{f.name: getattr(state, f.name) for f in fields(FilterState)}, modes=modes)


class TreeElmo:
    """The tree filter refined to the nearest likelihood mode.

    Parameters
    ----------
    db : FilterDB
    body : Body
        The database's body (the refinement renders it).
    camera : Camera
        The database's camera.
    filter_params : FilterParams
        The tree filter's tuning.
    params : TreeElmoParams, optional
    """

    name = "tree-elmo"

    def __init__(self, db: FilterDB, body: Body, camera: Camera, filter_params: FilterParams,
                 params: TreeElmoParams | None = None) -> None:
        self.db, self.body, self.camera, self.filter_params = db, body, camera, filter_params
        self.params = prm = params or TreeElmoParams()
        self.likelihood = PoseLikelihood(body, camera, prm.level, prm.sigma)
        coords, steps = coordinates(prm.root_step_m, prm.search)
        keep = slice(0 if prm.root_step_m > 0 else 3, None)  # root position searched or kept
        self.coords, self.steps = coords[keep], steps[keep]

    def init(self, placement: NDArray[np.float64] | None = None) -> TreeElmoState:
        """No pose information."""
        return _with_modes(initial_state(placement), None)

    def step(self, state: FilterState, observation: Observation) -> tuple[TreeElmoState, Estimate]:
        """One frame: the tree filter's step, then its estimate refined (see the module)."""
        prm = self.params
        previous = state.modes if isinstance(state, TreeElmoState) else None
        tstate, est = step(state, self.db, observation, self.filter_params)
        if est.reinitialised:
            previous = None
        starts = np.stack([world_pose(est, self.camera), world_pose(est, self.camera, mean=True)])
        if previous is not None:
            carried = previous.poses.copy()
            if prm.root_step_m <= 0:  # the root is the tree's: the previous modes carry their joints only
                carried[:, :3] = starts[0, :3]
            starts = np.concatenate([starts, carried])
        post, n = local_modes(starts, previous, self.likelihood, observation.features, self.coords, self.steps,
                              self.body, prm.iterations, prm.merge_m, prm.sigma_eta_m, prm.max_modes)
        best = int(np.argmax(post.weights))
        pose = post.poses[best].copy()
        ref = est.pose_map[:3]  # the template's own root: the placement keeps the tree's meaning
        placement = placement_of_root(pose[:3], ref, self.camera)
        pose[:3] = ref
        out = replace(est, pose_map=pose, pose_mean=pose.copy(), placement=placement,
                      evaluations=(*est.evaluations, n))
        return _with_modes(tstate, post), out
