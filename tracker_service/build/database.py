"""Building the template database (Okada & Stenger §2, §2.1): poses from the recordings (and
gesture scripts), pruned at 5 degrees, headings augmented, rendered as run-length silhouettes on
the image pyramid for one body model, clustered into a 3-level tree by Algorithm 1, with leaf
transition histograms from the recordings' frame order and pose-space neighbours for eq. 13.

Train/test split (by take): a recording is *held out* of the database -- reserved for evaluation --
when its row number in ``INDEX.tsv`` (0-based, header excluded) is divisible by 5
(:func:`is_held_out`); 51 of the 252 takes.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from protocol.formats.load import load_motion
from protocol.formats.mocap_data import IndexEntry, index_entries, mocap_root
from protocol.kinematics import fk
from protocol.motion import Motion
from protocol.rotations import matrix_to_quat, matrix_to_rotvec, rotvec_to_matrix
from protocol.skeleton import JOINT_INDEX, N_PARTS, PARTS, POSE_SIZE, ROT_JOINTS, Body
from tracker_service.body.raster import render_labels_with_areas, render_silhouettes, silhouette_runs_batch
from tracker_service.camera import Camera, default_camera
from tracker_service.cues.appearance import camera_joints
from tracker_service.cues.skin import leaf_joint_points
from tracker_service.estimators.tree_filter.filter import FilterDB
from tracker_service.silhouette.distance import RunSet
from tracker_service.silhouette.features import LEVEL_SIZES
from tracker_service.silhouette.placement import placement_columns, placement_rows
from tracker_service.templates.pruning import prune_poses
from tracker_service.templates.tree import PackedMaskDistance, build_tree, pack_masks

__all__ = ["DbBuildConfig", "build_filter_db", "heading_of", "is_held_out", "set_heading", "training_motions"]

log = logging.getLogger(__name__)

#: Which body part each rotating joint moves (eq. 14 groups joint parameters by body part).
JOINT_PART: dict[str, str] = {
    "pelvis": "pelvis", "spine": "torso", "chest": "torso", "neck": "head", "head": "head",
    "l_clavicle": "l_upper_arm", "l_shoulder": "l_upper_arm", "l_elbow": "l_forearm", "l_wrist": "l_hand",
    "r_clavicle": "r_upper_arm", "r_shoulder": "r_upper_arm", "r_elbow": "r_forearm", "r_wrist": "r_hand",
    "l_hip": "l_thigh", "l_knee": "l_shin", "l_ankle": "l_foot",
    "r_hip": "r_thigh", "r_knee": "r_shin", "r_ankle": "r_foot",
}
_JOINT_PART_IDX = np.array([PARTS.index(JOINT_PART[j]) for j in ROT_JOINTS])


@dataclass(frozen=True)
class DbBuildConfig:
    """Parameters of the database build (defaults are the documented product defaults).

    Attributes
    ----------
    threshold_deg : float
        §2.1 pruning threshold.
    yaw_offsets_deg : tuple of float
        Heading augmentation added to every (take-centred) pose.
    level_thresholds : tuple of float
        ``t_L`` of Algorithm 1 per level, as the XOR fraction of the level's pixels.
    fps : float
        Recordings are resampled to this rate before pruning and histogramming.
    neighbours : int
        Pose-space neighbours per leaf for eq. 13.
    max_poses : int, optional
        Cap on the pruned poses (for quick builds and tests).
    """

    threshold_deg: float = 5.0
    yaw_offsets_deg: tuple[float, ...] = (-35.0, 0.0, 35.0)
    level_thresholds: tuple[float, ...] = (0.025, 0.010, 0.005)
    fps: float = 30.0
    neighbours: int = 24
    max_poses: int | None = None


def is_held_out(row: int) -> bool:
    """True for recordings reserved for evaluation (every fifth row of INDEX.tsv)."""
    return row % 5 == 0


def training_motions(body: Body, entries: Sequence[IndexEntry] | None = None, fps: float = 30.0,
                     scripts: Sequence[Path] = (), progress: bool = False) -> list[Motion]:
    """The database's source motions: every non-held-out recording and the given scripts."""
    root = mocap_root()
    ents = list(entries) if entries is not None else [e for i, e in enumerate(index_entries()) if not is_held_out(i)]
    paths = [root / e.path for e in ents] + list(scripts)
    it = paths
    if progress:
        from tqdm import tqdm

        it = tqdm(paths, desc="read + retarget", unit="take", leave=False)
    return [load_motion(p, body=body, fps=fps) for p in it]


