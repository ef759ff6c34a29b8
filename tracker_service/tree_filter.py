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

from collections.abc import Callable
from dataclasses import replace
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

from protocol.rotations import matrix_to_quat, matrix_to_rotvec, quat_to_matrix, rotvec_to_matrix
from protocol.skeleton import POSE_SIZE

from ._kernels import leaf_prior_kernel
from .features import LevelFeatures
from .filter_model import Estimate, FilterDB, FilterParams, FilterState
from .silhouette_distance import evaluate_template_grid
from .skin import HAND_PARTS, SkinObservation, skin_cost

__all__ = ["Estimate", "FilterDB", "FilterParams", "FilterState", "initial_state", "step"]


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
    m2 = np.where(state.occluded, params.occlusion_m**2, 1.0)  # eq. 14
    inv_var = 1.0 / (db.sigma_part.astype(np.float64) ** 2 * m2)  # (N_PARTS,)
    prior = np.zeros(nl)
    # eq. 13: Gaussian around the previous pose over each leaf's pose-space neighbours, plus eq. 5's
    # transition histograms (numba; reference: _motion_prior_reference)
    leaf_prior_kernel(np.ascontiguousarray(state.leaves, np.int64), np.ascontiguousarray(state.weights, np.float64),
                      db.nbr_idx, db.nbr_dpart, inv_var, db.trans_ptr, db.trans_idx, db.trans_p,
                      float(params.hist_weight), prior)
    # re-acquisition mass, restricted to headings near the current one
    cur = db.leaf_heading[state.leaves].astype(np.float64)
    mean_heading = np.arctan2(state.weights @ np.sin(cur), state.weights @ np.cos(cur))
    turn = np.abs(np.remainder(db.leaf_heading - mean_heading + np.pi, 2.0 * np.pi) - np.pi)
    near = (turn < params.max_turn) & allowed
    prior *= 1.0 - params.uniform_mass
    prior[near] += params.uniform_mass / max(int(near.sum()), 1)
    prior *= allowed
    if prior.sum() <= 0:
        prior = allowed.astype(np.float64)
    return prior / prior.sum()


def _motion_prior_reference(leaves: NDArray[np.int64], weights: NDArray[np.float64], db: FilterDB,
                            inv_var: NDArray[np.float64], hist_weight: float) -> NDArray[np.float64]:
    """Plain-numpy reference of :func:`tracker_service._kernels.leaf_prior_kernel` (unnormalised
    eq. 13 + eq. 5 mass of the supported leaves; a test holds the two equal)."""
    prior = np.zeros(db.n_leaves)
    for leaf, w in zip(leaves, weights, strict=True):
        g = np.exp(-0.5 * db.nbr_dpart[leaf].astype(np.float64) @ inv_var)
        g /= g.sum()
        a, b = db.trans_ptr[leaf], db.trans_ptr[leaf + 1]
        hw = hist_weight if b > a else 0.0
        prior[db.nbr_idx[leaf]] += w * (1.0 - hw) * g
        if hw:
            prior[db.trans_idx[a:b]] += w * hw * db.trans_p[a:b]
    return prior


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
    t = 0.5 * (d / params.sigma[level]) ** 2 + _mixture_cost(pl, node_pred[sel], params, motion_scale)
    return t + _skin_cost(db, level, sub, pl, skin, params), pl, d.size


def _screened(neg_log: Callable[[NDArray[np.int64] | slice, NDArray[np.float64]],
                                 tuple[NDArray[np.float64], NDArray[np.float64], int]],
              offs: NDArray[np.float64], node_prior: NDArray[Any], n_best: int
              ) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
    """A level's placement grid in two passes (``FilterParams.screen``).

    Every node is evaluated at the grid's centre cell (its predicted placement); the ``n_best``
    nodes by posterior and the ``n_best`` by likelihood are then evaluated on the whole grid. Cells
    not evaluated get an infinite cost.

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
    cost : (n, H*G) float64
    places : (n, H*G, 3) float64
    evaluations : int
    """
    g = len(offs)
    c = g // 2
    t0, p0, n0 = neg_log(slice(None), offs[c: c + 1])  # (n, H), (n, H, 3)
    n, n_h = t0.shape
    lik = t0.min(axis=1)
    lp = np.log(np.maximum(node_prior, 1e-300)) - lik
    sel = np.union1d(np.argsort(-lp)[:n_best], np.argsort(lik)[:n_best])
    t_sel, p_sel, n1 = neg_log(sel, offs)
    cost = np.full((n, n_h, g), np.inf)
    places = np.repeat(p0[:, :, None, :], g, axis=2)
    cost[:, :, c] = t0
    cost[sel] = t_sel.reshape(len(sel), n_h, g)
    places[sel] = p_sel.reshape(len(sel), n_h, g, 3)
    return cost.reshape(n, -1), places.reshape(n, -1, 3), n0 + n1


