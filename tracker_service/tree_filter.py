"""Tree-based Bayesian filtering over the shape hierarchy (Okada & Stenger §2, eq. 1-6, 13-14).

The state is a leaf of the template tree (a pose) plus the subject's global placement in the image
(a shift ``(dx, dy)`` and a scale ``s`` about the principal point: a depth change for a level
camera). Per frame:

1. **Prediction** (eq. 2 / eq. 5): the previous leaf posterior is pushed through the transition
   model -- the leaf transition histograms of the recordings mixed with the first-order Gaussian
   dynamics of eq. 13, whose per-part standard deviations are multiplied by ``m`` for parts that
   were occluded (eq. 14) -- plus a small uniform mass that lets the filter re-acquire. The prior
   of a node is the sum of its leaves' priors (eq. 4).
2. **Update, coarse to fine** (eq. 1, eq. 6): level by level on the image pyramid, every candidate
   node's prototype silhouette is compared with the observation at a few placements around the
   predicted one; the Gaussian likelihood of the best placement times the node prior gives the node
   posterior; children of nodes whose posterior falls below a fraction of the level's best are
   not searched.
3. **Estimate**: the MAP leaf with its placement refined at full resolution, the posterior-mean
   pose over the retained leaves, and the visibility of each part (from the MAP template's part
   labels) that drives eq. 14 in the next frame.

Everything here is a pure function of arrays: ``step(state, db, features, obs) -> (state, estimate)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from protocol.rotations import matrix_to_quat, matrix_to_rotvec, quat_to_matrix, rotvec_to_matrix
from protocol.skeleton import N_JOINTS, N_PARTS, POSE_SIZE

from .features import LevelFeatures
from .silhouette_distance import RunSet, evaluate_templates
from .skin import HAND_PARTS, SkinObservation, skin_cost
from .template_tree import TemplateTree

__all__ = ["Estimate", "FilterDB", "FilterParams", "FilterState", "initial_state", "step"]


@dataclass(frozen=True)
class FilterDB:
    """What the filter needs of a template database (see :mod:`tracker_service.template_db`).

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
        (:func:`tracker_service.placement.template_columns`); empty: no per-template correction
        of the observed shift.
    ref_column : float
        The column :func:`tracker_service.placement.observed_placement` assumes for every template.
    level_bottom : tuple of (n_L,) float64, optional
        Each node's lowest template row at the reference placement, full-resolution pixels
        (:func:`tracker_service.placement.template_bottoms`); empty: every template is taken to
        stand on the floor.
    ref_bottom : float
        The row a standing template's lowest row lies on (the observed feet line's reference).
    leaf_points : (NL, J, 2) float32, optional
        Image position of every joint of each leaf's template at the reference placement
        (:func:`tracker_service.skin.leaf_joint_points`); empty: no skin cue.
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
    ref_bottom: float = float("nan")
    leaf_points: NDArray[np.float32] = field(default_factory=lambda: np.zeros((0, N_JOINTS, 2), np.float32))

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
    grid : tuple of (int, int)
        Placement search grid (shift steps x scale steps) per level, around each node's parent's
        best placement.
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
        Weight of the skin cue (:func:`tracker_service.skin.hand_cost`) added to eq. 6's negative
        log likelihood from level ``skin_from_level`` on; 0 disables it.
    skin_sigma_px, skin_cap_px, skin_hidden_cost : float
        Hand-to-skin distance scale and cap (full-resolution pixels), cost of a hidden hand.
    skin_cover_weight, skin_cover_radius_px : float
        Weight of the reverse term (:func:`tracker_service.skin.cover_cost`: skin no limb of the
        template explains) and the limb half-width it allows (full-resolution pixels).
    skin_cover_from_level : int
        First level where the reverse term is added (it costs ``K x S`` per evaluation).
    skin_min_visible : float
        A template's hand counts as visible above this visible fraction of the hand part.
    skin_max_fraction : float
        The cue is off for frames whose silhouette is more than this fraction skin (a skin-coloured
        shirt).
    """

    sigma: tuple[float, ...] = (0.01, 0.01, 0.01)
    keep_rel: float = 2e-3
    max_keep: tuple[int, ...] = (16, 48)
    keep_likelihood: tuple[int, ...] = (8, 16)
    grid: tuple[tuple[int, int], ...] = ((3, 3), (3, 1), (1, 1))
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


@dataclass(frozen=True)
class Estimate:
    """Result of one filter step.

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