def heading_of(poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N,) yaw (radians) of each pose's root: the direction of the pelvis +Z on the floor."""
    r = rotvec_to_matrix(poses[:, 3:6])
    fwd = r[:, :, 2]
    return np.arctan2(fwd[:, 0], fwd[:, 2])


def set_heading(poses: NDArray[np.float64], yaw: NDArray[np.float64]) -> NDArray[np.float64]:
    """Poses turned about the vertical so that their heading is ``yaw`` (root x, z set to 0)."""
    out = np.array(poses, dtype=np.float64, copy=True)
    delta = np.asarray(yaw) - heading_of(out)
    c, s = np.cos(delta), np.sin(delta)
    ry = np.zeros((len(out), 3, 3))
    ry[:, 0, 0], ry[:, 0, 2], ry[:, 1, 1], ry[:, 2, 0], ry[:, 2, 2] = c, s, 1, -s, c
    out[:, 3:6] = matrix_to_rotvec(ry @ rotvec_to_matrix(out[:, 3:6]))
    out[:, 0] = 0.0
    out[:, 2] = 0.0
    return out


def _centred_takes(motions: Sequence[Motion], yaw_offsets: Sequence[float]
                   ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """All valid frames, each take turned so its mean heading faces the camera, times the yaw
    offsets. Returns poses (N, P) and a "the next row is this frame's successor" flag (N,)."""
    poses, succ = [], []
    for m in motions:
        p = m.poses
        h = heading_of(p)
        mean = np.arctan2(np.sin(h).mean(), np.cos(h).mean())
        for off in yaw_offsets:
            q = set_heading(p, h - mean + np.radians(off))
            assert m.valid is not None
            ok = m.valid
            poses.append(q[ok])
            nxt = np.zeros(len(p), bool)
            nxt[:-1] = ok[:-1] & ok[1:]
            succ.append(nxt[ok])
    return np.concatenate(poses), np.concatenate(succ)


def _level_cameras(camera: Camera) -> list[Camera]:
    return [camera.scaled(w / camera.width) for w, _ in LEVEL_SIZES]


def _render_runs(joints: NDArray[np.float64], radii: NDArray[np.float64], cam: Camera, chunk: int = 4096
                 ) -> RunSet:
    datas, ptrs, base = [], [np.zeros(1, np.int64)], 0
    for i in range(0, len(joints), chunk):
        d, p = silhouette_runs_batch(joints[i: i + chunk], radii, cam)
        datas.append(d)
        ptrs.append(p[1:] + base)
        base += len(d)
    return RunSet(data=np.concatenate(datas), ptr=np.concatenate(ptrs))


class _LevelDistance:
    """Packed-mask XOR distance at one level; masks are rendered on demand for the node being
    clustered (all templates at once for the eager, coarsest level)."""

    def __init__(self, joints: NDArray[np.float64], radii: NDArray[np.float64], cam: Camera, eager: bool) -> None:
        self.joints, self.radii, self.cam = joints, radii, cam
        self.n_pixels = cam.width * cam.height
        self.ids = np.zeros(0, np.int64)
        self.packed = np.zeros((0, 1), np.uint64)
        if eager:
            self._pack(np.arange(len(joints), dtype=np.int64))

    def _pack(self, ids: NDArray[np.int64]) -> None:
        chunks = [pack_masks(render_silhouettes(self.joints[ids[i: i + 2048]], self.radii, self.cam))
                  for i in range(0, len(ids), 2048)]
        self.packed = np.concatenate(chunks)
        self.ids = ids

    def _local(self, items: NDArray[np.int64]) -> NDArray[np.int64] | None:
        pos = np.searchsorted(self.ids, items)
        pos = np.minimum(pos, len(self.ids) - 1) if len(self.ids) else pos
        if len(self.ids) == 0 or not np.array_equal(self.ids[pos], items):
            return None
        return pos.astype(np.int64)

    def distances(self, proto: int, members: NDArray[np.int64]) -> NDArray[np.float64]:
        local = self._local(members)
        p = self._local(np.array([proto], np.int64))
        if local is None or p is None:
            self._pack(np.unique(np.concatenate([members, [proto]])).astype(np.int64))
            local = self._local(members)
            p = self._local(np.array([proto], np.int64))
        assert local is not None and p is not None
        return PackedMaskDistance(self.packed, self.n_pixels).distances(int(p[0]), local)


def _neighbours(leaf_poses: NDArray[np.float64], k: int, pca_dims: int = 16
                ) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
    """k nearest leaves in joint-rotation space and their per-part squared angle differences.

    Candidates come from a KD-tree on a PCA projection of the per-joint quaternions (a KD-tree
    in all 76 dimensions is no faster than brute force), then are ranked by the exact distance.
    """
    n = len(leaf_poses)
    q = matrix_to_quat(rotvec_to_matrix(leaf_poses[:, 3:].reshape(n, -1, 3)))  # (n, R, 4), w >= 0
    flat = q.reshape(n, -1)
    centred = flat - flat.mean(axis=0)
    _, _, vt = np.linalg.svd(centred[:: max(1, n // 5000)], full_matrices=False)
    proj = centred @ vt[: min(pca_dims, vt.shape[0])].T
    kk = min(k, n)
    kc = min(2 * kk, n)
    _, cand = cKDTree(proj).query(proj, k=kc)
    cand = np.asarray(cand, np.int64).reshape(n, kc)
    dots = np.abs(np.einsum("nrc,nkrc->nkr", q, q[cand])).clip(0, 1)
    ang2 = (2 * np.arccos(dots)) ** 2  # (n, kc, R)
    order = np.argsort(ang2.sum(axis=2), axis=1, kind="stable")[:, :kk]
    idx = np.take_along_axis(cand, order, axis=1)
    ang2 = np.take_along_axis(ang2, order[:, :, None], axis=1)
    dpart = np.zeros((n, kk, N_PARTS), np.float32)
    for r, part in enumerate(_JOINT_PART_IDX):
        dpart[:, :, part] += ang2[:, :, r]
    return idx, dpart


def _sigma_part(poses: NDArray[np.float64], succ: NDArray[np.bool_]) -> NDArray[np.float32]:
    """RMS per-frame joint-angle change of each part over the training motions (eq. 13's sigma_j)."""
    n = len(poses)
    q = matrix_to_quat(rotvec_to_matrix(poses[:, 3:].reshape(n, -1, 3)))
    i = np.flatnonzero(succ)
    ang2 = (2 * np.arccos(np.abs(np.einsum("nrc,nrc->nr", q[i], q[i + 1])).clip(0, 1))) ** 2
    out = np.zeros(N_PARTS)
    for r, part in enumerate(_JOINT_PART_IDX):
        out[part] += ang2[:, r].mean()
    return np.sqrt(np.maximum(out, np.radians(1.0) ** 2)).astype(np.float32)


def build_filter_db(motions: Sequence[Motion], body: Body, camera: Camera | None = None,
                    config: DbBuildConfig = DbBuildConfig(), rng: np.random.Generator | None = None,
                    progress: bool = False) -> tuple[FilterDB, dict[str, float]]:
    """Build the filter's database for one body model.

    Parameters
    ----------
    motions : sequence of Motion
        Source motions at ``config.fps`` (see :func:`training_motions`).
    body : Body
        The body model the templates are rendered with.
    camera : Camera, optional
        Full-resolution camera (default :func:`tracker_service.camera.default_camera`).
    config : DbBuildConfig
    rng : np.random.Generator, optional
    progress : bool

    Returns
    -------
    db : FilterDB
    stats : dict
        Counts and timings of every stage.
    """
    g = rng or np.random.default_rng(0)
    cam = camera or default_camera()
    stats: dict[str, float] = {}
    t0 = time.perf_counter()
    poses, succ = _centred_takes(motions, config.yaw_offsets_deg)
    stats["frames"] = len(poses)
    pr = prune_poses(poses, config.threshold_deg, compare_heading=True)
    kept = pr.kept if config.max_poses is None else pr.kept[: config.max_poses]
    stats["poses"] = len(kept)
    stats["prune_s"] = pr.seconds
    tpl = poses[kept]
    joints = fk(tpl, body)
    radii = body.capsule_radii
    cams = _level_cameras(cam)
    t1 = time.perf_counter()
    runs = [_render_runs(joints, radii, c) for c in cams]
    stats["render_s"] = time.perf_counter() - t1
    t1 = time.perf_counter()
    dists = [_LevelDistance(joints, radii, c, eager=(lvl == 0)) for lvl, c in enumerate(cams)]
    tree = build_tree(len(tpl), dists, config.level_thresholds, rng=g, progress=progress)
    stats["cluster_s"] = time.perf_counter() - t1
    for lvl, size in enumerate(tree.level_sizes):
        stats[f"level{lvl + 1}_nodes"] = size
    leaf_tpl = tree.node_template[-1]
    nl = len(leaf_tpl)
    # ancestors of each leaf
    anc = np.zeros((tree.n_levels, nl), np.int64)
    anc[-1] = np.arange(nl)
    for lvl in range(tree.n_levels - 1, 0, -1):
        anc[lvl - 1] = tree.node_parent[lvl][anc[lvl]]
    # transitions: frame -> covering pose -> its leaf; histogram successive frames of a take
    limit = len(kept)
    frame_tpl = pr.cover
    frame_leaf = np.where(frame_tpl < limit, tree.template_leaf[np.minimum(frame_tpl, limit - 1)], -1)
    i = np.flatnonzero(succ[:-1] & (frame_leaf[:-1] >= 0) & (frame_leaf[1:] >= 0))
    a, b = frame_leaf[i], frame_leaf[i + 1]
    key = a * nl + b
    uniq, cnt = np.unique(key, return_counts=True)
    src, dst = uniq // nl, uniq % nl
    trans_ptr = np.zeros(nl + 1, np.int64)
    np.add.at(trans_ptr, src + 1, 1)
    trans_ptr = np.cumsum(trans_ptr)
    row_sum = np.bincount(src, weights=cnt, minlength=nl)
    trans_p = (cnt / row_sum[src]).astype(np.float32)
    stats["transitions"] = len(uniq)
    # leaf data
    leaf_poses = tpl[leaf_tpl]
    leaf_joints = joints[leaf_tpl]  # the leaves' joints, already posed
    vis = np.zeros((nl, N_PARTS), np.float32)
    for k, j in enumerate(leaf_joints):
        _, counts, areas = render_labels_with_areas(j, radii, cam)
        vis[k] = counts / np.maximum(areas, 1)
    nbr_idx, nbr_dpart = _neighbours(leaf_poses, config.neighbours)
    level_runs = tuple(
        RunSet([runs[lvl].runs(int(t)) for t in tree.node_template[lvl]]) for lvl in range(tree.n_levels)
    )
    level_scale = tuple(c.width / cam.width for c in cams)
    level_column, ref_column = placement_columns(level_runs, level_scale, cam)
    level_bottom, level_top, ref_bottom = placement_rows(level_runs, level_scale, cam)
    db = FilterDB(
        tree=tree, level_runs=level_runs, level_scale=level_scale,
        center=(cam.cx, cam.cy), leaf_poses=leaf_poses.astype(np.float32), leaf_visible=vis,
        leaf_anc=anc, leaf_heading=heading_of(leaf_poses).astype(np.float32), trans_ptr=trans_ptr,
        trans_idx=dst.astype(np.int64), trans_p=trans_p,
        nbr_idx=nbr_idx, nbr_dpart=nbr_dpart, sigma_part=_sigma_part(poses, succ),
        level_column=level_column, ref_column=ref_column,
        level_bottom=level_bottom, level_top=level_top, ref_bottom=ref_bottom,
        leaf_points=leaf_joint_points(leaf_joints, cam),
        leaf_joints3d=camera_joints(leaf_joints, cam, body.height),
    )
    stats["total_s"] = time.perf_counter() - t0
    log.info("database: %s", stats)
    assert POSE_SIZE == leaf_poses.shape[1] and JOINT_INDEX["pelvis"] == 0
    return db, stats
