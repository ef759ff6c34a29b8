"""The estimator interface: every pose estimator observes the same frame and returns the same estimate.

An estimator is a pair of pure functions over its own state (filterpy's style)::

    state = estimator.init(placement)                    # no information, or a known placement
    state, estimate = estimator.step(state, observation) # one frame

The :class:`Observation` is built once per frame by the pipeline
(:mod:`tracker_service.pipeline.process`): the silhouette's features on the image pyramid (Okada &
Stenger eq. 7-12), the placement measured from the feet line, the silhouette's rows, the skin
evidence, and the other cues as a list of :class:`LeafCost` (each a weighted cost over template
leaves at placements) with the leaves they propose. Estimators differ only in how they search the
pose space: the tree filter (:mod:`tracker_service.estimators.tree_filter`) walks the template
hierarchy of Algorithm 1.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Generic, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from tracker_service.cues.skin import SkinObservation
from tracker_service.silhouette.features import LevelFeatures

__all__ = ["Estimate", "Estimator", "LeafCost", "Observation", "leaf_cue_cost"]

StateT = TypeVar("StateT")


@dataclass(frozen=True)
class LeafCost:
    """A cue's evidence over template leaves: ``weight * cost(leaves, places)``.

    Attributes
    ----------
    name : str
        The cue (``shoes``, ``appearance``, ...), for logs and profiles.
    weight : float
        Its weight in the negative log likelihood (0: off).
    cost : callable
        ``cost(leaves (n,) int64, places (n, 3) float64) -> (n,) float64 or None``: None when the cue
        has nothing to say this frame.
    """

    name: str
    weight: float
    cost: Callable[[NDArray[np.int64], NDArray[np.float64]], NDArray[np.float64] | None]


def leaf_cue_cost(cues: Sequence[LeafCost], leaves: NDArray[np.int64], places: NDArray[np.float64]
                  ) -> NDArray[np.float64] | None:
    """The cues' added negative log likelihood of ``leaves`` at ``places``, in the cues' order.

    Each cue is weighted and taken relative to its cheapest leaf; a cue that answers None, or any
    non-finite cost (which would poison the posterior for good), is skipped.

    Parameters
    ----------
    cues : sequence of LeafCost
    leaves : (n,) int64
    places : (n, 3) float64

    Returns
    -------
    (n,) float64 or None
        None when no cue applies.
    """
    out = None
    for cue in cues:
        if cue.weight <= 0:
            continue
        c = cue.cost(leaves, places)
        if c is None or not np.isfinite(c).all():
            continue
        a = cue.weight * (c - c.min())
        out = a if out is None else out + a
    return out


@dataclass(frozen=True)
class Observation:
    """What every estimator sees of one frame.

    Attributes
    ----------
    features : list of LevelFeatures
        The silhouette's features, coarse to fine (:func:`tracker_service.silhouette.features.preprocess`).
    placement : (3,) float64 or None
        ``(dx, dy, s)`` measured from the silhouette's feet line and centre
        (:func:`tracker_service.silhouette.placement.observed_placement`, scaled for the body size).
    rows : (2,) float64 or None
        Top and bottom rows of the silhouette (:func:`tracker_service.silhouette.placement.silhouette_rows`).
    skin : SkinObservation or None
        Skin evidence (:func:`tracker_service.cues.skin.observe_skin`): where the hands may be.
    leaf_costs : tuple of LeafCost
        The other cues' costs over leaves (shoes, appearance), in the order they are summed.
    proposals : (n,) int64 or None
        Leaves proposed by a cue (the appearance network's nearest leaves).
    min_scale : float or None
        With the feet cut off by the bottom border (no ``placement``): the least scale the person
        can be at (:func:`tracker_service.pipeline.observe.nearest_scale`, scaled for the body
        size); None otherwise. The tree filter (and so ``tree-elmo``'s start) holds its placement to
        it; the particle filters and ELMO, comparisons of the papers, do not read it.
    """

    features: list[LevelFeatures]
    placement: NDArray[np.float64] | None = None
    rows: NDArray[np.float64] | None = None
    skin: SkinObservation | None = None
    leaf_costs: tuple[LeafCost, ...] = ()
    proposals: NDArray[np.int64] | None = None
    min_scale: float | None = None


@dataclass(frozen=True)
class Estimate:
    """Result of one estimator step.

    Attributes
    ----------
    leaf : int
        MAP leaf.
    pose_map : (P,) float64
        MAP leaf pose (reference placement; the caller turns the placement into a root position).
    pose_mean : (P,) float64
        Posterior-mean pose over the retained leaves.
    placement : (3,) float64
        ``(dx, dy, s)``, full-resolution pixels.
    distance : float
        Best full-resolution silhouette distance.
    confidence : float
        ``exp(-d^2 / (2 c^2))`` of the full-resolution distance (``c = confidence_scale``), in [0, 1].
    visibility : (N_PARTS,) float32
        Visible fraction of each part in the MAP template.
    evaluations : tuple of int
        Distance evaluations per level (Table 2).
    reinitialised : bool
    support_places : (K, 3) float64
        Best placement of each of the ``K`` support leaves, in the order of the new
        ``FilterState.leaves`` (which is empty after a re-initialisation).
    support_cost : (K,) float64
        Each support leaf's cost at that placement: eq. 6's negative log likelihood plus the
        placement prior, the skin cue, the shoe cue (``FilterParams.shoe_weight``) and the
        appearance cue (``FilterParams.appearance_weight``).
    support_leaves : (K,) int64
        The support leaves themselves (``FilterState.leaves`` before any re-initialisation).
    support_weights : (K,) float64
        Their posterior weights (sum 1), untempered.
    """

    leaf: int
    pose_map: NDArray[np.float64]
    pose_mean: NDArray[np.float64]
    placement: NDArray[np.float64]
    distance: float
    confidence: float
    visibility: NDArray[np.float32]
    evaluations: tuple[int, ...]
    reinitialised: bool
    support_places: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    support_cost: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    support_leaves: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    support_weights: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))


class Estimator(Protocol, Generic[StateT]):
    """A pose estimator: pure ``init`` and ``step`` over its own state type."""

    name: str

    def init(self, placement: NDArray[np.float64] | None = None) -> StateT:
        """The state with no pose information (after a loss), at ``placement`` when known."""
        ...

    def step(self, state: StateT, observation: Observation) -> tuple[StateT, Estimate]:
        """One frame: the new state and the frame's estimate."""
        ...
