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

Everything here is a pure function of arrays: ``step(state, db, observation, params) -> (state, estimate)``;
:class:`TreeFilter` is the same behind the estimator interface (:mod:`tracker_service.estimators.base`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import lru_cache, partial
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from tracker_service.cues.skin import HAND_PARTS, SkinObservation, skin_cost
from tracker_service.estimators.base import Estimate, Observation, leaf_cue_cost
from tracker_service.estimators.tree_filter._kernels import (
    expand_kernel,
    heading_mass_kernel,
    leaf_prior_kernel,
    level_cost_kernel,
    level_priors_kernel,
    mean_pose_kernel,
    node_predictions_kernel,
)
from tracker_service.estimators.tree_filter.model import FilterDB, FilterParams, FilterState
from tracker_service.estimators.tree_filter.reference import heading_mass_reference
from tracker_service.silhouette.distance import evaluate_template_grid
from tracker_service.silhouette.features import LevelFeatures

__all__ = ["Estimate", "FilterDB", "FilterParams", "FilterState", "initial_state", "mean_pose", "step",
           "support_heading", "tempered"]


def initial_state(placement: NDArray[np.float64] | None = None, reinits: int = 0) -> FilterState:
    """The state before the first frame (or after a loss): no leaf information."""
    p = np.array([0.0, 0.0, 1.0]) if placement is None else np.asarray(placement, np.float64)
    return FilterState(np.zeros(0, np.int64), np.zeros(0), p, reinits=reinits)


def support_heading(state: FilterState, db: FilterDB) -> float:
    """The heading of the filter's support: its leaves' headings' circular mean under their weights
    (radians; ``state.leaves`` must not be empty)."""
    cur = db.leaf_heading[state.leaves].astype(np.float64)
    return float(np.arctan2(state.weights @ np.sin(cur), state.weights @ np.cos(cur)))


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
    m2 = np.where(state.occluded, params.occlusion_m**2, 1.0)  # eq. 14
    inv_var = 1.0 / (db.sigma_part.astype(np.float64) ** 2 * m2)  # (N_PARTS,)
    prior = np.zeros(nl)
    # eq. 13: Gaussian around the previous pose over each leaf's pose-space neighbours, plus eq. 5's
    # transition histograms (numba; reference: reference.motion_prior_reference)
    leaf_prior_kernel(np.ascontiguousarray(state.leaves, np.int64), np.ascontiguousarray(state.weights, np.float64),
                      db.nbr_idx, db.nbr_dpart, inv_var, db.trans_ptr, db.trans_idx, db.trans_p,
                      float(params.hist_weight), prior)
    # re-acquisition mass, restricted to headings near the current one (numba; reference:
    # reference.heading_mass_reference)
    mean_heading = support_heading(state, db)
    if not heading_mass_kernel(prior, np.ascontiguousarray(db.leaf_heading, np.float32), allowed,
                               mean_heading, float(params.max_turn), float(params.uniform_mass)):
        prior = heading_mass_reference(prior, db.leaf_heading, allowed, mean_heading, params.max_turn,
                                       params.uniform_mass)
    if prior.sum() <= 0:
        prior = allowed.astype(np.float64)
    return prior / prior.sum()


@lru_cache(maxsize=64)
def _offsets(step_px: float, step_s: float, nx: int, ns: int) -> NDArray[np.float64]:
    """Placement offsets ``(ddx, 0, ds)`` of a small search grid (``ds`` relative).

    Returns
    -------
    (nx * ns, 3) float64
        Read-only (cached: the same few grids every frame).
    """
    kx = np.arange(nx) - (nx - 1) / 2
    ks = np.arange(ns) - (ns - 1) / 2
    dx, ds = np.meshgrid(kx * step_px, ks * step_s, indexing="ij")
    out = np.zeros((dx.size, 3))
    out[:, 0] = dx.ravel()
    out[:, 2] = ds.ravel()
    out.setflags(write=False)
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
    tr = places.copy()
    tr[..., :2] *= sc
    center = ((db.center[0] + 0.5) * sc - 0.5, (db.center[1] + 0.5) * sc - 0.5)  # pixel-centre convention
    d = evaluate_template_grid(feats, db.level_runs[level], nodes, tr, center)
    return d, places


def _level_cost(db: FilterDB, feats: LevelFeatures, level: int, nodes: NDArray[np.int64],
                centers: NDArray[np.float64], node_pred: NDArray[np.float64], params: FilterParams,
                motion_scale: float, skin: SkinObservation | None, sel: NDArray[np.int64] | slice,
                offsets: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """eq. 6's negative log likelihood plus the placement prior (and the skin cue) of the nodes
    ``nodes[sel]`` at every placement ``center + offset``.

    Parameters
    ----------
    centers : (n, 3) or (n, H, 3) float
        Each node's predicted placement, one per placement hypothesis (grids side by side).
    node_pred : (n, H, 3) float
        The hypotheses' predictions for the placement prior (:func:`_node_predictions`).

    Returns
    -------
    cost : (m, H*G) float64
    places : (m, H*G, 3) float64
    evaluations : int
    """
    sub, cen = nodes[sel], centers[sel]
    if cen.ndim == 3:  # several placement hypotheses per node: their grids side by side
        n_h = cen.shape[1]
        d, pl = _eval_level(db, feats, level, np.repeat(sub, n_h), cen.reshape(-1, 3), offsets)
        d, pl = d.reshape(len(sub), -1), pl.reshape(len(sub), -1, 3)
    else:
        d, pl = _eval_level(db, feats, level, sub, cen, offsets)
    t = _cost(d, pl, node_pred[sel], params.sigma[level], params, motion_scale)
    return t + _skin_cost(db, level, sub, pl, skin, params), pl, d.size


def _k_smallest(x: NDArray[np.float64], k: int) -> NDArray[np.int64]:
    """Indices of the ``k`` smallest entries of ``x`` in no particular order (a partition, not a
    sort: the callers take their union with another set).

    Parameters
    ----------
    x : (n,) float64
    k : int

    Returns
    -------
    (min(k, n),) int64
    """
    if k <= 0:
        return np.zeros(0, np.int64)
    if k >= len(x):
        return np.arange(len(x), dtype=np.int64)
    return np.asarray(np.argpartition(x, k - 1)[:k], np.int64)


def _screened(neg_log: Callable[[NDArray[np.int64] | slice, NDArray[np.float64]],
                                 tuple[NDArray[np.float64], NDArray[np.float64], int]],
              offs: NDArray[np.float64], node_prior: NDArray[Any], n_best: int
              ) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """A level's placement grid in two passes (``FilterParams.screen``), and each node's best cell.

    Every node is evaluated at the grid's centre cell (its predicted placement); the ``n_best``
    nodes by posterior and the ``n_best`` by likelihood are then evaluated on the whole grid. A
    node's best cell is the cheapest it was evaluated at (the first of equal ones in the order
    hypothesis, then grid cell): what the arg-min over a full ``(n, H*G)`` table with infinite cost
    in the cells not evaluated gives, without building that table.

    Parameters
    ----------
    neg_log : callable
        ``neg_log(sel, offsets) -> (cost (n, H*G), places (n, H*G, 3), evaluations)`` for nodes ``sel``.
    offs : (G, 3) float
        The grid (odd sizes: its middle cell is the zero offset).
    node_prior : (n,) float
    n_best : int

    Returns
    -------
    cost : (n,) float64
        Each node's cost at its best cell.
    place : (n, 3) float64
        That cell's full-resolution placement.
    evaluations : int
    """
    g = len(offs)
    c = g // 2
    t0, p0, n0 = neg_log(slice(None), offs[c: c + 1])  # (n, H), (n, H, 3)
    n = len(t0)
    lik = t0.min(axis=1)
    lp = np.log(np.maximum(node_prior, 1e-300)) - lik
    sel = np.union1d(_k_smallest(-lp, n_best), _k_smallest(lik, n_best))
    t_sel, p_sel, n1 = neg_log(sel, offs)
    rows = np.arange(n)
    h0 = np.argmin(t0, axis=1)
    cost, place = t0[rows, h0], p0[rows, h0]
    r_sel = np.arange(len(sel))
    b_sel = np.argmin(t_sel, axis=1)
    cost[sel] = t_sel[r_sel, b_sel]
    place[sel] = p_sel[r_sel, b_sel]
    return cost, place, n0 + n1


def mean_pose(poses: NDArray[np.float64], w: NDArray[np.float64]) -> NDArray[np.float64]:
    """Weighted mean of poses ``(n, P)``: root averaged, rotations as the normalised weighted sum
    of quaternions on one hemisphere (numba; reference: reference.mean_pose_reference).

    Returns
    -------
    (P,) float64
    """
    return mean_pose_kernel(np.ascontiguousarray(poses, np.float64), np.ascontiguousarray(w, np.float64))


def tempered(w: NDArray[np.float64], temperature: float) -> NDArray[np.float64]:
    """Weights ``w ** (1 / T)`` renormalised (``T`` = 1: ``w`` itself)."""
    if temperature == 1.0:
        return w
    t = np.power(np.maximum(w, 1e-300), 1.0 / temperature)
    return t / t.sum()


def _cost(d: NDArray[np.float64], places: NDArray[np.float64], hyps: NDArray[np.float64], sigma: float,
          params: FilterParams, motion_scale: float) -> NDArray[np.float64]:
    """eq. 6's negative log likelihood of distances ``d`` ``(n, G)`` plus the placement prior of
    ``places`` ``(n, G, 3)``: a Gaussian in shift and scale around the cheaper of each node's
    hypotheses ``(n, H, 3)``, the height hypothesis's scale held to the motion prediction's
    ``motion_scale`` (a body off the floor has not changed depth; a wrong pose cannot buy the
    silhouette's height by a jump in depth) at ``airborne_cost`` more (numba; reference:
    reference.level_cost_reference).

    Returns
    -------
    (n, G) float64
    """
    return level_cost_kernel(np.ascontiguousarray(d, np.float64), np.ascontiguousarray(places, np.float64),
                             np.ascontiguousarray(hyps, np.float64), float(sigma), float(params.placement_sigma_px),
                             float(params.placement_sigma_scale), float(motion_scale), float(params.airborne_cost))


def _node_predictions(db: FilterDB, level: int, nodes: NDArray[np.int64], pred: NDArray[np.float64],
                      obs_weight: float, obs: NDArray[np.float64] | None = None,
                      rows: NDArray[np.float64] | None = None, scale_range: tuple[float, float] = (0.0, np.inf)
                      ) -> NDArray[np.float64]:
    """Predicted placements of each node: one per placement hypothesis.

    Hypothesis 0, **feet on the floor**: the observed placement assumes every template's lower-body
    column is the root's and its lowest row is on the floor. A template whose column lies elsewhere
    (a leg or arm to one side) is shifted by the difference; one whose feet are off the floor (a
    stride, a raised knee) has the observed scale multiplied by ``(floor - c_y) / (bottom - c_y)``
    so that its own lowest row, not the floor row, meets the observed feet line. Both corrections
    enter in the observation's share ``obs_weight`` of the prediction.

    Hypothesis 1, **the silhouette's height** (with ``rows``): the whole body may be off the floor
    (a leap, the flight phase of a run), where the feet line reads as a person moving away (a
    40 cm leap looked 2 m further away). The height of the silhouette does not change in a leap:
    the scale is the observed height over the template's, and the template is shifted vertically
    so that its lowest row meets the observed one. The silhouette decides between the two
    (:func:`step` evaluates both; the placement prior is their mixture).

    Computed by :func:`tracker_service.estimators.tree_filter._kernels.node_predictions_kernel` (reference:
    :func:`tracker_service.estimators.tree_filter.reference.node_predictions_reference`).

    Parameters
    ----------
    rows : (2,) float, optional
        The observed silhouette's top and bottom rows (full resolution).
    scale_range : (float, float)
        Bounds of the height hypothesis's scale (around the motion prediction's: a leap does not
        change the depth, and a pose the database lacks must not buy the silhouette's height with
        a jump in depth).

    Returns
    -------
    (n, H, 3) float64
        ``H`` = 1, or 2 with ``rows``.
    """
    has_rows = bool(db.level_bottom) and bool(np.isfinite(db.ref_bottom))
    use_obs = obs_weight > 0 and obs is not None and has_rows
    use_height = rows is not None and has_rows and bool(db.level_top)
    use_column = obs_weight > 0 and bool(db.level_column) and bool(np.isfinite(db.ref_column))
    none = np.zeros(0)
    return node_predictions_kernel(
        np.ascontiguousarray(nodes, np.int64), np.ascontiguousarray(pred, np.float64),
        none if obs is None else np.ascontiguousarray(obs, np.float64), float(obs_weight), use_obs,
        db.level_bottom[level] if has_rows else none, db.level_top[level] if use_height else none, use_height,
        none if rows is None else np.ascontiguousarray(rows, np.float64), float(scale_range[0]),
        float(scale_range[1]), db.level_column[level] if use_column else none, use_column, float(db.ref_column),
        float(db.ref_bottom), float(db.center[1]))


def _skin_cost(db: FilterDB, level: int, nodes: NDArray[np.int64], places: NDArray[np.float64],
               skin: SkinObservation | None, params: FilterParams) -> NDArray[np.float64] | float:
    """Skin-cue cost (:func:`tracker_service.cues.skin.hand_cost`) of nodes at placements ``(n, G, 3)``;
    a node above the leaves is represented by the leaf holding its prototype template."""
    if (skin is None or params.skin_weight <= 0 or level < params.skin_from_level or not len(db.leaf_points)
            or skin.fraction > params.skin_max_fraction):
        return 0.0
    tree = db.tree
    leaves = nodes if level == tree.n_levels - 1 else tree.template_leaf[tree.node_template[level][nodes]]
    c = skin_cost(skin, db.leaf_points, db.leaf_visible, leaves, places, db.center, params.skin_sigma_px,
                  params.skin_cap_px, params.skin_hidden_cost,
                  params.skin_cover_weight if level >= params.skin_cover_from_level else 0.0,
                  params.skin_cover_radius_px, params.skin_min_visible, HAND_PARTS)
    return params.skin_weight * c


def step(state: FilterState, db: FilterDB, observation: Observation, params: FilterParams
         ) -> tuple[FilterState, Estimate]:
    """One frame of tree-based filtering (eq. 1-6 over the levels of Algorithm 1's tree).

    Parameters
    ----------
    state : FilterState
    db : FilterDB
    observation : Observation
        The frame as every estimator sees it (:class:`tracker_service.estimators.base.Observation`):
        the features, coarse to fine; the placement measured from the silhouette (blended into the
        prediction, used alone after a (re-)initialisation); the silhouette's rows (a second
        placement hypothesis per node from its height: a body off the floor); the skin evidence
        (where the hands may be); the cues' leaf costs, added to the leaf level's negative log
        likelihood (:func:`tracker_service.estimators.base.leaf_cue_cost`); and the proposed leaves,
        evaluated at the leaf level beside the tree's own candidates, each on the refinement grid
        (±2 px, ±1 %) around its predicted placement, with its prior from the motion model like every
        other leaf.
    params : FilterParams

    Returns
    -------
    state : FilterState
    estimate : Estimate
    """
    features, skin = observation.features, observation.skin
    pr = _prediction(state, observation, params)
    predict_nodes = partial(_node_predictions, db, pred=pr.pred, obs_weight=pr.w_obs, obs=pr.obs, rows=pr.sil_rows,
                            scale_range=pr.s_range)
    prior = predict_leaves(state, db, params)
    tree = db.tree
    bounds = np.concatenate([[0], np.cumsum(tree.level_sizes)]).astype(np.int64)
    all_priors = np.zeros(int(bounds[-1]))
    level_priors_kernel(db.leaf_anc, prior, bounds, all_priors)  # eq. 4 (reference: np.bincount)
    sr = _search(db, features, params, skin, pr.motion_scale, predict_nodes, all_priors, bounds)
    if observation.proposals is not None and len(observation.proposals):
        sr = _with_proposals(sr, np.asarray(observation.proposals, np.int64), db, features, params, skin,
                             pr.motion_scale, predict_nodes, all_priors[bounds[-2]: bounds[-1]])
    return _estimate(state, sr, observation, db, features, params, pr, predict_nodes)


class _Prediction(NamedTuple):
    """Where the subject is expected this frame (the placement part of eq. 2)."""

    pred: NDArray[np.float64]  # (3,) predicted placement, blended with the observed one
    w_obs: float  # the observed placement's weight in that blend
    obs: NDArray[np.float64] | None  # the observed placement
    sil_rows: NDArray[np.float64] | None  # the silhouette's rows when the feet line rose (height hypothesis)
    s_range: tuple[float, float]  # scales the height hypothesis may take
    motion_scale: float  # the predicted scale before the blend
    fresh: bool  # no posterior yet (initialisation)


def _prediction(state: FilterState, observation: Observation, params: FilterParams) -> _Prediction:
    """The predicted placement: constant velocity, blended with the placement observed from the feet
    line (alone after a (re-)initialisation); the height hypothesis when the feet line rose."""
    observed_placement, observed_rows = observation.placement, observation.rows
    fresh = len(state.leaves) == 0
    pred = state.placement + 0.5 * state.velocity
    if observation.min_scale is not None:  # the feet cut off by the border: at least this near
        pred[2] = max(pred[2], observation.min_scale)
    sil_rows = None
    motion_scale = float(pred[2])
    cur_rows = None if observed_rows is None else np.asarray(observed_rows, np.float64)
    if (cur_rows is not None and params.height_hypothesis and observed_placement is not None and not fresh
            and float(observed_placement[2]) < motion_scale * (1.0 - params.airborne_gate)):
        sil_rows = cur_rows  # the feet line rose: a step back, or the feet left the floor
    s_range = (motion_scale * (1.0 - params.airborne_scale_range), motion_scale * (1.0 + params.airborne_scale_range))
    w_obs = 0.0
    obs = None
    if observed_placement is not None:
        obs = np.asarray(observed_placement, np.float64)
        w_obs = 1.0 if fresh else params.observation_weight
        pred = w_obs * obs + (1 - w_obs) * pred
    return _Prediction(pred, w_obs, obs, sil_rows, s_range, motion_scale, fresh)


class _Search(NamedTuple):
    """The leaf level reached by the coarse-to-fine search."""

    nodes: NDArray[np.int64]  # (n,) leaves
    node_place: NDArray[np.float64]  # (n, 3) each one's best placement
    cost: NDArray[np.float64]  # (n,) its negative log likelihood there
    logpost: NDArray[np.float64]  # (n,) log posterior (eq. 1), unnormalised
    post: NDArray[np.float64]  # (n,) posterior (sum 1)
    evals: list[int]  # distance evaluations per level


def _search(db: FilterDB, features: list[LevelFeatures], params: FilterParams, skin: SkinObservation | None,
            motion_scale: float, predict_nodes: Callable[..., NDArray[np.float64]],
            all_priors: NDArray[np.float64], bounds: NDArray[np.int64]) -> _Search:
    """Eq. 1 and 6 level by level, coarse to fine: every candidate node on its placement grid, the
    nodes whose posterior falls below a fraction of the level's best not expanded."""
    tree = db.tree
    n_levels = tree.n_levels
    nodes = np.arange(tree.level_sizes[0], dtype=np.int64)
    centers = predict_nodes(0, nodes)  # (n, H, 3) at level 0
    evals: list[int] = []
    post = logpost = cost = np.zeros(0)
    node_place = centers
    for lvl in range(n_levels):
        node_prior = all_priors[bounds[lvl]: bounds[lvl + 1]][nodes]
        shrink = 0.5**lvl
        grid = params.grid[lvl]
        offs = _offsets(params.step_px * shrink, params.step_scale * shrink, grid[0], grid[1])
        node_pred = centers if lvl == 0 else predict_nodes(lvl, nodes)

        neg_log = partial(_level_cost, db, features[lvl], lvl, nodes, centers, node_pred, params, motion_scale, skin)
        n_screen = params.screen[lvl] if lvl < len(params.screen) else 0
        if n_screen > 0 and len(offs) > 1 and len(nodes) > 2 * n_screen:
            cost, node_place, n_eval = _screened(neg_log, offs, node_prior, n_screen)
        else:
            total, places, n_eval = neg_log(slice(None), offs)
            best = np.argmin(total, axis=1)
            rows = np.arange(len(nodes))
            cost = total[rows, best]
            node_place = places[rows, best]
        evals.append(n_eval)
        logpost = np.log(np.maximum(node_prior, 1e-300)) - cost  # eq. 1
        post = np.exp(logpost - logpost.max())
        post /= post.sum()
        if lvl < n_levels - 1:
            keep = np.flatnonzero(post >= params.keep_rel * post.max())
            keep = keep[np.argsort(-post[keep])][: params.max_keep[lvl]]
            n_lik = params.keep_likelihood[lvl] if lvl < len(params.keep_likelihood) else 0
            if n_lik:  # data-driven proposal: the best nodes by likelihood alone survive a misleading prior
                keep = np.union1d(keep, _k_smallest(cost, n_lik))
            # the kept nodes' children start from their parent's best placement, corrected for the
            # difference of their template columns (numba; reference: reference.expand_reference)
            cols = db.level_column
            nodes, centers = expand_kernel(tree.child_ptr[lvl], nodes, np.ascontiguousarray(keep, np.int64),
                                           np.ascontiguousarray(node_place, np.float64),
                                           cols[lvl] if cols else np.zeros(0), cols[lvl + 1] if cols else np.zeros(0),
                                           bool(cols))
    return _Search(nodes, node_place, cost, logpost, post, evals)


def _with_proposals(sr: _Search, proposals: NDArray[np.int64], db: FilterDB, features: list[LevelFeatures],
                    params: FilterParams, skin: SkinObservation | None, motion_scale: float,
                    predict_nodes: Callable[..., NDArray[np.float64]], leaf_priors: NDArray[np.float64]) -> _Search:
    """The proposed leaves the search did not reach, each on a small grid around its own predictions,
    with its prior from the motion model, added to the leaf level."""
    extra = np.setdiff1d(proposals, sr.nodes)
    if not len(extra):
        return sr
    last = db.tree.n_levels - 1
    ex_pred = predict_nodes(last, extra)
    t_ex, p_ex, n_ex = _level_cost(db, features[last], last, extra, ex_pred, ex_pred, params,
                                   motion_scale, skin, slice(None), _offsets(2.0, 0.01, 3, 3))
    evals = [*sr.evals[:-1], sr.evals[-1] + n_ex]
    b_ex = np.argmin(t_ex, axis=1)
    r_ex = np.arange(len(extra))
    c_ex = t_ex[r_ex, b_ex]
    logpost = np.concatenate([sr.logpost, np.log(np.maximum(leaf_priors[extra], 1e-300)) - c_ex])
    post = np.exp(logpost - logpost.max())
    post /= post.sum()
    return _Search(np.concatenate([sr.nodes, extra]), np.concatenate([sr.node_place, p_ex[r_ex, b_ex]]),
                   np.concatenate([sr.cost, c_ex]), logpost, post, evals)


def _estimate(state: FilterState, sr: _Search, observation: Observation, db: FilterDB,
              features: list[LevelFeatures], params: FilterParams, pr: _Prediction,
              predict_nodes: Callable[..., NDArray[np.float64]]) -> tuple[FilterState, Estimate]:
    """The cues' leaf costs added, the best leaves' placement refined at full resolution, the MAP
    leaf, the tempered posterior mean of the support and the next state."""
    leaves, node_place, cost, post, evals = sr.nodes, sr.node_place, sr.cost, sr.post, list(sr.evals)
    n_levels = db.tree.n_levels
    leaf_c = leaf_cue_cost(observation.leaf_costs, leaves, node_place)
    if leaf_c is not None:
        cost = cost + leaf_c
        logpost = np.log(np.maximum(post, 1e-300)) - leaf_c
        post = np.exp(logpost - logpost.max())
        post /= post.sum()
    order = np.argsort(-post)
    # refine the placement of the best leaves at full resolution
    top = order[: params.refine]
    offs = _offsets(2.0, 0.01, 3, 3)
    d_ref, places = _eval_level(db, features[-1], n_levels - 1, leaves[top], node_place[top], offs)
    evals[-1] += d_ref.size
    top_pred = predict_nodes(n_levels - 1, leaves[top])
    total = _cost(d_ref, places, top_pred, params.sigma[-1], params, pr.motion_scale)
    total = total + _skin_cost(db, n_levels - 1, leaves[top], places, observation.skin, params)
    if leaf_c is not None:
        total = total + leaf_c[top, None]
    best = np.argmin(total, axis=1)
    rows = np.arange(len(top))
    lp = np.log(np.maximum(post[top], 1e-300)) + cost[top] - total[rows, best]
    k = int(np.argmax(lp))
    map_leaf = int(leaves[top[k]])
    place = places[k, best[k]]
    if observation.min_scale is not None and place[2] < observation.min_scale:
        place = place.copy()
        place[2] = observation.min_scale
    dist = float(d_ref[k, best[k]])
    sup = order[: params.support]
    w = post[sup] / post[sup].sum()
    sup_leaves = leaves[sup]
    poses = db.leaf_poses[sup_leaves].astype(np.float64)
    vis = db.leaf_visible[map_leaf]
    misses = state.misses + 1 if dist > params.lost_distance else 0
    reinit = misses >= params.lost_frames
    vel = 0.5 * state.velocity + 0.5 * (place - state.placement) if not pr.fresh else np.zeros(3)
    new_state = FilterState(sup_leaves, w, place, vel, vis <= 0.0, misses, state.reinits)
    if reinit:
        new_state = initial_state(place, state.reinits + 1)
    est = Estimate(
        leaf=map_leaf, pose_map=db.leaf_poses[map_leaf].astype(np.float64),
        pose_mean=mean_pose(poses, tempered(w, params.mean_temperature)),
        placement=place, distance=dist,
        confidence=float(np.exp(-0.5 * (dist / params.confidence_scale) ** 2)),
        visibility=vis.astype(np.float32), evaluations=tuple(evals), reinitialised=reinit,
        support_places=node_place[sup], support_cost=cost[sup], support_leaves=np.asarray(sup_leaves, np.int64),
        support_weights=w,
    )
    return new_state, est


def with_occlusion(state: FilterState, occluded: NDArray[np.bool_]) -> FilterState:
    """Override the occlusion flags (for DM1 vs DM2 comparisons: all False disables eq. 14)."""
    return replace(state, occluded=np.asarray(occluded, bool))


@dataclass(frozen=True)
class TreeFilter:
    """The Okada-Stenger tree-based filter behind the estimator interface
    (:class:`tracker_service.estimators.base.Estimator`).

    Attributes
    ----------
    db : FilterDB
        The template tree and its leaves.
    params : FilterParams
    """

    db: FilterDB
    params: FilterParams = field(default_factory=FilterParams)
    name: str = "tree"

    def init(self, placement: NDArray[np.float64] | None = None) -> FilterState:
        """No pose information (:func:`initial_state`)."""
        return initial_state(placement)

    def step(self, state: FilterState, observation: Observation) -> tuple[FilterState, Estimate]:
        """One frame (:func:`step`)."""
        return step(state, self.db, observation, self.params)

    def heading(self, state: FilterState) -> float | None:
        """The support's heading (:func:`support_heading`); None with no support."""
        return support_heading(state, self.db) if len(state.leaves) else None
