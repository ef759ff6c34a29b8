"""The shape hierarchy (Okada & Stenger §2, Algorithm 1): hierarchical clustering of template
silhouettes into a tree whose nodes each carry a prototype pose.

Algorithm 1, for each node ``n`` of level ``L - 1``:

1. the first prototype is the member with the smallest mean silhouette distance to the others;
2. then, while ``d_max > t_L``, the member farthest from the prototypes chosen so far becomes a
   prototype;
3. every member is assigned to its closest prototype;
4. each cluster is a node of level ``L`` with parent ``n``.

"Farthest" (step 2) is the distance to the *nearest* chosen prototype (farthest-point clustering),
which guarantees that every member lies within ``t_L`` of its prototype -- the property the
coarse-to-fine search relies on. Read literally, the paper's wording ("largest mean silhouette
distance from the selected poses") does not terminate usefully: the mean distance of a point to a
spreading set of prototypes tends to the node's average pairwise distance, so with any ``t_L``
below it every member becomes a prototype (measured: 200 of 200 points of a 2D normal sample at
``t_L = 1``). For nodes with more than ``medoid_sample`` members the first prototype is the medoid
of a random sample (an exact medoid is O(n^2) distance evaluations).

Distances are supplied per level by a :class:`LevelDistance`: ``distances(proto, members)`` returns
the silhouette distance of one template to many. :class:`PackedMaskDistance` is the one used by the
database: XOR (Hamming) distance between bit-packed binary silhouettes, as a fraction of pixels.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from tracker_service.templates._kernels import hamming_to_many

__all__ = ["LevelDistance", "PackedMaskDistance", "TemplateTree", "build_tree", "cluster_node",
           "hamming_to_many_reference", "pack_masks"]

log = logging.getLogger(__name__)


class LevelDistance(Protocol):
    """Silhouette distance between templates at one tree level."""

    def distances(self, proto: int, members: NDArray[np.int64]) -> NDArray[np.float64]:
        """Distances from template ``proto`` to each template in ``members``, ``(n,)`` float64."""
        ...


def pack_masks(masks: NDArray[np.bool_]) -> NDArray[np.uint64]:
    """Bit-pack binary masks for Hamming distances.

    Parameters
    ----------
    masks : (N, H, W) bool

    Returns
    -------
    (N, ceil(H * W / 64)) uint64
    """
    n = masks.shape[0]
    flat = np.packbits(masks.reshape(n, -1), axis=1)
    pad = (-flat.shape[1]) % 8
    if pad:
        flat = np.concatenate([flat, np.zeros((n, pad), np.uint8)], axis=1)
    return np.ascontiguousarray(flat).view(np.uint64)


def hamming_to_many_reference(packed: NDArray[np.uint64], proto: int, members: NDArray[np.int64]) -> NDArray[np.int64]:
    """Plain-numpy reference of :func:`tracker_service.templates._kernels.hamming_to_many`: the number of
    differing bits between packed mask ``proto`` and each of ``members``, ``(n,) int64``."""
    diff = np.bitwise_xor(packed[np.asarray(members, np.int64)], packed[int(proto)])
    return np.unpackbits(diff.view(np.uint8), axis=1).sum(axis=1, dtype=np.int64)


class PackedMaskDistance:
    """XOR distance (eq. 7 without the window: fraction of differing pixels) on packed masks.

    Parameters
    ----------
    packed : (N, words) uint64
        From :func:`pack_masks`.
    n_pixels : int
        Pixels per mask (the normaliser).
    """

    def __init__(self, packed: NDArray[np.uint64], n_pixels: int) -> None:
        self.packed = np.ascontiguousarray(packed, dtype=np.uint64)
        self.n_pixels = int(n_pixels)

    def distances(self, proto: int, members: NDArray[np.int64]) -> NDArray[np.float64]:
        # numba kernel; reference: hamming_to_many_reference
        counts = hamming_to_many(self.packed, int(proto), np.ascontiguousarray(members, np.int64))
        return counts.astype(np.float64) / self.n_pixels


def _medoid(members: NDArray[np.int64], dist: LevelDistance, sample: int, rng: np.random.Generator) -> int:
    cand = members if len(members) <= sample else rng.choice(members, sample, replace=False)
    ref = members if len(members) <= sample else rng.choice(members, sample, replace=False)
    means = np.array([dist.distances(int(c), ref).mean() for c in cand])
    return int(cand[int(np.argmin(means))])


def cluster_node(members: NDArray[np.int64], dist: LevelDistance, threshold: float, *,
                 medoid_sample: int = 256,
                 max_prototypes: int | None = None, rng: np.random.Generator | None = None
                 ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Algorithm 1, steps 1-3, for one node.

    Parameters
    ----------
    members : (n,) int64
        Template indices in the node.
    dist : LevelDistance
    threshold : float
        ``t_L``.
    medoid_sample : int
        Sample size for the first prototype of large nodes.
    max_prototypes : int, optional
        Safety cap on the number of clusters.
    rng : np.random.Generator, optional

    Returns
    -------
    prototypes : (k,) int64
        Template indices of the prototypes (the first is the medoid).
    assignment : (n,) int64
        Index into ``prototypes`` of each member's cluster.
    """
    members = np.asarray(members, dtype=np.int64)
    if len(members) == 0:
        raise ValueError("empty node")
    g = rng or np.random.default_rng(0)
    protos = [_medoid(members, dist, medoid_sample, g)]
    d0 = dist.distances(protos[0], members)
    nearest_d = d0.copy()
    nearest_k = np.zeros(len(members), np.int64)
    cap = max_prototypes or len(members)
    while len(protos) < cap:
        score = np.where(np.isin(members, protos), -np.inf, nearest_d)
        far = int(np.argmax(score))
        if not score[far] > threshold:  # while d_max > t_L
            break
        protos.append(int(members[far]))
        d = dist.distances(protos[-1], members)
        closer = d < nearest_d
        nearest_d = np.where(closer, d, nearest_d)
        nearest_k = np.where(closer, len(protos) - 1, nearest_k)
    return np.asarray(protos, np.int64), nearest_k


