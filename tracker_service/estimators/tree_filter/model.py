"""The tree filter's data: the database it searches, its tuning, its state between frames and
its per-frame estimate (Okada & Stenger §2). The algorithm is in :mod:`tracker_service.estimators.tree_filter.filter`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import N_JOINTS, N_PARTS
from tracker_service.estimators.base import Estimate
from tracker_service.silhouette.distance import RunSet
from tracker_service.templates.tree import TemplateTree

__all__ = ["Estimate", "FilterDB", "FilterParams", "FilterState"]


@dataclass(frozen=True)
class FilterDB:
    """What the filter needs of a template database (see :mod:`tracker_service.templates.database`).

    Attributes
    ----------
    tree : TemplateTree
    level_runs : tuple of RunSet
        Prototype silhouette runs of every node of each level, at that level's resolution.
    level_scale : tuple of float
        Pixel scale of each level relative to full resolution (e.g. 0.25, 0.5, 1).
    center : (float, float)
        Scaling centre (principal point) at full resolution.
    leaf_poses : (NL, P) float32
        Pose of each leaf's prototype, rendered at the reference placement.
    leaf_visible : (NL, N_PARTS) float32
        Visible fraction of each part in each leaf's template.
    leaf_anc : (L, NL) int64
        Ancestor node of each leaf at every level (the last row is ``arange(NL)``).
    leaf_heading : (NL,) float32
        Heading (yaw, radians; 0 = facing the camera) of each leaf's pose.
    trans_ptr, trans_idx, trans_p : CSR (NL + 1,), (E,), (E,)
        Leaf transition histograms (row-normalised) from the recordings' frame order.
    nbr_idx : (NL, K) int64
        Nearest leaves in pose space (first column: the leaf itself).
    nbr_dpart : (NL, K, N_PARTS) float32
        Squared joint-angle differences (rad^2) to each neighbour, summed per body part.
    sigma_part : (N_PARTS,) float32
        Per-part standard deviation of eq. 13 (radians per frame at 30 Hz).
    level_column : tuple of (n_L,) float64, optional
        Each node's template column at the reference placement, full-resolution pixels
        (:func:`tracker_service.silhouette.placement.template_columns`); empty: no per-template correction
        of the observed shift.
    ref_column : float
        The column :func:`tracker_service.silhouette.placement.observed_placement` assumes for every template.
    level_bottom : tuple of (n_L,) float64, optional
        Each node's lowest template row at the reference placement, full-resolution pixels
        (:func:`tracker_service.silhouette.placement.template_bottoms`); empty: every template is taken to
        stand on the floor.
    level_top : tuple of (n_L,) float64, optional
        Each node's highest template row (:func:`tracker_service.silhouette.placement.template_tops`).
    ref_bottom : float
        The row a standing template's lowest row lies on (the observed feet line's reference).
    leaf_points : (NL, J, 2) float32, optional
        Image position of every joint of each leaf's template at the reference placement
        (:func:`tracker_service.cues.skin.leaf_joint_points` of the leaves' joints); empty: no skin cue.
    leaf_joints3d : (NL, J, 3) float32, optional
        Every leaf's joints relative to its pelvis in the camera's axes, over the body's height
        (:func:`tracker_service.cues.appearance.camera_joints` of the leaves' joints); empty: no appearance cue.
    """

    tree: TemplateTree
    level_runs: tuple[RunSet, ...]
    level_scale: tuple[float, ...]
    center: tuple[float, float]
    leaf_poses: NDArray[np.float32]
    leaf_visible: NDArray[np.float32]
    leaf_anc: NDArray[np.int64]
    leaf_heading: NDArray[np.float32]
    trans_ptr: NDArray[np.int64]
    trans_idx: NDArray[np.int64]
    trans_p: NDArray[np.float32]
    nbr_idx: NDArray[np.int64]
    nbr_dpart: NDArray[np.float32]
    sigma_part: NDArray[np.float32]
    level_column: tuple[NDArray[np.float64], ...] = ()
    ref_column: float = float("nan")
    level_bottom: tuple[NDArray[np.float64], ...] = ()
    level_top: tuple[NDArray[np.float64], ...] = ()
    ref_bottom: float = float("nan")
    leaf_points: NDArray[np.float32] = field(default_factory=lambda: np.zeros((0, N_JOINTS, 2), np.float32))
    leaf_joints3d: NDArray[np.float32] = field(default_factory=lambda: np.zeros((0, N_JOINTS, 3), np.float32))

    @property
    def n_leaves(self) -> int:
        return int(self.leaf_poses.shape[0])

    @property
    def leaf_facing(self) -> NDArray[np.bool_]:
        """(NL,) bool: leaves facing the camera (|heading| < 90 degrees)."""
        return np.abs(self.leaf_heading) < np.pi / 2


@dataclass(frozen=True)
class FilterParams:
    """Tuning of the filter (defaults documented in docs/TRACKER.md).

    Attributes
    ----------
    sigma : tuple of float
        Likelihood standard deviation per level (eq. 6), in distance units.
    keep_rel : float
        Nodes with posterior below ``keep_rel`` times the level's best are pruned.
    max_keep : tuple of int
        At most this many nodes are expanded per level.
    keep_likelihood : tuple of int
        Per level, the best nodes by likelihood alone are expanded as well (the data-driven
        proposal: a misleading prior cannot prune the subtree that explains the silhouette).
        (24, 96): with the appearance cue's proposals the level-0 ones past the best 24 changed
        nothing (51 held-out takes, three subjects: the same MPJPE within 0.02 cm) and cost 14 %
        of the frame time; (96, 192), the setting before the cue, is in docs/TRACKER.md.
    grid : tuple of (int, int)
        Placement search grid (shift steps x scale steps) per level, around each node's parent's
        best placement.
    screen : tuple of int
        Per level, the placement grid in two passes when > 0: every node at its predicted
        placement first, then the full grid only for the ``screen[level]`` best nodes by posterior
        and as many best by likelihood (the grid's other cells matter only for nodes that would
        rank there). 0 (or a level past the tuple) evaluates every node on the full grid.
    refine : int
        Best leaves whose placement is refined at full resolution.
    placement_sigma_px, placement_sigma_scale : float
        Gaussian prior of the placement around the prediction (shift in pixels, relative scale).
    observation_weight : float
        Weight of the placement measured from the silhouette against the motion prediction.
    uniform_mass : float
        Prior mass spread uniformly over the leaves whose heading is within ``max_turn`` of the
        current estimate (re-acquisition of the pose; a person does not turn round in a frame).
    max_turn : float
        Heading range (radians) of the uniform mass around the current heading.
    hist_weight : float
        Weight of the transition histograms against the Gaussian dynamics.
    max_heading : float or None
        Leaves turned further than this (radians) from facing the camera get no prior mass: an
        application whose user faces the screen (the game) says so, and the front/back and
        turned-body ambiguities of the silhouette go away. None: any heading.
    occlusion_m : float
        ``m`` of eq. 14.
    support : int
        Leaves carried to the next frame.
    height_hypothesis : bool
        Besides the feet-on-the-floor placement, evaluate each node at the scale that gives it the
        silhouette's height, its lowest row on the observed one (a leap, a run's flight phase).
    airborne_cost : float
        Prior cost (negative log odds) of the height hypothesis against the feet on the floor.
    airborne_gate : float
        The height hypothesis is evaluated only when the feet line rose (its scale is below the
        motion prediction's by more than this fraction): the person stepped back or left the floor.
    airborne_scale_range : float
        The height hypothesis's scale stays within this fraction of the motion prediction's.
    mean_temperature : float
        The posterior-mean pose weighs the support leaves by ``posterior ** (1 / T)``: ``T`` > 1
        hedges between the modes of an ambiguous silhouette (1: the posterior itself).
    step_px : float
        Placement search step (full-resolution pixels) at the coarsest level.
    step_scale : float
        Relative scale search step at the coarsest level.
    lost_distance : float
        A frame whose best level-3 distance exceeds this counts as a miss.
    lost_frames : int
        Consecutive misses that trigger re-initialisation.
    confidence_scale : float
        Distance at which the reported confidence ``exp(-d^2 / (2 c^2))`` is 0.61.
    skin_weight : float
        Weight of the skin cue (:func:`tracker_service.cues.skin.hand_cost`) added to eq. 6's negative
        log likelihood from level ``skin_from_level`` on; 0 disables it.
    skin_sigma_px, skin_cap_px, skin_hidden_cost : float
        Hand-to-skin distance scale and cap (full-resolution pixels), cost of a hidden hand.
    skin_cover_weight, skin_cover_radius_px : float
        Weight of the reverse term (:func:`tracker_service.cues.skin.cover_cost`: skin no limb of the
        template explains) and the limb half-width it allows (full-resolution pixels).
    skin_cover_from_level : int
        First level where the reverse term is added (it costs ``K x S`` per evaluation).
    skin_min_visible : float
        A template's hand counts as visible above this visible fraction of the hand part.
    skin_max_fraction : float
        The cue is off for frames whose silhouette is more than this fraction skin (a skin-coloured
        shirt).
    shoe_weight : float
        Weight of the shoe cue's cost (:func:`tracker_service.cues.shoes.feet_cost`, relative to the
        cheapest leaf) in the leaf level's negative log likelihood (a ``LeafCost`` of the observation);
        0: the cue only re-weights the published legs. 0.02: over the 51 held-out takes, root
        error -0.14 / -0.15 / -0.49 cm on three subjects, MPJPE -0.02 cm on average (0.05 was
        worse; docs/TRACKER.md). The published legs' re-weighting
        (``ShoeParams.weight``) multiplies the support's tempered posterior, which already holds
        this term (``exp(-shoe_weight * cost / T)``): the two were tuned together. The term is
        scored at each leaf's placement before the refinement and held over the refinement grid.
    appearance_weight : float
        Weight of the appearance cue's cost (:func:`tracker_service.cues.appearance.joints_cost`,
        relative to the cheapest leaf) in the leaf level's negative log likelihood
        (a ``LeafCost`` of the observation); 0: off. 1: the network's Gaussian at face value; 8 held-out
        takes gave 6.97 / 6.80 / 6.66 / 6.58 / 6.52 / 6.49 / 6.47 cm at 0.05 / 0.1 / 0.2 / 0.6 / 1 / 2 / 4
        (docs/TRACKER.md).
    appearance_coords : tuple of int
        Coordinates of the joints the appearance cue scores (0 = x, 1 = y, 2 = depth).
    appearance_proposals : int
        Leaves the appearance cue proposes from the whole database each frame (its best by
        :func:`tracker_service.cues.appearance.propose_leaves` among the headings within ``max_turn``
        of the current one), evaluated at the leaf level beside the tree's candidates; 0: none
        (64 gave the same as 32).
    """

    sigma: tuple[float, ...] = (0.01, 0.01, 0.01)
    keep_rel: float = 2e-3
    max_keep: tuple[int, ...] = (16, 48)
    keep_likelihood: tuple[int, ...] = (24, 96)
    grid: tuple[tuple[int, int], ...] = ((3, 3), (3, 1), (1, 1))
    screen: tuple[int, ...] = (48, 48)
    refine: int = 6
    placement_sigma_px: float = 6.0
    placement_sigma_scale: float = 0.03
    observation_weight: float = 0.7
    uniform_mass: float = 0.05
    max_turn: float = 1.0
    hist_weight: float = 0.5
    max_heading: float | None = None
    occlusion_m: float = 5.0
    support: int = 48
    mean_temperature: float = 5.0
    height_hypothesis: bool = True
    airborne_cost: float = 3.0
    airborne_gate: float = 0.04
    airborne_scale_range: float = 0.06
    step_px: float = 8.0
    step_scale: float = 0.05
    lost_distance: float = 0.15
    lost_frames: int = 6
    confidence_scale: float = 0.05
    skin_weight: float = 2.0
    skin_from_level: int = 1
    skin_sigma_px: float = 4.0
    skin_cap_px: float = 16.0
    skin_hidden_cost: float = 1.0
    skin_min_visible: float = 0.25
    skin_max_fraction: float = 0.45
    skin_cover_weight: float = 6.0
    skin_cover_from_level: int = 2
    skin_cover_radius_px: float = 6.0
    shoe_weight: float = 0.02
    appearance_weight: float = 1.0
    appearance_coords: tuple[int, ...] = (0, 1, 2)
    appearance_proposals: int = 32


@dataclass(frozen=True)
class FilterState:
    """Posterior carried between frames.

    Attributes
    ----------
    leaves : (M,) int64
        Supported leaves.
    weights : (M,) float64
        Their posterior probabilities (sum 1); empty means "no information" (initial state).
    placement : (3,) float64
        ``(dx, dy, s)`` of the MAP estimate (full-resolution pixels).
    velocity : (3,) float64
        Per-frame change of the placement.
    occluded : (N_PARTS,) bool
        Parts occluded in the last estimate (eq. 14).
    misses : int
        Consecutive frames above ``lost_distance``.
    reinits : int
        Re-initialisations so far.
    """

    leaves: NDArray[np.int64]
    weights: NDArray[np.float64]
    placement: NDArray[np.float64]
    velocity: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    occluded: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(N_PARTS, bool))
    misses: int = 0
    reinits: int = 0