def initial_state(placement: NDArray[np.float64] | None = None, reinits: int = 0) -> FilterState:
    """The state before the first frame (or after a loss): no leaf information."""
    p = np.array([0.0, 0.0, 1.0]) if placement is None else np.asarray(placement, np.float64)
    return FilterState(np.zeros(0, np.int64), np.zeros(0), p, reinits=reinits)


def predict_leaves(state: FilterState, db: FilterDB, params: FilterParams) -> NDArray[np.float64]:
    """Prior over all leaves (eq. 2, 5, 13, 14).

    Returns
    -------
    (NL,) float64, sums to 1.
    """
    nl = db.n_leaves
    allowed = (np.abs(db.leaf_heading) <= params.max_heading if params.max_heading is not None
               else np.ones(nl, bool))
    if not allowed.any():
        allowed[:] = True
    if len(state.leaves) == 0:  # no history: faces the camera first (front/back resolved so)
        prior = (db.leaf_facing & allowed).astype(np.float64)
        if not prior.any():
            prior[:] = 1.0
        return prior / prior.sum()
    prior = np.zeros(nl)
    m2 = np.where(state.occluded, params.occlusion_m**2, 1.0)  # eq. 14
    inv_var = 1.0 / (db.sigma_part.astype(np.float64) ** 2 * m2)  # (N_PARTS,)
    for leaf, w in zip(state.leaves, state.weights, strict=True):
        # eq. 13: Gaussian around the previous pose, over the leaf's pose-space neighbours
        g = np.exp(-0.5 * db.nbr_dpart[leaf].astype(np.float64) @ inv_var)
        g /= g.sum()
        a, b = db.trans_ptr[leaf], db.trans_ptr[leaf + 1]
        hw = params.hist_weight if b > a else 0.0
        prior[db.nbr_idx[leaf]] += w * (1.0 - hw) * g
        if hw:
            prior[db.trans_idx[a:b]] += w * hw * db.trans_p[a:b]
    # re-acquisition mass, restricted to headings near the current one
    cur = db.leaf_heading[state.leaves].astype(np.float64)
    mean_heading = np.arctan2(state.weights @ np.sin(cur), state.weights @ np.cos(cur))
    near = (np.abs(np.angle(np.exp(1j * (db.leaf_heading - mean_heading)))) < params.max_turn) & allowed
    prior *= 1.0 - params.uniform_mass
    prior[near] += params.uniform_mass / max(int(near.sum()), 1)
    prior *= allowed
    if prior.sum() <= 0:
        prior = allowed.astype(np.float64)
    return prior / prior.sum()


def _offsets(step_px: float, step_s: float, nx: int, ns: int) -> NDArray[np.float64]:
    """Placement offsets ``(ddx, 0, ds)`` of a small search grid (``ds`` relative)."""
    kx = np.arange(nx) - (nx - 1) / 2
    ks = np.arange(ns) - (ns - 1) / 2
    dx, ds = np.meshgrid(kx * step_px, ks * step_s, indexing="ij")
    out = np.zeros((dx.size, 3))
    out[:, 0] = dx.ravel()
    out[:, 2] = ds.ravel()
    return out


