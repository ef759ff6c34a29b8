"""ELMO §3.1: sampling with parameter-sensitive hashing (Shakhnarovich, Viola & Darrell 2003).

The database's templates (the :class:`~tracker_service.estimators.tree_filter.model.FilterDB` leaves)
are indexed by an image feature of their silhouettes; the hash functions are *learned* so that
pairs of leaves with similar poses collide and pairs with dissimilar poses do not. A query returns
leaves whose poses are likely near a mode of the likelihood: the starting points of the local
search (§3.2).

Image feature (the paper concatenates multi-scale edge direction histograms of the image; we have a
binary silhouette): the silhouette cropped to its bounding box and divided into a ``grid_rows x
grid_cols`` grid, each cell's occupied fraction, plus the box's aspect ratio (width / height) --
invariant to the placement (shift and scale) by construction. :func:`runs_features` computes it
straight from horizontal runs (the database's storage form, no rasterisation), so a leaf and an
observation (:func:`observed_mask` turned into runs) go through the same code.

PSH (the paper's §3.1 and [16]): a hash bit is ``h(x) = [x_d > T]``. From random candidates ``(d, T)``
(``T`` at a random quantile of dimension ``d``), those with the best *PSH criterion* on sampled pairs
of leaves are kept::

    score(h) = P(h(x) = h(x') | pose-similar) - P(h(x) = h(x') | pose-dissimilar)

(pose-similar: mean joint distance, root-relative, below ``similar_m``; dissimilar: above
``dissimilar_m``). ``l`` tables each concatenate ``k`` bits drawn at random from the kept ones
(locality-sensitive hashing's amplification); a query's candidates are the union of its buckets
over the tables, ranked by feature distance, the ``n`` nearest returned.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from protocol.kinematics import fk
from protocol.skeleton import Body
from tracker_service.silhouette.distance import RunSet, mask_to_runs
from tracker_service.silhouette.features import LevelFeatures

__all__ = ["PSHIndex", "PSHParams", "build_index", "leaf_joints", "observed_mask", "runs_features",
           "silhouette_feature"]


@dataclass(frozen=True)
class PSHParams:
    """Tuning of the index.

    Attributes
    ----------
    grid_rows, grid_cols : int
        Occupancy grid over the silhouette's bounding box.
    n_tables, n_bits : int
        ``l`` tables of ``k`` bits.
    n_candidates : int
        Random threshold functions ``(d, T)`` scored by the PSH criterion.
    n_keep : int
        Best-scoring functions the tables draw their bits from.
    n_pairs : int
        Similar and dissimilar pairs (each) sampled to score them.
    similar_m, dissimilar_m : float
        Mean root-relative joint distance (m) below which a pair is pose-similar, above which it is
        dissimilar (the paper: 5 cm between key joints).
    max_train_leaves : int
        Leaves sampled for the thresholds' quantiles (all leaves are indexed, pairs drawn from all).
    """

    grid_rows: int = 16
    grid_cols: int = 8
    n_tables: int = 20
    n_bits: int = 12
    n_candidates: int = 600
    n_keep: int = 80
    n_pairs: int = 4000
    similar_m: float = 0.05
    dissimilar_m: float = 0.15
    max_train_leaves: int = 20000


def observed_mask(feat: LevelFeatures) -> NDArray[np.bool_]:
    """The observed silhouette of one pyramid level, recovered from its features: ``A < 0`` exactly
    on the silhouette for XOR (``1 - 2S``), cwXOR and nwXOR (``D(S) = 0`` and a positive core term
    inside, ``D(S) > 0`` outside)."""
    return np.diff(feat.integral, axis=1) < 0


def runs_features(runset: RunSet, grid_rows: int = 16, grid_cols: int = 8, chunk: int = 4000
                  ) -> NDArray[np.float32]:
    """The feature of every template of ``runset``: occupied fraction of each cell of a
    ``grid_rows x grid_cols`` grid over the template's bounding box, then the box's width / height.

    Returns
    -------
    (T, grid_rows * grid_cols + 1) float32
        Zeros for an empty template.
    """
    n = len(runset)
    out = np.zeros((n, grid_rows * grid_cols + 1), np.float32)
    ptr = runset.ptr
    for a in range(0, n, chunk):
        b = min(a + chunk, n)
        data = runset.data[ptr[a]: ptr[b]].astype(np.float64)
        if len(data) == 0:
            continue
        counts = np.diff(ptr[a: b + 1])
        owner = np.repeat(np.arange(b - a), counts)
        nz = counts > 0
        starts = (ptr[a:b] - ptr[a])[nz]
        y, xs, xe = data[:, 0], data[:, 1], data[:, 2]
        y0 = np.full(b - a, np.inf)
        y1 = np.full(b - a, -np.inf)
        x0 = np.full(b - a, np.inf)
        x1 = np.full(b - a, -np.inf)
        y0[nz] = np.minimum.reduceat(y, starts)
        y1[nz] = np.maximum.reduceat(y, starts)
        x0[nz] = np.minimum.reduceat(xs, starts)
        x1[nz] = np.maximum.reduceat(xe, starts)
        h = np.where(nz, y1 - y0 + 1, 1.0)
        w = np.where(nz, x1 - x0, 1.0)
        row = np.minimum(((y - y0[owner]) / h[owner] * grid_rows).astype(np.int64), grid_rows - 1)
        cell_w = w / grid_cols
        acc = np.zeros((b - a) * grid_rows * grid_cols)
        for c in range(grid_cols):
            lo = x0[owner] + c * cell_w[owner]
            hi = lo + cell_w[owner]
            ov = np.clip(np.minimum(xe, hi) - np.maximum(xs, lo), 0.0, None)
            acc += np.bincount((owner * grid_rows + row) * grid_cols + c, weights=ov,
                               minlength=len(acc))
        rows_per_cell = h / grid_rows  # pixel rows per grid row (fractional)
        area = (rows_per_cell * cell_w)[:, None]
        occ = acc.reshape(b - a, grid_rows * grid_cols) / np.maximum(area, 1e-9)
        out[a:b, :-1] = np.where(nz[:, None], np.clip(occ, 0.0, 1.0), 0.0)
        out[a:b, -1] = np.where(nz, w / h, 0.0)
    return out


def silhouette_feature(mask: NDArray[np.bool_], grid_rows: int = 16, grid_cols: int = 8) -> NDArray[np.float32]:
    """:func:`runs_features` of one binary mask. Returns ``(grid_rows * grid_cols + 1,)``."""
    return runs_features(RunSet([mask_to_runs(mask)]), grid_rows, grid_cols)[0]


def leaf_joints(poses: NDArray[np.float64] | NDArray[np.float32], body: Body) -> NDArray[np.float64]:
    """Root-relative joint positions ``(N, J, 3)`` of poses (the pose-similarity space of PSH)."""
    j = fk(np.asarray(poses, np.float64), body)
    return j - j[:, :1]


def _mean_joint_distance(ja: NDArray[np.float64], jb: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.linalg.norm(ja - jb, axis=-1).mean(axis=-1)


@dataclass(frozen=True)
class PSHIndex:
    """The learned hash tables over the leaves' features.

    Attributes
    ----------
    features : (NL, F) float32
        Every indexed leaf's feature.
    dims, thresholds : (l, k) int64, float32
        Bit ``b`` of table ``t`` is ``features[:, dims[t, b]] > thresholds[t, b]``.
    sorted_codes : (l, NL) int64
        Each table's codes sorted; ``order[t]`` the leaves in that order.
    order : (l, NL) int64
    scores : (n_keep,) float64
        The PSH criterion of the kept functions (diagnostics).
    params : PSHParams
    """

    features: NDArray[np.float32]
    dims: NDArray[np.int64]
    thresholds: NDArray[np.float32]
    sorted_codes: NDArray[np.int64]
    order: NDArray[np.int64]
    scores: NDArray[np.float64]
    params: PSHParams

    def codes(self, x: NDArray[np.float32]) -> NDArray[np.int64]:
        """Hash codes ``(l, N)`` of features ``x`` ``(N, F)``."""
        bits = x[:, self.dims] > self.thresholds  # (N, l, k)
        weights = np.int64(1) << np.arange(self.dims.shape[1], dtype=np.int64)
        return (bits.astype(np.int64) @ weights).T

    def candidates(self, x: NDArray[np.float32]) -> NDArray[np.int64]:
        """The union over the tables of the leaves that collide with one feature ``x`` ``(F,)``."""
        code = self.codes(np.asarray(x, np.float32)[None])[:, 0]
        found = []
        for t in range(len(code)):
            lo, hi = np.searchsorted(self.sorted_codes[t], [code[t], code[t] + 1])
            found.append(self.order[t, lo:hi])
        return np.unique(np.concatenate(found)) if found else np.zeros(0, np.int64)

    def query(self, x: NDArray[np.float32], n: int = 50, min_candidates: int = 0) -> NDArray[np.int64]:
        """The ``n`` colliding leaves nearest to ``x`` in feature space (Euclidean), nearest first.
        When fewer than ``min_candidates`` collide, every leaf is ranked instead (a linear scan: the
        hashing's fallback for an unusual silhouette)."""
        cand = self.candidates(x)
        if len(cand) < min_candidates:
            cand = np.arange(len(self.features))
        d = np.linalg.norm(self.features[cand] - np.asarray(x, np.float32), axis=1)
        k = min(n, len(cand))
        if k == 0:
            return np.zeros(0, np.int64)
        part = np.argpartition(d, k - 1)[:k]
        return cand[part[np.argsort(d[part], kind="stable")]]


def _sample_pairs(joints: NDArray[np.float64], nbr: NDArray[np.int64] | None, params: PSHParams,
                  rng: np.random.Generator) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Pose-similar and pose-dissimilar pairs ``(n, 2)`` of leaf indices (into ``joints``)."""
    n = len(joints)
    m = params.n_pairs
    # similar: among the database's nearest leaves in pose space when known, else random nearby rows
    if nbr is not None and nbr.shape[1] > 1:
        a = rng.integers(0, n, 4 * m)
        b = nbr[a, rng.integers(1, nbr.shape[1], 4 * m)]
    else:
        a = rng.integers(0, n, 4 * m)
        b = np.clip(a + rng.integers(-3, 4, 4 * m), 0, n - 1)
    keep = (a != b) & (_mean_joint_distance(joints[a], joints[b]) < params.similar_m)
    sim = np.stack([a[keep], b[keep]], axis=1)[:m]
    a = rng.integers(0, n, 4 * m)
    b = rng.integers(0, n, 4 * m)
    keep = _mean_joint_distance(joints[a], joints[b]) > params.dissimilar_m
    dis = np.stack([a[keep], b[keep]], axis=1)[:m]
    return sim, dis


def build_index(features: NDArray[np.float32], joints: NDArray[np.float64], params: PSHParams | None = None,
                rng: np.random.Generator | None = None, nbr: NDArray[np.int64] | None = None) -> PSHIndex:
    """Learn the PSH functions on pairs of leaves and hash every leaf.

    Parameters
    ----------
    features : (NL, F) float32
        Every leaf's feature (:func:`runs_features`).
    joints : (NL, J, 3) float64
        Root-relative joints of every leaf (:func:`leaf_joints`): pose similarity.
    params : PSHParams
    rng : Generator
    nbr : (NL, K) int64, optional
        Nearest leaves in pose space (``FilterDB.nbr_idx``): where similar pairs are found.

    Returns
    -------
    PSHIndex
    """
    prm = params or PSHParams()
    rng = rng if rng is not None else np.random.default_rng(0)
    n, f = features.shape
    sim, dis = _sample_pairs(joints, nbr, prm, rng)
    xs = features  # the thresholds' quantiles: on a subsample of a large database
    if n > prm.max_train_leaves:
        xs = features[np.sort(rng.choice(n, prm.max_train_leaves, replace=False))]
    # candidate functions: a dimension with some spread, a threshold at a random quantile of it
    spread = xs.std(axis=0)
    live = np.flatnonzero(spread > 1e-6)
    if len(live) == 0:
        live = np.arange(f)
    cd = rng.choice(live, prm.n_candidates)
    q = rng.uniform(0.1, 0.9, prm.n_candidates)
    sorted_cols = np.sort(xs[:, cd], axis=0)
    ct = sorted_cols[(q * (len(xs) - 1)).astype(np.int64), np.arange(prm.n_candidates)]

    def collide(pairs: NDArray[np.int64]) -> NDArray[np.float64]:
        if len(pairs) == 0:
            return np.zeros(prm.n_candidates)
        ha = features[pairs[:, 0]][:, cd] > ct
        hb = features[pairs[:, 1]][:, cd] > ct
        return np.asarray((ha == hb).mean(axis=0), np.float64)

    score = collide(sim) - collide(dis)  # the PSH criterion
    keep = np.argsort(-score, kind="stable")[: min(prm.n_keep, prm.n_candidates)]
    k = min(prm.n_bits, len(keep))
    pick = np.stack([rng.choice(len(keep), k, replace=False) for _ in range(prm.n_tables)])
    dims = cd[keep][pick].astype(np.int64)
    thr = ct[keep][pick].astype(np.float32)
    index = PSHIndex(features, dims, thr, np.zeros((0, 0), np.int64), np.zeros((0, 0), np.int64),
                     score[keep], prm)
    codes = index.codes(features)
    order = np.argsort(codes, axis=1, kind="stable")
    return PSHIndex(features, dims, thr, np.take_along_axis(codes, order, axis=1), order, score[keep], prm)
