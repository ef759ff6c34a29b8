"""Numba kernels of the tree filter's per-frame bookkeeping (:mod:`tracker_service.estimators.tree_filter.filter`):
the heading part of the prior, the node priors of every level, the nodes' predicted placements,
the placement prior of a level's grid, the expansion of the kept nodes into their children and
the posterior-mean pose.

Each repeats a numpy computation operation for operation (same operands, same order, no fused
multiply-adds), so the filter's decisions do not move; the plain-numpy references live in
:mod:`tracker_service.estimators.tree_filter.reference` and tests hold the two equal (bit for bit, the mean pose
to 1e-12). Transcendental functions (``exp``, ``log``) stay in numpy where the filter decides
with them: numpy's SIMD versions are not bit-equal to libm's.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True, nogil=True)
def heading_mass_kernel(prior: NDArray[np.float64], heading: NDArray[np.float32], allowed: NDArray[np.bool_],
                        mean_heading: float, max_turn: float, uniform_mass: float) -> bool:
    """Mix the re-acquisition mass into the motion prior and drop the leaves not allowed, in place:
    the tail of :func:`tracker_service.estimators.tree_filter.filter.predict_leaves` (reference:
    :func:`tracker_service.estimators.tree_filter.reference.heading_mass_reference`).

    Parameters
    ----------
    prior : (NL,) float64
        The motion prior (unnormalised); scaled by ``1 - uniform_mass``, plus the uniform mass on
        the allowed leaves whose heading is within ``max_turn`` of ``mean_heading``, times ``allowed``.
    heading : (NL,) float32
        Each leaf's heading (radians).
    allowed : (NL,) bool
    mean_heading, max_turn, uniform_mass : float

    Returns
    -------
    bool
        False (``prior`` untouched) when a heading lies outside ``[-pi, pi]``: then the reference
        (whose ``fmod`` the kernel leaves out) must do it.
    """
    n = prior.shape[0]
    two_pi = 2.0 * np.pi
    near = np.empty(n, np.bool_)
    count = 0
    for i in range(n):
        x = np.float64(heading[i]) - mean_heading + np.pi
        # numpy's remainder: fmod, then the divisor's sign (+0 for an exact multiple). Headings lie
        # in [-pi, pi], so x in [-pi, 3pi]: fmod is x, or x - 2pi (exact: Sterbenz)
        if not -two_pi < x < 2.0 * two_pi:
            return False  # a heading outside [-pi, pi]: the caller takes the numpy reference
        m = x - two_pi if x >= two_pi else x
        m = (m + two_pi if m < 0.0 else m) + 0.0  # + 0.0: -0 -> +0
        ok = (abs(m - np.pi) < max_turn) & allowed[i]
        near[i] = ok
        count += 1 if ok else 0
    keep = 1.0 - uniform_mass
    add = uniform_mass / max(count, 1)
    for i in range(n):
        p = prior[i] * keep
        p = p + add if near[i] else p
        prior[i] = p * (1.0 if allowed[i] else 0.0)
    return True


@njit(cache=True, nogil=True)
def level_priors_kernel(leaf_anc: NDArray[np.int64], prior: NDArray[np.float64], offsets: NDArray[np.int64],
                        out: NDArray[np.float64]) -> None:
    """Prior of every node of every level (eq. 4: the sum of its leaves' priors), added in leaf
    order as ``np.bincount(leaf_anc[l], weights=prior)`` adds them.

    Parameters
    ----------
    leaf_anc : (L, NL) int64
        Ancestor node of each leaf at every level.
    prior : (NL,) float64
    offsets : (L + 1,) int64
        Start of each level's nodes in ``out`` (``offsets[l + 1] - offsets[l]`` = the level's size).
    out : (offsets[L],) float64
        Zeroed; accumulated into.
    """
    n_lvl = leaf_anc.shape[0]
    for i in range(prior.shape[0]):  # the levels interleaved: independent chains of additions
        p = prior[i]
        for lvl in range(n_lvl):
            out[offsets[lvl] + leaf_anc[lvl, i]] += p


@njit(cache=True, nogil=True)
def node_predictions_kernel(nodes: NDArray[np.int64], pred: NDArray[np.float64], obs: NDArray[np.float64],
                            obs_weight: float, use_obs: bool, bottom: NDArray[np.float64], top: NDArray[np.float64],
                            use_height: bool, rows: NDArray[np.float64], scale_lo: float, scale_hi: float,
                            column: NDArray[np.float64], use_column: bool, ref_column: float, ref_bottom: float,
                            cy: float) -> NDArray[np.float64]:
    """Predicted placements of nodes, one per placement hypothesis (reference:
    :func:`tracker_service.estimators.tree_filter.reference.node_predictions_reference`; the model is described in
    :func:`tracker_service.estimators.tree_filter.filter._node_predictions`).

    Parameters
    ----------
    nodes : (n,) int64
        The nodes (indices into the level's ``bottom``, ``top`` and ``column``).
    pred : (3,) float64
        The motion prediction blended with the observation.
    obs : (3,) float64
        The observed placement (read only with ``use_obs``).
    obs_weight : float
    use_obs : bool
        Correct the scale and vertical shift for each template's lowest row.
    bottom, top : (N_l,) float64
        The level's lowest and highest template rows (read with ``use_obs`` / ``use_height``).
    use_height : bool
        Add the silhouette-height hypothesis (``H`` = 2).
    rows : (2,) float64
        The silhouette's top and bottom rows (read with ``use_height``).
    scale_lo, scale_hi : float
        Bounds of the height hypothesis's scale.
    column : (N_l,) float64
        The level's template columns (read with ``use_column``).
    use_column : bool
    ref_column, ref_bottom, cy : float

    Returns
    -------
    (n, H, 3) float64
    """
    n = nodes.shape[0]
    n_h = 2 if use_height else 1
    res = np.empty((n, n_h, 3))
    wo1 = obs_weight * obs[1] if use_obs else 0.0
    wo2 = obs_weight * obs[2] if use_obs else 0.0
    rb = ref_bottom - cy
    r1c = rows[1] - cy if use_height else 0.0
    dr = rows[1] - rows[0] if use_height else 0.0
    for i in range(n):
        nd = nodes[i]
        o0, o1, o2 = pred[0], pred[1], pred[2]
        if use_obs:
            b = bottom[nd] - cy
            if not b >= 1.0 and not math.isnan(b):  # np.maximum(b, 1.0), NaN kept
                b = 1.0
            c = rb / b
            if math.isnan(c):
                c = 1.0
            c = min(max(c, 0.8), 2.0)
            o2 = o2 + wo2 * (c - 1.0)
            o1 = o1 + wo1 * (c - 1.0)
        res[i, 0, 0] = o0
        res[i, 0, 1] = o1
        res[i, 0, 2] = o2
        if use_height:
            h = bottom[nd] - top[nd]
            ok = math.isfinite(h) and h > 4.0
            s = dr / h if ok else o2
            s = min(max(s, scale_lo), scale_hi)
            fb = 0.0 if math.isnan(bottom[nd]) else bottom[nd]
            res[i, 1, 0] = o0
            res[i, 1, 1] = r1c - s * (fb - cy) if ok else o1
            res[i, 1, 2] = s
        if use_column:
            dc = ref_column - column[nd]
            for k in range(n_h):
                corr = obs_weight * res[i, k, 2] * dc
                res[i, k, 0] += 0.0 if math.isnan(corr) else corr
    return res


@njit(cache=True, nogil=True)
def level_cost_kernel(d: NDArray[np.float64], places: NDArray[np.float64], hyps: NDArray[np.float64], sigma: float,
                      sigma_px: float, sigma_scale: float, motion_scale: float, airborne_cost: float
                      ) -> NDArray[np.float64]:
    """eq. 6's negative log likelihood plus the placement prior under the mixture of each node's
    hypotheses (reference: :func:`tracker_service.estimators.tree_filter.reference.level_cost_reference`).

    Parameters
    ----------
    d : (n, G) float64
        Silhouette distances of each node at each placement.
    places : (n, G, 3) float64
        The placements.
    hyps : (n, H, 3) float64
        The nodes' predicted placements: the feet on the floor, and (``H`` = 2) the silhouette's
        height, whose scale is held to ``motion_scale`` and which costs ``airborne_cost`` more.
    sigma : float
        The level's likelihood standard deviation.
    sigma_px, sigma_scale : float
        The placement prior's standard deviations (shift in pixels, relative scale).
    motion_scale, airborne_cost : float

    Returns
    -------
    (n, G) float64
    """
    n, g = d.shape
    out = np.empty((n, g))
    two = hyps.shape[1] > 1
    for i in range(n):
        q0, q2 = hyps[i, 0, 0], hyps[i, 0, 2]
        r0 = hyps[i, 1, 0] if two else 0.0
        for j in range(g):
            p0, p2 = places[i, j, 0], places[i, j, 2]
            a = (p0 - q0) / sigma_px
            b = (p2 / q2 - 1.0) / sigma_scale
            c = 0.5 * (a * a + b * b)
            if two:
                a = (p0 - r0) / sigma_px
                b = (p2 / motion_scale - 1.0) / sigma_scale
                c1 = 0.5 * (a * a + b * b) + airborne_cost
                if not (c <= c1 or math.isnan(c)):  # np.minimum: NaN wins
                    c = c1
            x = d[i, j] / sigma
            out[i, j] = 0.5 * (x * x) + c
    return out


@njit(cache=True, nogil=True)
def expand_kernel(child_ptr: NDArray[np.int64], nodes: NDArray[np.int64], keep: NDArray[np.int64],
                  node_place: NDArray[np.float64], column: NDArray[np.float64], child_column: NDArray[np.float64],
                  use_column: bool) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The children of the kept nodes and their starting placements: each child starts from its
    parent's best placement, shifted by the difference of their template columns (reference:
    :func:`tracker_service.estimators.tree_filter.reference.expand_reference`).

    Parameters
    ----------
    child_ptr : (N_l + 1,) int64
        CSR pointers of the level's nodes into the next level.
    nodes : (n,) int64
        The level's searched nodes.
    keep : (k,) int64
        Indices into ``nodes`` of the nodes to expand.
    node_place : (n, 3) float64
        Each searched node's best placement.
    column, child_column : (N_l,), (N_{l+1},) float64
        Template columns of the level's and the next level's nodes (read with ``use_column``).
    use_column : bool

    Returns
    -------
    children : (m,) int64
    centers : (m, 3) float64
    """
    m = 0
    for k in keep:
        m += child_ptr[nodes[k] + 1] - child_ptr[nodes[k]]
    children = np.empty(m, np.int64)
    centers = np.empty((m, 3))
    j = 0
    for k in keep:
        par = nodes[k]
        for c in range(child_ptr[par], child_ptr[par + 1]):
            children[j] = c
            x0, x1, x2 = node_place[k, 0], node_place[k, 1], node_place[k, 2]
            if use_column:
                v = x2 * (column[par] - child_column[c])
                x0 += 0.0 if math.isnan(v) else v
            centers[j, 0] = x0
            centers[j, 1] = x1
            centers[j, 2] = x2
            j += 1
    return children, centers


@njit(cache=True, nogil=True)
def _rotvec_quat(x: float, y: float, z: float, q: NDArray[np.float64]) -> None:
    """Rodrigues' matrix of a rotation vector, then Shepperd's quaternion (``w >= 0``), as
    :func:`protocol.rotations.rotvec_to_matrix` and :func:`protocol.rotations.matrix_to_quat`."""
    theta = math.sqrt(x * x + y * y + z * z)
    if theta < 1e-8:
        a = 1.0 - theta**2 / 6.0
        b = 0.5 - theta**2 / 24.0
    else:
        a = math.sin(theta) / theta
        b = (1.0 - math.cos(theta)) / theta**2
    # K = [[0, -z, y], [z, 0, -x], [-y, x, 0]]; K @ K
    m00 = 1.0 + b * (-z * z - y * y)
    m11 = 1.0 + b * (-z * z - x * x)
    m22 = 1.0 + b * (-y * y - x * x)
    m01 = a * -z + b * (y * x)
    m02 = a * y + b * (z * x)
    m10 = a * z + b * (x * y)
    m12 = a * -x + b * (z * y)
    m20 = a * -y + b * (x * z)
    m21 = a * x + b * (y * z)
    _matrix_quat(m00, m01, m02, m10, m11, m12, m20, m21, m22, q)


@njit(cache=True, nogil=True)
def _matrix_quat(m00: float, m01: float, m02: float, m10: float, m11: float, m12: float, m20: float, m21: float,
                 m22: float, q: NDArray[np.float64]) -> None:
    """Shepperd's method (:func:`protocol.rotations.matrix_to_quat`): unit ``(w, x, y, z)``, ``w >= 0``."""
    c0 = 1 + m00 + m11 + m22
    c1 = 1 + m00 - m11 - m22
    c2 = 1 - m00 + m11 - m22
    c3 = 1 - m00 - m11 + m22
    idx, best = 0, c0
    if c1 > best:
        idx, best = 1, c1
    if c2 > best:
        idx, best = 2, c2
    if c3 > best:
        idx, best = 3, c3
    s = math.sqrt(max(best, 1e-12)) * 2.0
    if idx == 0:
        q[0], q[1], q[2], q[3] = 0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s
    elif idx == 1:
        q[0], q[1], q[2], q[3] = (m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s
    elif idx == 2:
        q[0], q[1], q[2], q[3] = (m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s
    else:
        q[0], q[1], q[2], q[3] = (m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s
    nrm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    sign = -1.0 if q[0] / nrm < 0 else 1.0
    for c in range(4):
        q[c] = sign * (q[c] / nrm)


@njit(cache=True, nogil=True)
def mean_pose_kernel(poses: NDArray[np.float64], w: NDArray[np.float64]) -> NDArray[np.float64]:
    """Weighted mean pose: the root position averaged, each joint's rotation the normalised weighted
    sum of its quaternions on the first pose's hemisphere (reference:
    :func:`tracker_service.estimators.tree_filter.reference.mean_pose_reference`, equal to 1e-12).

    Parameters
    ----------
    poses : (n, P) float64
        Root position, then one rotation vector per joint (``n`` >= 1).
    w : (n,) float64
        Their weights (sum 1).

    Returns
    -------
    (P,) float64
    """
    n, p = poses.shape
    out = np.zeros(p)
    for c in range(3):
        acc = 0.0
        for i in range(n):
            acc += w[i] * poses[i, c]
        out[c] = acc
    q0 = np.empty(4)
    q = np.empty(4)
    qm = np.empty(4)
    for r in range((p - 3) // 3):
        j = 3 + 3 * r
        qm[:] = 0.0
        for i in range(n):
            _rotvec_quat(poses[i, j], poses[i, j + 1], poses[i, j + 2], q)
            if i == 0:
                q0[:] = q
            sgn = -1.0 if q[0] * q0[0] + q[1] * q0[1] + q[2] * q0[2] + q[3] * q0[3] < 0 else 1.0
            for c in range(4):
                qm[c] += w[i] * (sgn * q[c])
        nrm = math.sqrt(qm[0] ** 2 + qm[1] ** 2 + qm[2] ** 2 + qm[3] ** 2)
        qw, qx, qy, qz = qm[0] / nrm, qm[1] / nrm, qm[2] / nrm, qm[3] / nrm
        _matrix_quat(1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy),
                     2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx),
                     2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy), q)
        s = math.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
        scale = 2.0 if s < 1e-10 else 2.0 * math.atan2(s, q[0]) / s
        out[j] = q[1] * scale
        out[j + 1] = q[2] * scale
        out[j + 2] = q[3] * scale
    return out


@njit(cache=True, nogil=True)
def leaf_prior_kernel(leaves: NDArray[np.int64], weights: NDArray[np.float64], nbr_idx: NDArray[np.int64],
                      nbr_dpart: NDArray[np.float32], inv_var: NDArray[np.float64], trans_ptr: NDArray[np.int64],
                      trans_idx: NDArray[np.int64], trans_p: NDArray[np.float32], hist_weight: float,
                      prior: NDArray[np.float64]) -> None:
    """Add the motion prior of the supported leaves to ``prior`` (eq. 13 with eq. 14's variances, and
    the transition histograms of eq. 5): the loop of
    :func:`tracker_service.estimators.tree_filter.filter.predict_leaves`.

    Parameters
    ----------
    leaves : (M,) int64
    weights : (M,) float64
    nbr_idx : (NL, K) int64
        Pose-space neighbours of every leaf.
    nbr_dpart : (NL, K, N_PARTS) float32
        Their squared per-part pose differences.
    inv_var : (N_PARTS,) float64
        Inverse variances per part.
    trans_ptr, trans_idx, trans_p
        CSR transition histograms.
    hist_weight : float
    prior : (NL,) float64
        Accumulated into.
    """
    k = nbr_idx.shape[1]
    npart = inv_var.shape[0]
    g = np.empty(k)
    for m in range(leaves.shape[0]):
        leaf = leaves[m]
        w = weights[m]
        tot = 0.0
        for j in range(k):
            e = 0.0
            for p in range(npart):
                e += np.float64(nbr_dpart[leaf, j, p]) * inv_var[p]
            g[j] = np.exp(-0.5 * e)
            tot += g[j]
        a, b = trans_ptr[leaf], trans_ptr[leaf + 1]
        hw = hist_weight if b > a else 0.0
        f = w * (1.0 - hw) / tot
        for j in range(k):
            prior[nbr_idx[leaf, j]] += f * g[j]
        if hw != 0.0:
            for t in range(a, b):
                prior[trans_idx[t]] += w * hw * np.float64(trans_p[t])
