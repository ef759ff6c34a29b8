from pathlib import Path

import numpy as np
import pytest

from protocol.formats.load import load_motion
from protocol.formats.mocap_data import IndexEntry
from protocol.rotations import matrix_to_rotvec, rotvec_to_matrix
from protocol.skeleton import POSE_SIZE, standing_pose
from tracker_service.templates.pruning import pose_features, prune_poses, prune_poses_reference


def _jittered(rng: np.random.Generator, n: int, deg: float) -> np.ndarray:
    base = standing_pose()
    p = np.repeat(base[None], n, axis=0)
    p[:, 6:] += rng.normal(0, np.radians(deg), (n, POSE_SIZE - 6))
    return p


def test_kernel_equals_numpy_reference_on_random_poses(rng: np.random.Generator) -> None:
    p = _jittered(rng, 1500, 1.0)
    got = prune_poses(p, 5.0).kept
    np.testing.assert_array_equal(got, prune_poses_reference(p, 5.0))
    assert 1 < len(got) < 1500


def test_kernel_equals_reference_on_real_frames(mocap_dir: Path) -> None:
    m = load_motion(mocap_dir / "bandai/dataset-1_kick_normal_001.bvh")
    got = prune_poses(m.poses, 5.0).kept
    np.testing.assert_array_equal(got, prune_poses_reference(m.poses, 5.0))


def test_pruning_semantics(rng: np.random.Generator) -> None:
    p = _jittered(rng, 400, 6.0)
    kept = prune_poses(p, 5.0).kept
    q = pose_features(p).astype(np.float64)
    c = np.cos(np.radians(5.0) / 2)
    kset = set(kept.tolist())
    for i in range(len(p)):
        d = np.abs(np.einsum("mkc,kc->mk", q[kept], q[i]))
        close = np.all(d > c, axis=1)  # kept poses within 5 deg in every joint
        if i in kset:
            assert close.sum() == 1  # only itself
        else:
            assert close[kept < i].any()  # an earlier kept pose covers it
    # the cover map points at a kept pose within the threshold
    res = prune_poses(p, 5.0)
    for i in range(len(p)):
        d = np.abs(np.einsum("kc,kc->k", q[res.kept[res.cover[i]]], q[i]))
        assert np.all(d > c - 1e-6)


def test_heading_is_ignored_but_tilt_is_not() -> None:
    a = standing_pose()
    turned = a.copy()
    turned[3:6] = matrix_to_rotvec(rotvec_to_matrix([0, 2.0, 0]))
    tilted = a.copy()
    tilted[3:6] = [0.2, 0, 0]
    assert prune_poses(np.stack([a, turned]), 5.0).n_kept == 1
    assert prune_poses(np.stack([a, tilted]), 5.0).n_kept == 2


def test_duplicates_collapse_and_threshold_orders_counts(rng: np.random.Generator) -> None:
    p = _jittered(rng, 300, 8.0)
    assert prune_poses(np.concatenate([p, p]), 5.0).n_kept == prune_poses(p, 5.0).n_kept
    n = [prune_poses(p, t).n_kept for t in (2.0, 5.0, 10.0)]
    assert n[0] >= n[1] >= n[2]
    with pytest.raises(ValueError):
        prune_poses(p, 0.0)


def test_shared_folder_pruning_counts(mocap_index: list[IndexEntry], mocap_dir: Path) -> None:
    motions = [load_motion(mocap_dir / e.path) for e in mocap_index if e.path.startswith("cmu/")]
    poses = np.concatenate([m.poses[m.valid] for m in motions])
    res = prune_poses(poses, 5.0)
    # 120 Hz CMU takes are highly redundant at 5 degrees
    assert 0.05 * len(poses) < res.n_kept < 0.8 * len(poses)