def _eval_level(db: FilterDB, feats: LevelFeatures, level: int, nodes: NDArray[np.int64],
                centers: NDArray[np.float64], offsets: NDArray[np.float64]
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Distances of every node at every placement ``center + offset``.

    Returns
    -------
    d : (n, G) float64
    places : (n, G, 3) float64
        The full-resolution placements evaluated.
    """
    sc = db.level_scale[level]
    places = centers[:, None, :] + offsets[None, :, :]
    places[..., 2] = centers[:, None, 2] * (1.0 + offsets[None, :, 2])
    tr = places.reshape(-1, 3).copy()
    tr[:, :2] *= sc
    ids = np.repeat(nodes, len(offsets))
    center = ((db.center[0] + 0.5) * sc - 0.5, (db.center[1] + 0.5) * sc - 0.5)  # pixel-centre convention
    d = evaluate_templates(feats, db.level_runs[level], ids, tr, center)
    return d.reshape(len(nodes), len(offsets)), places


def _mean_pose(poses: NDArray[np.float64], w: NDArray[np.float64]) -> NDArray[np.float64]:
    n = len(poses)
    q = matrix_to_quat(rotvec_to_matrix(poses[:, 3:].reshape(n, -1, 3)))  # (n, R, 4)
    q = np.where((np.einsum("nrc,rc->nr", q, q[0]) < 0)[..., None], -q, q)  # same hemisphere
    qm = np.einsum("n,nrc->rc", w, q)
    out = np.empty(POSE_SIZE)
    out[:3] = w @ poses[:, :3]
    out[3:] = matrix_to_rotvec(quat_to_matrix(qm)).reshape(-1)
    return out


def _placement_cost(places: NDArray[np.float64], pred: NDArray[np.float64], params: FilterParams
                    ) -> NDArray[np.float64]:
    """Negative log prior of placements around the predicted ones (Gaussian in shift and scale);
    ``pred`` broadcasts against ``places`` (both ``(..., 3)``)."""
    return 0.5 * (((places[..., 0] - pred[..., 0]) / params.placement_sigma_px) ** 2
                  + ((places[..., 2] / pred[..., 2] - 1.0) / params.placement_sigma_scale) ** 2)


def _node_predictions(db: FilterDB, level: int, nodes: NDArray[np.int64], pred: NDArray[np.float64],
                      obs_weight: float, obs: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """Predicted placement of each node.

    The observed placement assumes every template's lower-body column is the root's and its lowest
    row is on the floor. A template whose column lies elsewhere (a leg or arm to one side) is
    shifted by the difference; one whose feet are off the floor (a leap, a stride, a raised knee)
    has the observed scale multiplied by ``(floor - c_y) / (bottom - c_y)`` so that its own lowest
    row, not the floor row, meets the observed feet line. Both corrections enter in the
    observation's share ``obs_weight`` of the prediction.

    Returns
    -------
    (n, 3) float64
    """
    out = np.repeat(pred[None], len(nodes), axis=0)
    if obs_weight > 0 and obs is not None and db.level_bottom and np.isfinite(db.ref_bottom):
        cy = db.center[1]
        c = (db.ref_bottom - cy) / np.maximum(db.level_bottom[level][nodes] - cy, 1.0)
        c = np.clip(np.nan_to_num(c, nan=1.0), 0.8, 2.0)
        out[:, 2] += obs_weight * obs[2] * (c - 1.0)
        out[:, 1] += obs_weight * obs[1] * (c - 1.0)
    if obs_weight > 0 and db.level_column and np.isfinite(db.ref_column):
        corr = obs_weight * out[:, 2] * (db.ref_column - db.level_column[level][nodes])
        out[:, 0] += np.nan_to_num(corr)
    return out


def _skin_cost(db: FilterDB, level: int, nodes: NDArray[np.int64], places: NDArray[np.float64],
               skin: SkinObservation | None, params: FilterParams) -> NDArray[np.float64] | float:
    """Skin-cue cost (:func:`tracker_service.skin.hand_cost`) of nodes at placements ``(n, G, 3)``;
    a node above the leaves is represented by the leaf holding its prototype template."""
    if (skin is None or params.skin_weight <= 0 or level < params.skin_from_level or not len(db.leaf_points)
            or skin.fraction > params.skin_max_fraction):
        return 0.0
    tree = db.tree
    leaves = nodes if level == tree.n_levels - 1 else tree.template_leaf[tree.node_template[level][nodes]]
    vis = db.leaf_visible[leaves][:, list(HAND_PARTS)] > params.skin_min_visible
    c = skin_cost(skin, db.leaf_points[leaves], vis, places, db.center, params.skin_sigma_px, params.skin_cap_px,
                  params.skin_hidden_cost, params.skin_cover_weight if level >= params.skin_cover_from_level else 0.0,
                  params.skin_cover_radius_px)
    return params.skin_weight * c


def step(state: FilterState, db: FilterDB, features: list[LevelFeatures], params: FilterParams,
         observed_placement: NDArray[np.float64] | None = None, skin: SkinObservation | None = None
         ) -> tuple[FilterState, Estimate]:
    """One frame of tree-based filtering.

    Parameters
    ----------
    state : FilterState
    db : FilterDB
    features : list of LevelFeatures
        The observation, coarse to fine (:func:`tracker_service.features.preprocess`).
    params : FilterParams
    observed_placement : (3,) float, optional
        Placement measured directly from the silhouette (feet line and body centre); blended into
        the prediction, and used alone after (re-)initialisation.
    skin : SkinObservation, optional
        The frame's skin evidence (:func:`tracker_service.skin.observe_skin`): where the hands may be.

    Returns
    -------
    state : FilterState
    estimate : Estimate
    """
    fresh = len(state.leaves) == 0
    pred = state.placement + 0.5 * state.velocity
    w_obs = 0.0
    obs = None
    if observed_placement is not None:
        obs = np.asarray(observed_placement, np.float64)
        w_obs = 1.0 if fresh else params.observation_weight
        pred = w_obs * obs + (1 - w_obs) * pred
    prior = predict_leaves(state, db, params)
    tree = db.tree
    n_levels = tree.n_levels
    nodes = np.arange(tree.level_sizes[0], dtype=np.int64)
    centers = _node_predictions(db, 0, nodes, pred, w_obs, obs)
    evals: list[int] = []
    post = np.zeros(0)
    node_place = centers
    cost = np.zeros(0)
    for lvl in range(n_levels):
        node_prior = np.bincount(db.leaf_anc[lvl], weights=prior, minlength=tree.level_sizes[lvl])[nodes]
        shrink = 0.5**lvl
        grid = params.grid[lvl]
        offs = _offsets(params.step_px * shrink, params.step_scale * shrink, grid[0], grid[1])
        d, places = _eval_level(db, features[lvl], lvl, nodes, centers, offs)
        evals.append(d.size)
        node_pred = _node_predictions(db, lvl, nodes, pred, w_obs, obs)
        total = 0.5 * (d / params.sigma[lvl]) ** 2 + _placement_cost(places, node_pred[:, None], params)  # eq. 6
        total = total + _skin_cost(db, lvl, nodes, places, skin, params)
        best = np.argmin(total, axis=1)
        rows = np.arange(len(nodes))
        cost = total[rows, best]
        node_place = places[rows, best]
        logpost = np.log(np.maximum(node_prior, 1e-300)) - cost  # eq. 1
        post = np.exp(logpost - logpost.max())
        post /= post.sum()
        if lvl < n_levels - 1:
            keep = np.flatnonzero(post >= params.keep_rel * post.max())
            keep = keep[np.argsort(-post[keep])][: params.max_keep[lvl]]
            n_lik = params.keep_likelihood[lvl] if lvl < len(params.keep_likelihood) else 0
            if n_lik:  # data-driven proposal: the best nodes by likelihood alone survive a misleading prior
                keep = np.union1d(keep, np.argsort(cost)[:n_lik])
            kids = [tree.children(lvl, int(nodes[k])) for k in keep]
            parent = np.repeat(keep, [len(c) for c in kids])
            centers = node_place[parent].copy()
            parent_nodes = nodes[parent]
            nodes = np.concatenate(kids)
            if db.level_column:  # a child's template column differs from its parent's
                dcol = db.level_column[lvl][parent_nodes] - db.level_column[lvl + 1][nodes]
                centers[:, 0] += np.nan_to_num(centers[:, 2] * dcol)
    leaves = nodes
    order = np.argsort(-post)
    # refine the placement of the best leaves at full resolution
    top = order[: params.refine]
    offs = _offsets(2.0, 0.01, 3, 3)
    d_ref, places = _eval_level(db, features[-1], n_levels - 1, leaves[top], node_place[top], offs)
    evals[-1] += d_ref.size
    top_pred = _node_predictions(db, n_levels - 1, leaves[top], pred, w_obs, obs)
    total = 0.5 * (d_ref / params.sigma[-1]) ** 2 + _placement_cost(places, top_pred[:, None], params)
    total = total + _skin_cost(db, n_levels - 1, leaves[top], places, skin, params)
    best = np.argmin(total, axis=1)
    rows = np.arange(len(top))
    lp = np.log(np.maximum(post[top], 1e-300)) + cost[top] - total[rows, best]
    k = int(np.argmax(lp))
    map_leaf = int(leaves[top[k]])
    place = places[k, best[k]]
    dist = float(d_ref[k, best[k]])
    sup = order[: params.support]
    w = post[sup] / post[sup].sum()
    sup_leaves = leaves[sup]
    poses = db.leaf_poses[sup_leaves].astype(np.float64)
    vis = db.leaf_visible[map_leaf]
    misses = state.misses + 1 if dist > params.lost_distance else 0
    reinit = misses >= params.lost_frames
    vel = 0.5 * state.velocity + 0.5 * (place - state.placement) if not fresh else np.zeros(3)
    new_state = FilterState(sup_leaves, w, place, vel, vis <= 0.0, misses, state.reinits)
    if reinit:
        new_state = initial_state(place, state.reinits + 1)
    est = Estimate(
        leaf=map_leaf, pose_map=db.leaf_poses[map_leaf].astype(np.float64), pose_mean=_mean_pose(poses, w),
        placement=place, distance=dist,
        confidence=float(np.exp(-0.5 * (dist / params.confidence_scale) ** 2)),
        visibility=vis.astype(np.float32), evaluations=tuple(evals), reinitialised=reinit,
    )
    return new_state, est


def with_occlusion(state: FilterState, occluded: NDArray[np.bool_]) -> FilterState:
    """Override the occlusion flags (for DM1 vs DM2 comparisons: all False disables eq. 14)."""
    return replace(state, occluded=np.asarray(occluded, bool))
