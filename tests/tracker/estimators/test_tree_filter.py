"""Template database build, on-disk format and the tree-based filter on a small fixture database
(a few real takes, one body model), tracked from capsule silhouettes of another body."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from protocol import POSE_SIZE, fk
from tracker_service.body.family import body_model
from tracker_service.body.raster import render_silhouette
from tracker_service.build.database import heading_of, set_heading
from tracker_service.camera import default_camera
from tracker_service.estimators.base import LeafCost, Observation
from tracker_service.estimators.tree_filter.filter import FilterParams, initial_state, predict_leaves, step
from tracker_service.silhouette.features import preprocess
from tracker_service.silhouette.placement import observed_placement, placement_to_root, silhouette_rows
from tracker_service.templates.database import DatabaseError, load_db


def test_build_statistics_and_tree(small_db) -> None:  # type: ignore[no-untyped-def]
    db, _, motions, stats, _ = small_db
    assert stats["frames"] == sum(int(m.valid.sum()) for m in motions)
    assert 0 < stats["poses"] < stats["frames"]
    sizes = db.tree.level_sizes
    assert sizes[0] < sizes[1] <= sizes[2] <= stats["poses"]
    assert db.leaf_poses.shape == (sizes[2], 60)
    # transition rows are distributions; neighbours start with the leaf itself
    rows = np.diff(db.trans_ptr)
    for leaf in np.flatnonzero(rows)[:50]:
        assert db.trans_p[db.trans_ptr[leaf]: db.trans_ptr[leaf + 1]].sum() == pytest.approx(1.0, abs=1e-5)
    assert np.mean(db.nbr_idx[:, 0] == np.arange(len(db.nbr_idx))) > 0.99
    assert np.all(db.sigma_part > 0)
    assert np.all((db.leaf_visible >= 0) & (db.leaf_visible <= 1))


def test_prior_is_a_distribution_and_follows_the_state(small_db) -> None:  # type: ignore[no-untyped-def]
    db, *_ = small_db
    p0 = predict_leaves(initial_state(), db, FilterParams())
    assert p0.sum() == pytest.approx(1.0) and np.all(p0[~db.leaf_facing] == 0)
    st = initial_state()
    st = type(st)(np.array([5]), np.array([1.0]), st.placement)
    p1 = predict_leaves(st, db, FilterParams())
    assert p1.sum() == pytest.approx(1.0)
    assert p1[5] > 10 * np.median(p1)  # mass stays near the previous leaf
    # eq. 14: occluding every part widens the dynamics
    occ = type(st)(st.leaves, st.weights, st.placement, occluded=np.ones(15, bool))
    p2 = predict_leaves(occ, db, FilterParams())
    assert p2[5] < p1[5]


def test_prior_with_headings_outside_pi_takes_the_numpy_path(small_db) -> None:  # type: ignore[no-untyped-def]
    """A database whose headings are stored past +-pi (not one `build-db` writes) falls back from the
    numba re-acquisition mass to its numpy reference; headings a turn apart give the same prior."""
    db, *_ = small_db
    st = initial_state()
    st = type(st)(np.array([5, 9]), np.array([0.7, 0.3]), st.placement)
    turned = replace(db, leaf_heading=(db.leaf_heading.astype(np.float64) + 2.0 * np.pi).astype(np.float32))
    p_in, p_out = predict_leaves(st, db, FilterParams()), predict_leaves(st, turned, FilterParams())
    assert p_out.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(p_out, p_in, rtol=1e-9, atol=1e-15)


def test_max_heading_keeps_the_prior_on_leaves_facing_the_camera(small_db) -> None:  # type: ignore[no-untyped-def]
    db, *_ = small_db
    lim = float(np.median(np.abs(db.leaf_heading)))  # the small database's takes face the camera: half of them
    prm = FilterParams(max_heading=lim)
    far = np.abs(db.leaf_heading) > lim
    assert far.any() and (~far).any()
    p0 = predict_leaves(initial_state(), db, prm)
    assert p0.sum() == pytest.approx(1.0) and np.all(p0[far] == 0)
    # from a turned leaf, the mass moves to the allowed leaves only (also the re-acquisition share)
    turned = int(np.flatnonzero(far)[0])
    st = initial_state()
    st = type(st)(np.array([turned]), np.array([1.0]), st.placement)
    p1 = predict_leaves(st, db, prm)
    assert p1.sum() == pytest.approx(1.0) and np.all(p1[far] == 0)
    assert predict_leaves(st, db, FilterParams())[far].sum() > 0  # without the limit they keep mass


@pytest.mark.parametrize("screen", [(), (2, 2)])
def test_tracks_a_take_of_another_body(small_db, screen: tuple[int, ...]) -> None:  # type: ignore[no-untyped-def]
    db, body, motions, _, _ = small_db
    assert db.tree.level_sizes[0] > 2 * 2  # the screened search is exercised
    subject = body_model("mLA").body
    cam = default_camera()
    m = motions[0]
    poses = m.poses.copy()
    poses = set_heading(poses, heading_of(poses) - heading_of(poses[:1])[0])
    truth = fk(poses, subject)
    st = initial_state()
    errs, errs_mean = [], []
    for f in range(0, len(poses), 2):
        mask = render_silhouette(truth[f], subject.capsule_radii, cam)
        obs = Observation(preprocess(mask), observed_placement(mask, cam))
        st, est = step(st, db, obs, FilterParams(screen=screen))
        pose = est.pose_map.copy()
        pose[:3] = placement_to_root(est.placement, pose[:3], cam)
        j = fk(pose, body)
        errs.append(np.linalg.norm((j - j[0]) - (truth[f] - truth[f, 0]), axis=1).mean())
        assert np.linalg.norm(pose[:3] - truth[f, 0]) < 0.25
        assert 0.0 <= est.confidence <= 1.0 and len(est.evaluations) == 3
        # the support's own placements and costs, in the order of the carried leaves
        k = len(est.support_cost)
        assert k > 0 and est.support_places.shape == (k, 3) and (est.reinitialised or len(st.leaves) == k)
        assert np.all(np.isfinite(est.support_cost)) and np.all(est.support_places[:, 2] > 0)
        assert np.all(np.abs(est.support_places - est.placement).max(axis=0) < (40.0, 40.0, 0.5))
        mean = est.pose_mean.copy()
        mean[:3] = placement_to_root(est.placement, mean[:3], cam)
        jm = fk(mean, body)
        errs_mean.append(np.linalg.norm((jm - jm[0]) - (truth[f] - truth[f, 0]), axis=1).mean())
    assert np.mean(errs) < 0.08  # the take is in the database: tracked within a few cm
    assert np.mean(errs_mean) < 0.08


def test_a_leap_is_not_taken_for_a_step_back(small_db) -> None:  # type: ignore[no-untyped-def]
    """A body lifted 30 cm off the floor: its feet line reads as ~1 m further away; the height
    hypothesis keeps the depth (and puts the root up)."""
    db, body, motions, _, _ = small_db
    cam = default_camera()
    poses = motions[0].poses.copy()
    poses = set_heading(poses, heading_of(poses) - heading_of(poses[:1])[0])
    for height_hypothesis, tol in ((True, 0.15), (False, None)):
        st = initial_state()
        depth_err, height_err = [], []
        for f in range(0, 50, 2):
            pose = poses[f].copy()
            lift = 0.3 * np.sin(np.pi * (f - 30) / 20) if 30 <= f < 50 else 0.0
            pose[1] += lift
            truth = fk(pose, body)
            mask = render_silhouette(truth, body.capsule_radii, cam)
            obs = Observation(preprocess(mask), observed_placement(mask, cam), silhouette_rows(mask))
            st, est = step(st, db, obs, FilterParams(height_hypothesis=height_hypothesis))
            root = placement_to_root(est.placement, est.pose_map[:3], cam)
            if lift > 0.15:
                depth_err.append(abs(float(cam.depth(root)) - float(cam.depth(truth[0]))))
                height_err.append(abs(root[1] - truth[0, 1]))
        if tol is not None:
            assert max(depth_err) < tol and max(height_err) < 0.1
        else:  # the feet line alone: the failure this hypothesis removes
            assert max(depth_err) > 0.4


def test_screened_grid_evaluates_the_grid_only_for_the_best_nodes(rng: np.random.Generator) -> None:
    from tracker_service.estimators.tree_filter.filter import _offsets, _screened

    n, n_h = 40, 2
    offs = _offsets(8.0, 0.05, 3, 3)  # middle cell (index 4) is the zero offset
    assert np.all(offs[4] == 0)
    table = rng.uniform(0.0, 10.0, (n, n_h, len(offs)))
    table[7, :, 4] = -5.0  # the best node by likelihood
    prior = rng.uniform(0.1, 1.0, n)
    prior[11] = 1e6  # the best node by prior
    calls: list[int] = []

    def neg_log(sel, offsets):  # type: ignore[no-untyped-def]
        rows = np.arange(n)[sel]
        cols = [int(np.flatnonzero(np.all(offs == o, axis=1))[0]) for o in offsets]
        t = table[rows][:, :, cols].reshape(len(rows), -1)
        places = np.broadcast_to(np.asarray(cols, float)[None, None, :, None], (len(rows), n_h, len(cols), 3))
        calls.append(t.size)
        return t, places.reshape(len(rows), -1, 3).copy(), t.size

    cost, place, evals = _screened(neg_log, offs, prior, n_best=3)
    assert cost.shape == (n,) and place.shape == (n, 3) and evals == sum(calls)
    assert calls[0] == n * n_h and 3 * n_h * 9 <= calls[1] <= 6 * n_h * 9  # the centre, then the best nodes' grids
    # what an arg-min over the whole table gives, the cells not evaluated at an infinite cost
    full = np.full((n, n_h, 9), np.inf)
    full[:, :, 4] = table[:, :, 4]
    searched = np.union1d(np.argsort(-(np.log(prior) - table[:, :, 4].min(axis=1)))[:3],
                          np.argsort(table[:, :, 4].min(axis=1))[:3])
    assert 7 in searched and 11 in searched  # the best by each ranking got the whole grid
    full[searched] = table[searched]
    flat = full.reshape(n, -1)
    best = np.argmin(flat, axis=1)
    np.testing.assert_array_equal(cost, flat[np.arange(n), best])
    np.testing.assert_array_equal(place[:, 0], best % 9)  # the cell of each node's best
    assert (place[:, 0] != 4).any()  # some searched node is best off the centre: not vacuous


def test_k_smallest_is_the_sorted_selection(rng: np.random.Generator) -> None:
    """The screen's partition selects the same nodes as a full sort would (distinct costs)."""
    from tracker_service.estimators.tree_filter.filter import _k_smallest

    x = rng.permutation(500).astype(np.float64)
    for k in (1, 48, 96, 499):
        np.testing.assert_array_equal(np.sort(_k_smallest(x, k)), np.sort(np.argsort(x)[:k]))
    np.testing.assert_array_equal(np.sort(_k_smallest(x[:5], 96)), np.arange(5))
    assert len(_k_smallest(x, 0)) == 0 and _k_smallest(x, 3).dtype == np.int64


