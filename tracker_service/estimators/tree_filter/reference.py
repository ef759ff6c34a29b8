"""Plain-numpy references of the tree filter's kernels (:mod:`tracker_service.estimators.tree_filter._kernels`,
and :func:`tracker_service.estimators.tree_filter._kernels.leaf_prior_kernel`).

These are the filter's per-frame bookkeeping as it was written in numpy before it moved into numba;
the tests hold each kernel equal to its reference (bit for bit; the mean pose to 1e-12). The
filter itself (:mod:`tracker_service.estimators.tree_filter.filter`) calls the kernels.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from protocol.rotations import matrix_to_quat, matrix_to_rotvec, quat_to_matrix, rotvec_to_matrix
from protocol.skeleton import POSE_SIZE
from tracker_service.estimators.tree_filter.model import FilterDB, FilterParams

__all__ = [
    "expand_reference",
    "finite",
    "heading_mass_reference",
    "level_cost_reference",
    "level_priors_reference",
    "mean_pose_reference",
    "mixture_cost_reference",
    "motion_prior_reference",
    "node_predictions_reference",
    "placement_cost_reference",
]


def finite(x: NDArray[np.float64], fill: float = 0.0) -> NDArray[np.float64]:
    """``x`` with NaN (a template without rows or columns at a level) replaced by ``fill``."""
    return np.where(np.isnan(x), fill, x)


def motion_prior_reference(leaves: NDArray[np.int64], weights: NDArray[np.float64], db: FilterDB,
                           inv_var: NDArray[np.float64], hist_weight: float) -> NDArray[np.float64]:
    """Reference of :func:`tracker_service.estimators.tree_filter._kernels.leaf_prior_kernel`
    (unnormalised eq. 13 + eq. 5 mass of the supported leaves).

    Returns
    -------
    (NL,) float64
    """
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


def heading_mass_reference(prior: NDArray[np.float64], heading: NDArray[np.float32], allowed: NDArray[np.bool_],
                           mean_heading: float, max_turn: float, uniform_mass: float) -> NDArray[np.float64]:
    """Reference of :func:`tracker_service.estimators.tree_filter._kernels.heading_mass_kernel` (returns a new array).

    Returns
    -------
    (NL,) float64
    """
    prior = prior.copy()
    turn = np.abs(np.remainder(heading - np.float64(mean_heading) + np.pi, 2.0 * np.pi) - np.pi)
    near = (turn < max_turn) & allowed
    prior *= 1.0 - uniform_mass
    prior[near] += uniform_mass / max(int(near.sum()), 1)
    prior *= allowed
    return prior


def level_priors_reference(leaf_anc: NDArray[np.int64], prior: NDArray[np.float64],
                           sizes: list[int]) -> list[NDArray[np.float64]]:
    """Reference of :func:`tracker_service.estimators.tree_filter._kernels.level_priors_kernel`: each level's node
    priors (eq. 4).

    Returns
    -------
    list of (N_l,) float64
    """
    return [np.bincount(leaf_anc[lvl], weights=prior, minlength=n).astype(np.float64, copy=False)
            for lvl, n in enumerate(sizes)]


def node_predictions_reference(db: FilterDB, level: int, nodes: NDArray[np.int64], pred: NDArray[np.float64],
                               obs_weight: float, obs: NDArray[np.float64] | None = None,
                               rows: NDArray[np.float64] | None = None,
                               scale_range: tuple[float, float] = (0.0, np.inf)) -> NDArray[np.float64]:
    """Reference of :func:`tracker_service.estimators.tree_filter._kernels.node_predictions_kernel` (the model:
    :func:`tracker_service.estimators.tree_filter.filter._node_predictions`).

    Returns
    -------
    (n, H, 3) float64
    """
    out = np.repeat(pred[None], len(nodes), axis=0)
    has_rows = bool(db.level_bottom) and np.isfinite(db.ref_bottom)
    cy = db.center[1]
    bottom = db.level_bottom[level][nodes] if has_rows else None
    if obs_weight > 0 and obs is not None and bottom is not None:
        c = (db.ref_bottom - cy) / np.maximum(bottom - cy, 1.0)
        c = np.clip(finite(c, 1.0), 0.8, 2.0)
        out[:, 2] += obs_weight * obs[2] * (c - 1.0)
        out[:, 1] += obs_weight * obs[1] * (c - 1.0)
    hyps = [out]
    if rows is not None and bottom is not None and db.level_top:
        height = bottom - db.level_top[level][nodes]
        ok = np.isfinite(height) & (height > 4.0)
        alt = out.copy()
        s_h = np.where(ok, (rows[1] - rows[0]) / np.where(ok, height, 1.0), out[:, 2])
        alt[:, 2] = np.clip(s_h, *scale_range)
        alt[:, 1] = np.where(ok, rows[1] - cy - alt[:, 2] * (finite(bottom) - cy), out[:, 1])
        hyps.append(alt)
    res = np.stack(hyps, axis=1)
    if obs_weight > 0 and db.level_column and np.isfinite(db.ref_column):
        corr = obs_weight * res[..., 2] * (db.ref_column - db.level_column[level][nodes])[:, None]
        res[..., 0] += finite(corr)
    return res


def placement_cost_reference(places: NDArray[np.float64], pred: NDArray[np.float64], params: FilterParams
                             ) -> NDArray[np.float64]:
    """Negative log prior of placements around the predicted ones (Gaussian in shift and scale);
    ``pred`` broadcasts against ``places`` (both ``(..., 3)``)."""
    return 0.5 * (((places[..., 0] - pred[..., 0]) / params.placement_sigma_px) ** 2
                  + ((places[..., 2] / pred[..., 2] - 1.0) / params.placement_sigma_scale) ** 2)


def mixture_cost_reference(places: NDArray[np.float64], hyps: NDArray[np.float64], params: FilterParams,
                           motion_scale: float | None = None) -> NDArray[np.float64]:
    """Placement prior of ``places`` ``(n, G, 3)`` under the mixture of the nodes' hypotheses
    ``(n, H, 3)`` (the cheapest hypothesis for each placement); the height hypothesis's scale is
    held to ``motion_scale``."""
    costs = [placement_cost_reference(places, hyps[:, 0, None], params)]
    if hyps.shape[1] > 1:
        ref = hyps[:, 1].copy()
        if motion_scale is not None:
            ref[:, 2] = motion_scale
        costs.append(placement_cost_reference(places, ref[:, None], params) + params.airborne_cost)
    return np.min(costs, axis=0)


def level_cost_reference(d: NDArray[np.float64], places: NDArray[np.float64], hyps: NDArray[np.float64],
                         sigma: float, params: FilterParams, motion_scale: float) -> NDArray[np.float64]:
    """Reference of :func:`tracker_service.estimators.tree_filter._kernels.level_cost_kernel`.

    Returns
    -------
    (n, G) float64
    """
    return 0.5 * (d / sigma) ** 2 + mixture_cost_reference(places, hyps, params, motion_scale)


def expand_reference(db: FilterDB, level: int, nodes: NDArray[np.int64], keep: NDArray[np.int64],
                     node_place: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Reference of :func:`tracker_service.estimators.tree_filter._kernels.expand_kernel`.

    Returns
    -------
    children : (m,) int64
    centers : (m, 3) float64
    """
    tree = db.tree
    kids = [tree.children(level, int(nodes[k])) for k in keep]
    parent = np.repeat(keep, [len(c) for c in kids])
    centers = node_place[parent].copy()
    parent_nodes = nodes[parent]
    children = np.concatenate(kids)
    if db.level_column:
        dcol = db.level_column[level][parent_nodes] - db.level_column[level + 1][children]
        centers[:, 0] += finite(centers[:, 2] * dcol)
    return children, centers


def mean_pose_reference(poses: NDArray[np.float64], w: NDArray[np.float64]) -> NDArray[np.float64]:
    """Reference of :func:`tracker_service.estimators.tree_filter._kernels.mean_pose_kernel` (``poses`` ``(n, P)``).

    Returns
    -------
    (P,) float64
    """
    n = len(poses)
    q = matrix_to_quat(rotvec_to_matrix(poses[:, 3:].reshape(n, -1, 3)))  # (n, R, 4)
    q = np.where((np.einsum("nrc,rc->nr", q, q[0]) < 0)[..., None], -q, q)  # same hemisphere
    qm = np.einsum("n,nrc->rc", w, q)
    out = np.empty(POSE_SIZE)
    out[:3] = w @ poses[:, :3]
    out[3:] = matrix_to_rotvec(quat_to_matrix(qm)).reshape(-1)
    return out
