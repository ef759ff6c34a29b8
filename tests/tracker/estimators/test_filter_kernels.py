"""The tree filter's bookkeeping kernels (tracker_service.estimators.tree_filter._kernels) against their numpy
references (tracker_service.estimators.tree_filter.reference): bit for bit, the mean pose to 1e-12."""

from dataclasses import replace

import numpy as np
import pytest

from protocol import POSE_SIZE
from tracker_service.estimators.tree_filter._kernels import (
    expand_kernel,
    heading_mass_kernel,
    level_cost_kernel,
    level_priors_kernel,
    mean_pose_kernel,
)
from tracker_service.estimators.tree_filter.filter import _node_predictions
from tracker_service.estimators.tree_filter.model import FilterParams
from tracker_service.estimators.tree_filter.reference import (
    expand_reference,
    heading_mass_reference,
    level_cost_reference,
    level_priors_reference,
    mean_pose_reference,
    node_predictions_reference,
)


def test_heading_mass_kernel_matches_reference(rng: np.random.Generator) -> None:
    n = 5000
    heading = rng.uniform(-np.pi, np.pi, n).astype(np.float32)
    heading[:6] = np.float32([np.pi, -np.pi, 0.0, -0.0, np.float32(np.pi) - 1e-6, 1.0])  # edges of the range
    for mean in (0.0, 0.3, -2.9, np.pi, -np.pi, float(heading[0])):
        for frac_allowed in (1.0, 0.5, 0.0):
            allowed = rng.random(n) < frac_allowed
            prior = rng.random(n) * (rng.random(n) < 0.7)
            fast = prior.copy()
            assert heading_mass_kernel(fast, heading, allowed, mean, 1.0, 0.05)
            np.testing.assert_array_equal(fast, heading_mass_reference(prior, heading, allowed, mean, 1.0, 0.05))


def test_heading_mass_kernel_leaves_headings_out_of_range_to_the_reference() -> None:
    prior = np.ones(3)
    assert not heading_mass_kernel(prior, np.float32([0.0, 20.0, 1.0]), np.ones(3, bool), 0.0, 1.0, 0.05)
    np.testing.assert_array_equal(prior, 1.0)  # untouched


def test_level_priors_kernel_matches_bincount(rng: np.random.Generator) -> None:
    n_leaves = 3000
    sizes = [40, 700, n_leaves]
    anc = np.stack([np.sort(rng.integers(0, sizes[0], n_leaves)), rng.integers(0, sizes[1], n_leaves),
                    np.arange(n_leaves)]).astype(np.int64)
    prior = rng.random(n_leaves) ** 4
    prior /= prior.sum()
    bounds = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    out = np.zeros(int(bounds[-1]))
    level_priors_kernel(anc, prior, bounds, out)
    for lvl, ref in enumerate(level_priors_reference(anc, prior, sizes)):
        np.testing.assert_array_equal(out[bounds[lvl]: bounds[lvl + 1]], ref)


@pytest.mark.parametrize("nan_rows", [False, True])
def test_node_predictions_kernel_matches_reference(small_db, rng: np.random.Generator,  # type: ignore[no-untyped-def]
                                                   nan_rows: bool) -> None:
    db, *_ = small_db
    if nan_rows:  # templates without rows or columns at a level
        def holes(a: np.ndarray) -> np.ndarray:
            a = a.copy()
            a[rng.random(len(a)) < 0.2] = np.nan
            return a
        db = replace(db, level_bottom=tuple(holes(b) for b in db.level_bottom),
                     level_top=tuple(holes(t) for t in db.level_top),
                     level_column=tuple(holes(c) for c in db.level_column))
    for lvl in range(db.tree.n_levels):
        nodes = rng.choice(db.tree.level_sizes[lvl], size=min(200, db.tree.level_sizes[lvl]), replace=False)
        pred = np.array([rng.normal(0, 10), rng.normal(0, 5), rng.uniform(0.7, 1.3)])
        obs = np.array([rng.normal(0, 10), rng.normal(0, 5), rng.uniform(0.7, 1.3)])
        rows = np.array([rng.uniform(20, 60), rng.uniform(150, 230)])
        for w, o, r, rng_s in ((0.7, obs, rows, (0.9, 1.1)), (1.0, obs, None, (0.0, np.inf)),
                               (0.0, None, rows, (0.8, 1.2)), (0.0, None, None, (0.0, np.inf)),
                               (0.7, obs, rows, (1.5, 2.0))):
            got = _node_predictions(db, lvl, nodes, pred, w, o, r, rng_s)
            np.testing.assert_array_equal(got, node_predictions_reference(db, lvl, nodes, pred, w, o, r, rng_s))
    bare = replace(db, level_bottom=(), level_top=(), level_column=())  # a database without them
    got = _node_predictions(bare, 0, np.arange(5), pred, 0.7, obs, rows, (0.9, 1.1))
    np.testing.assert_array_equal(got, node_predictions_reference(bare, 0, np.arange(5), pred, 0.7, obs, rows,
                                                                  (0.9, 1.1)))