def test_tempered_weights_hedge_between_modes() -> None:
    from tracker_service.estimators.tree_filter.filter import mean_pose, tempered

    w = np.array([0.9, 0.09, 0.01])
    assert tempered(w, 1.0) is w
    t = tempered(w, 5.0)
    assert t.sum() == pytest.approx(1.0) and np.all(np.diff(t) < 0)  # same order, flatter
    assert t[0] < w[0] and t[2] > w[2]
    # two leaves differing in one joint angle: the tempered mean lies between them, nearer the best
    poses = np.zeros((2, POSE_SIZE))
    poses[1, 3 + 3 * 5] = 1.0  # a rotation of 1 rad about x of one joint
    for temp, lo, hi in ((1.0, 0.0, 0.15), (5.0, 0.3, 0.5)):
        m = mean_pose(poses, tempered(np.array([0.9, 0.1]), temp))
        assert lo < m[3 + 3 * 5] < hi


def test_database_round_trip_and_damage(small_db, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    db, body, _, _, path = small_db
    loaded = load_db(path)
    assert loaded.body.name == body.name
    np.testing.assert_array_equal(loaded.db.leaf_poses, db.leaf_poses)
    np.testing.assert_array_equal(loaded.db.level_runs[2].data, db.level_runs[2].data)
    assert loaded.db.tree.level_sizes == db.tree.level_sizes
    with pytest.raises(DatabaseError, match="build-db"):
        load_db(tmp_path / "missing")
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(path, bad)
    f = bad / "leaf_poses.npy"
    f.write_bytes(f.read_bytes()[:-40])  # truncated
    with pytest.raises(DatabaseError, match=r"truncated|corrupt|shape"):
        load_db(bad)
    shutil.rmtree(bad)
    shutil.copytree(path, bad)
    raw = bytearray((bad / "trans_p.npy").read_bytes())
    raw[-3] ^= 0xFF  # flipped bits
    (bad / "trans_p.npy").write_bytes(bytes(raw))
    with pytest.raises(DatabaseError, match="checksum"):
        load_db(bad)
    man = (bad / "manifest.json").read_text().replace('"version": 2', '"version": 1')
    (bad / "manifest.json").write_text(man)
    with pytest.raises(DatabaseError, match="stale"):
        load_db(bad)


def test_motion_prior_kernel_matches_numpy_reference(small_db, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    from tracker_service.estimators.tree_filter._kernels import leaf_prior_kernel
    from tracker_service.estimators.tree_filter.reference import motion_prior_reference
    db, *_ = small_db
    leaves = rng.choice(db.n_leaves, size=min(48, db.n_leaves), replace=False).astype(np.int64)
    w = rng.random(len(leaves))
    w /= w.sum()
    for occluded_scale in (1.0, 25.0):
        inv_var = 1.0 / (db.sigma_part.astype(np.float64) ** 2 * occluded_scale)
        for hw in (0.0, 0.5):
            fast = np.zeros(db.n_leaves)
            leaf_prior_kernel(leaves, w, np.ascontiguousarray(db.nbr_idx, np.int64), np.ascontiguousarray(db.nbr_dpart),
                              inv_var, db.trans_ptr, db.trans_idx, db.trans_p, hw, fast)
            ref = motion_prior_reference(leaves, w, db, inv_var, hw)
            assert ref.sum() == pytest.approx(1.0)  # the mass of the support is conserved
            np.testing.assert_allclose(fast, ref, rtol=1e-10, atol=1e-15)


def test_the_shoe_cost_reweights_the_leaf_posterior(small_db) -> None:  # type: ignore[no-untyped-def]
    """A shoe ``LeafCost`` in the observation adds ``shoe_weight * (cost - min)`` to the leaves' negative log
    likelihood: a leaf the cue favours gains weight, nothing changes at weight 0 or without a cue."""
    db, _, motions, _, _ = small_db
    cam = default_camera()
    subject = body_model("mLA").body
    mask = render_silhouette(fk(motions[0].poses[10], subject), subject.capsule_radii, cam)
    feats, obs = preprocess(mask), observed_placement(mask, cam)
    st, _ = step(initial_state(), db, Observation(feats, obs), FilterParams())
    base_st, base = step(st, db, Observation(feats, obs), FilterParams())
    seen: list[tuple[np.ndarray, np.ndarray]] = []

    fav = int(base_st.leaves[np.argsort(-base_st.weights)[1]])  # the runner-up

    def favour_last(leaves: np.ndarray, places: np.ndarray) -> np.ndarray:
        seen.append((leaves.copy(), places.copy()))
        return np.where(leaves == fav, 0.0, 200.0)

    for weight, fn in ((0.0, favour_last), (0.02, lambda leaves, places: None)):
        st0, est0 = step(st, db, Observation(feats, obs, leaf_costs=(LeafCost("shoes", weight, fn),)), FilterParams())
        np.testing.assert_array_equal(st0.leaves, base_st.leaves)
        np.testing.assert_array_equal(st0.weights, base_st.weights)
        assert est0.leaf == base.leaf
    assert not seen  # weight 0: the cue is not even computed
    shoes = (LeafCost("shoes", 0.05, favour_last),)
    st1, est1 = step(st, db, Observation(feats, obs, leaf_costs=shoes), FilterParams())
    (leaves, places), = seen
    assert places.shape == (len(leaves), 3) and fav in leaves
    w0 = dict(zip(base_st.leaves.tolist(), base_st.weights.tolist(), strict=True)).get(fav, 0.0)
    w1 = dict(zip(st1.leaves.tolist(), st1.weights.tolist(), strict=True)).get(fav, 0.0)
    assert w1 > w0 and w1 > 0.5 and est1.leaf == fav  # exp(-0.05 * 200): the others lose a factor e^10


def test_feet_cut_off_bound_the_depth(small_db) -> None:  # type: ignore[no-untyped-def]
    """Without a feet line (cut off by the border) the observation's ``min_scale`` keeps the
    estimate at least that near, in the published placement and in the next state."""
    db, body, motions, _, _ = small_db
    cam = default_camera()
    poses = set_heading(motions[0].poses.copy(), heading_of(motions[0].poses) - heading_of(motions[0].poses[:1])[0])
    mask = render_silhouette(fk(poses[0], body), body.capsule_radii, cam)
    st, _ = step(initial_state(), db, Observation(preprocess(mask), observed_placement(mask, cam)), FilterParams())
    bound = float(st.placement[2]) * 1.08
    _, free = step(st, db, Observation(preprocess(mask)), FilterParams())
    assert free.placement[2] < bound  # the silhouette alone places it farther than the bound
    st2, est = step(st, db, Observation(preprocess(mask), min_scale=bound), FilterParams())
    assert est.placement[2] >= bound and st2.placement[2] >= bound