def _mean_pose(poses: NDArray[np.float64], w: NDArray[np.float64]) -> NDArray[np.float64]:
    n = len(poses)
    q = matrix_to_quat(rotvec_to_matrix(poses[:, 3:].reshape(n, -1, 3)))  # (n, R, 4)
    q = np.where((np.einsum("nrc,rc->nr", q, q[0]) < 0)[..., None], -q, q)  # same hemisphere
    qm = np.einsum("n,nrc->rc", w, q)
    out = np.empty(POSE_SIZE)
    out[:3] = w @ poses[:, :3]
    out[3:] = matrix_to_rotvec(quat_to_matrix(qm)).reshape(-1)
    return out


def _tempered(w: NDArray[np.float64], temperature: float) -> NDArray[np.float64]:
    """Weights ``w ** (1 / T)`` renormalised (``T`` = 1: ``w`` itself)."""
    if temperature == 1.0:
        return w
    t = np.power(np.maximum(w, 1e-300), 1.0 / temperature)
    return t / t.sum()


def _finite(x: NDArray[np.float64], fill: float = 0.0) -> NDArray[np.float64]:
    """``x`` with NaN (a template without rows or columns at a level) replaced by ``fill``; a
    cheaper ``np.nan_to_num`` for the per-level arrays of the search."""
    return np.where(np.isnan(x), fill, x)


def _placement_cost(places: NDArray[np.float64], pred: NDArray[np.float64], params: FilterParams
                    ) -> NDArray[np.float64]:
    """Negative log prior of placements around the predicted ones (Gaussian in shift and scale);
    ``pred`` broadcasts against ``places`` (both ``(..., 3)``)."""
    return 0.5 * (((places[..., 0] - pred[..., 0]) / params.placement_sigma_px) ** 2
                  + ((places[..., 2] / pred[..., 2] - 1.0) / params.placement_sigma_scale) ** 2)


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
    out = np.repeat(pred[None], len(nodes), axis=0)
    has_rows = bool(db.level_bottom) and np.isfinite(db.ref_bottom)
    cy = db.center[1]
    bottom = db.level_bottom[level][nodes] if has_rows else None
    if obs_weight > 0 and obs is not None and bottom is not None:
        c = (db.ref_bottom - cy) / np.maximum(bottom - cy, 1.0)
        c = np.clip(_finite(c, 1.0), 0.8, 2.0)
        out[:, 2] += obs_weight * obs[2] * (c - 1.0)
        out[:, 1] += obs_weight * obs[1] * (c - 1.0)
    hyps = [out]
    if rows is not None and bottom is not None and db.level_top:
        height = bottom - db.level_top[level][nodes]
        ok = np.isfinite(height) & (height > 4.0)
        alt = out.copy()
        s_h = np.where(ok, (rows[1] - rows[0]) / np.where(ok, height, 1.0), out[:, 2])
        alt[:, 2] = np.clip(s_h, *scale_range)
        alt[:, 1] = np.where(ok, rows[1] - cy - alt[:, 2] * (_finite(bottom) - cy), out[:, 1])
        hyps.append(alt)
    res = np.stack(hyps, axis=1)
    if obs_weight > 0 and db.level_column and np.isfinite(db.ref_column):
        corr = obs_weight * res[..., 2] * (db.ref_column - db.level_column[level][nodes])[:, None]
        res[..., 0] += _finite(corr)
    return res