@pytest.mark.parametrize("n_h", [1, 2])
def test_level_cost_kernel_matches_reference(rng: np.random.Generator, n_h: int) -> None:
    params = FilterParams()
    n, g = 300, n_h * 9
    d = rng.uniform(0.0, 0.2, (n, g))
    places = np.stack([rng.normal(0, 10, (n, g)), rng.normal(0, 5, (n, g)), rng.uniform(0.8, 1.2, (n, g))], -1)
    hyps = np.stack([rng.normal(0, 10, (n, n_h)), rng.normal(0, 5, (n, n_h)), rng.uniform(0.8, 1.2, (n, n_h))], -1)
    places[0, 0] = hyps[0, 0]  # the prediction itself: zero placement cost
    got = level_cost_kernel(d, places, hyps, 0.01, params.placement_sigma_px, params.placement_sigma_scale, 0.97,
                            params.airborne_cost)
    np.testing.assert_array_equal(got, level_cost_reference(d, places, hyps, 0.01, params, 0.97))


def test_expand_kernel_matches_reference(small_db, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    db, *_ = small_db
    tree = db.tree
    for use_column in (True, False):
        dbx = db if use_column else replace(db, level_column=())
        for lvl in range(tree.n_levels - 1):
            nodes = rng.permutation(tree.level_sizes[lvl])[: max(tree.level_sizes[lvl] // 2, 1)].astype(np.int64)
            keep = np.unique(rng.choice(len(nodes), size=min(30, len(nodes)))).astype(np.int64)
            place = np.stack([rng.normal(0, 10, len(nodes)), rng.normal(0, 5, len(nodes)),
                              rng.uniform(0.8, 1.2, len(nodes))], -1)
            cols = dbx.level_column
            kids, centers = expand_kernel(tree.child_ptr[lvl], nodes, keep, place,
                                          cols[lvl] if cols else np.zeros(0), cols[lvl + 1] if cols else np.zeros(0),
                                          bool(cols))
            ref_kids, ref_centers = expand_reference(dbx, lvl, nodes, keep, place)
            np.testing.assert_array_equal(kids, ref_kids)
            np.testing.assert_array_equal(centers, ref_centers)


def test_mean_pose_kernel_matches_reference(rng: np.random.Generator) -> None:
    n = 48
    poses = np.zeros((n, POSE_SIZE))
    poses[:, :3] = rng.normal(0, 1, (n, 3))
    rv = rng.normal(0, 1, (n, POSE_SIZE - 3))
    poses[:, 3:] = rv
    axis = rv[:, :3] / np.linalg.norm(rv[:, :3], axis=1, keepdims=True)
    poses[: n // 2, 3:6] = axis[: n // 2] * np.pi * rng.uniform(0.999, 1.0, (n // 2, 1))  # near a half turn
    poses[:4, 6:9] = rng.normal(0, 1e-9, (4, 3))  # near the identity
    for w in (rng.random(n), np.eye(n)[0]):
        w = w / w.sum()
        np.testing.assert_allclose(mean_pose_kernel(poses, w), mean_pose_reference(poses, w), rtol=0, atol=1e-12)
