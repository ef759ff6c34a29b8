import numpy as np
import pytest

from tracker_service.templates._kernels import hamming_to_many
from tracker_service.templates.tree import (
    PackedMaskDistance,
    build_tree,
    cluster_node,
    hamming_to_many_reference,
    pack_masks,
)


class EuclidDistance:
    """Reference distance on points, to test Algorithm 1 independently of silhouettes."""

    def __init__(self, x: np.ndarray) -> None:
        self.x = x

    def distances(self, proto: int, members: np.ndarray) -> np.ndarray:
        return np.linalg.norm(self.x[members] - self.x[proto], axis=1)


def test_hamming_kernel_matches_numpy(rng: np.random.Generator) -> None:
    masks = rng.random((50, 60, 80)) > 0.5
    d = PackedMaskDistance(pack_masks(masks), 60 * 80)
    got = d.distances(3, np.arange(50))
    want = (masks != masks[3]).reshape(50, -1).mean(axis=1)
    np.testing.assert_allclose(got, want)


@pytest.mark.parametrize("shape", [(60, 80), (7, 9), (8, 8)])  # a padded last word, less than one word, exact
def test_hamming_kernel_equals_its_reference(rng: np.random.Generator, shape: tuple[int, int]) -> None:
    masks = rng.random((40, *shape)) > rng.uniform(0.05, 0.95, (40, 1, 1))
    packed = pack_masks(masks)
    for proto in (0, 17, 39):
        members = np.concatenate([rng.permutation(40), [proto, proto]]).astype(np.int64)  # itself, repeated
        got = hamming_to_many(packed, proto, members)
        want = hamming_to_many_reference(packed, proto, members)
        assert got.dtype == want.dtype == np.int64
        np.testing.assert_array_equal(got, want)
        np.testing.assert_array_equal(want, (masks[members] != masks[proto]).reshape(len(members), -1).sum(axis=1))
    assert len(hamming_to_many(packed, 3, np.zeros(0, np.int64))) == 0


def test_cluster_radius_is_bounded_and_first_is_medoid(rng: np.random.Generator) -> None:
    x = np.concatenate([rng.normal(c, 0.3, (60, 2)) for c in ((0, 0), (5, 0), (0, 5), (5, 5))])
    dist = EuclidDistance(x)
    members = np.arange(len(x))
    protos, assign = cluster_node(members, dist, threshold=1.5, rng=rng)
    assert 4 <= len(protos) <= 12
    radius = np.linalg.norm(x - x[protos[assign]], axis=1)
    assert radius.max() <= 1.5 + 1e-12  # every member within t_L of its prototype
    # each member goes to its nearest prototype
    d_all = np.linalg.norm(x[:, None] - x[protos][None], axis=2)
    np.testing.assert_array_equal(assign, np.argmin(d_all, axis=1))
    # the first prototype is the exact medoid for small nodes
    means = np.linalg.norm(x[:, None] - x[None], axis=2).mean(axis=1)
    assert protos[0] == np.argmin(means)


def test_max_prototypes_caps_a_node(rng: np.random.Generator) -> None:
    x = rng.normal(0, 1, (200, 2))
    protos, assign = cluster_node(np.arange(200), EuclidDistance(x), 0.01, max_prototypes=7, rng=rng)
    assert len(protos) == 7 and assign.max() == 6


def test_three_level_tree_structure(rng: np.random.Generator) -> None:
    x = rng.uniform(0, 10, (600, 2))
    dist = EuclidDistance(x)
    tree = build_tree(len(x), [dist, dist, dist], [4.0, 1.5, 0.5], rng=rng)
    sizes = tree.level_sizes
    assert sizes[0] < sizes[1] < sizes[2] <= 600
    # CSR children cover every node of the next level exactly once, in order
    for lvl in range(2):
        ptr = tree.child_ptr[lvl]
        assert ptr[0] == 0 and ptr[-1] == sizes[lvl + 1] and np.all(np.diff(ptr) >= 1)
        for node in range(sizes[lvl]):
            assert np.all(tree.node_parent[lvl + 1][tree.children(lvl, node)] == node)
    # every template's leaf is within t_3 of the leaf prototype, and leaves nest in their ancestors
    leaf_proto = tree.node_template[2][tree.template_leaf]
    assert np.linalg.norm(x - x[leaf_proto], axis=1).max() <= 0.5 + 1e-12
    assert np.all(np.isin(tree.node_template[0], np.arange(600)))


def test_bad_arguments() -> None:
    with pytest.raises(ValueError):
        build_tree(3, [], [])
    with pytest.raises(ValueError):
        cluster_node(np.zeros(0, np.int64), EuclidDistance(np.zeros((1, 2))), 1.0)


def test_the_leaf_joint_tables_are_the_same_in_chunks(small_db) -> None:  # type: ignore[no-untyped-def]
    """The load derives the leaves' image points and camera-axis joints a chunk at a time (a lower
    memory peak): the same arrays as all at once."""
    import numpy as np

    from protocol import fk
    from tracker_service.cues.appearance import camera_joints
    from tracker_service.cues.skin import leaf_joint_points
    from tracker_service.templates.database import _leaf_joint_tables, load_db

    loaded = load_db(small_db[4])
    poses, body, cam = loaded.db.leaf_poses, loaded.body, loaded.camera
    j = fk(np.asarray(poses, np.float64), body)
    for chunk in (7, 4096):
        pts, j3 = _leaf_joint_tables(poses, body, cam, chunk=chunk)
        np.testing.assert_array_equal(pts, leaf_joint_points(j, cam))
        np.testing.assert_array_equal(j3, camera_joints(j, cam, body.height))
    np.testing.assert_array_equal(loaded.db.leaf_points, pts)
    empty = _leaf_joint_tables(poses[:0], body, cam)
    assert empty[0].shape == (0, *pts.shape[1:]) and empty[1].shape == (0, *j3.shape[1:])