def _mixture_cost(places: NDArray[np.float64], hyps: NDArray[np.float64], params: FilterParams,
                  motion_scale: float | None = None) -> NDArray[np.float64]:
    """Placement prior of ``places`` ``(n, G, 3)`` under the mixture of the nodes' hypotheses
    ``(n, H, 3)`` (the cheapest hypothesis for each placement). The height hypothesis's scale is
    held to the motion prediction's ``motion_scale`` (a body off the floor has not changed depth;
    a wrong pose cannot buy the silhouette's height by a jump in depth)."""
    costs = [_placement_cost(places, hyps[:, 0, None], params)]
    if hyps.shape[1] > 1:
        ref = hyps[:, 1].copy()
        if motion_scale is not None:
            ref[:, 2] = motion_scale
        costs.append(_placement_cost(places, ref[:, None], params) + params.airborne_cost)
    return np.min(costs, axis=0)


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
         observed_placement: NDArray[np.float64] | None = None, skin: SkinObservation | None = None,
         observed_rows: NDArray[np.float64] | None = None) -> tuple[FilterState, Estimate]:
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
    observed_rows : (2,) float, optional
        Top and bottom rows of the silhouette (:func:`tracker_service.placement.silhouette_rows`):
        a second placement hypothesis per node from the silhouette's height (a body off the floor).

    Returns
    -------
    state : FilterState
    estimate : Estimate
    """
    fresh = len(state.leaves) == 0
    pred = state.placement + 0.5 * state.velocity
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
    prior = predict_leaves(state, db, params)
    tree = db.tree
    n_levels = tree.n_levels
    nodes = np.arange(tree.level_sizes[0], dtype=np.int64)
    centers = _node_predictions(db, 0, nodes, pred, w_obs, obs, sil_rows, s_range)  # (n, H, 3) at level 0
    evals: list[int] = []
    post = np.zeros(0)
    node_place = centers
    cost = np.zeros(0)
    for lvl in range(n_levels):
        node_prior = np.bincount(db.leaf_anc[lvl], weights=prior, minlength=tree.level_sizes[lvl])[nodes]
        shrink = 0.5**lvl
        grid = params.grid[lvl]
        offs = _offsets(params.step_px * shrink, params.step_scale * shrink, grid[0], grid[1])
        node_pred = centers if lvl == 0 else _node_predictions(db, lvl, nodes, pred, w_obs, obs, sil_rows, s_range)

        neg_log = partial(_level_cost, db, features[lvl], lvl, nodes, centers, node_pred, params, motion_scale, skin)
        n_screen = params.screen[lvl] if lvl < len(params.screen) else 0
        if n_screen > 0 and len(offs) > 1 and len(nodes) > 2 * n_screen:
            total, places, n_eval = _screened(neg_log, offs, node_prior, n_screen)
        else:
            total, places, n_eval = neg_log(slice(None), offs)
        evals.append(n_eval)
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
                centers[:, 0] += _finite(centers[:, 2] * dcol)
    leaves = nodes
    order = np.argsort(-post)
    # refine the placement of the best leaves at full resolution
    top = order[: params.refine]
    offs = _offsets(2.0, 0.01, 3, 3)
    d_ref, places = _eval_level(db, features[-1], n_levels - 1, leaves[top], node_place[top], offs)
    evals[-1] += d_ref.size
    top_pred = _node_predictions(db, n_levels - 1, leaves[top], pred, w_obs, obs, sil_rows, s_range)
    total = 0.5 * (d_ref / params.sigma[-1]) ** 2 + _mixture_cost(places, top_pred, params, motion_scale)
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
        leaf=map_leaf, pose_map=db.leaf_poses[map_leaf].astype(np.float64),
        pose_mean=_mean_pose(poses, _tempered(w, params.mean_temperature)),
        placement=place, distance=dist,
        confidence=float(np.exp(-0.5 * (dist / params.confidence_scale) ** 2)),
        visibility=vis.astype(np.float32), evaluations=tuple(evals), reinitialised=reinit,
    )
    return new_state, est


def with_occlusion(state: FilterState, occluded: NDArray[np.bool_]) -> FilterState:
    """Override the occlusion flags (for DM1 vs DM2 comparisons: all False disables eq. 14)."""
    return replace(state, occluded=np.asarray(occluded, bool))