@dataclass(frozen=True)
class TemplateTree:
    """A shape hierarchy over ``N`` templates.

    Levels are numbered 0 (top, coarsest) to ``L - 1`` (leaves). Nodes of a level are stored
    grouped by parent, so the children of node ``i`` of level ``l`` are the contiguous range
    ``child_ptr[l][i]:child_ptr[l][i + 1]`` of level ``l + 1``.

    Attributes
    ----------
    node_template : list of (N_l,) int64
        Prototype template of each node (its pose and silhouette represent the node).
    node_parent : list of (N_l,) int64
        Parent node index in the level above (-1 at the top level).
    child_ptr : list of (N_l + 1,) int64
        CSR pointers into the next level (empty array at the leaf level).
    template_leaf : (N,) int64
        Leaf node of every template.
    thresholds : tuple of float
        ``t_L`` of each level.
    """

    node_template: list[NDArray[np.int64]]
    node_parent: list[NDArray[np.int64]]
    child_ptr: list[NDArray[np.int64]]
    template_leaf: NDArray[np.int64]
    thresholds: tuple[float, ...]

    @property
    def n_levels(self) -> int:
        return len(self.node_template)

    @property
    def level_sizes(self) -> list[int]:
        return [len(t) for t in self.node_template]

    def children(self, level: int, node: int) -> NDArray[np.int64]:
        """Node indices (in ``level + 1``) of the children of ``node``."""
        p = self.child_ptr[level]
        return np.arange(p[node], p[node + 1], dtype=np.int64)


def build_tree(n_templates: int, distances: Sequence[LevelDistance], thresholds: Sequence[float], *,
               rng: np.random.Generator | None = None,
               progress: bool = False) -> TemplateTree:
    """Algorithm 1 over all levels.

    Parameters
    ----------
    n_templates : int
    distances : sequence of LevelDistance
        One per level (e.g. on the 80x60, 160x120 and 320x240 silhouettes).
    thresholds : sequence of float
        ``t_L`` per level, decreasing.
    rng : np.random.Generator, optional
        Sampling of medoid candidates in large nodes.
    progress : bool
        Show a progress bar per level.

    Returns
    -------
    TemplateTree
    """
    if len(distances) != len(thresholds) or not distances:
        raise ValueError("need one distance and one threshold per level")
    g = rng or np.random.default_rng(0)
    groups: list[NDArray[np.int64]] = [np.arange(n_templates, dtype=np.int64)]  # members per parent node
    node_template, node_parent, child_ptr = [], [], []
    owner = np.zeros(n_templates, np.int64)  # node (of the current level) of each template
    for lvl, (dist, t) in enumerate(zip(distances, thresholds, strict=True)):
        protos_l: list[int] = []
        parents_l: list[int] = []
        new_groups: list[NDArray[np.int64]] = []
        ptr = [0]
        it = groups
        if progress:
            from tqdm import tqdm

            it = tqdm(groups, desc=f"Algorithm 1, level {lvl + 1} (t={t:g})", unit="node", leave=False)
        for parent, members in enumerate(it):
            protos, assign = cluster_node(members, dist, t, rng=g)
            for k in range(len(protos)):
                node = len(protos_l)
                sel = members[assign == k]
                owner[sel] = node
                protos_l.append(int(protos[k]))
                parents_l.append(parent if lvl > 0 else -1)
                new_groups.append(sel)
            ptr.append(len(protos_l))
        if lvl > 0:
            child_ptr.append(np.asarray(ptr, np.int64))
        node_template.append(np.asarray(protos_l, np.int64))
        node_parent.append(np.asarray(parents_l, np.int64))
        groups = new_groups
        log.info("level %d: %d nodes (t_L = %g)", lvl + 1, len(protos_l), t)
    child_ptr.append(np.zeros(0, np.int64))
    return TemplateTree(node_template, node_parent, child_ptr, owner.copy(), tuple(float(x) for x in thresholds))
