"""The particle-filter baselines (issue 40): the pose likelihood, the resampling strategies,
Condensation and the cardbox paper's hierarchical particle filter (DRS / SRS), each tracking a
short arm-raise take rendered from capsule silhouettes."""

from __future__ import annotations

import numpy as np
import pytest

from protocol import fk
from protocol.skeleton import standing_pose
from tracker_service.body.family import body_model
from tracker_service.body.raster import render_silhouette
from tracker_service.build.database import heading_of, set_heading
from tracker_service.camera import default_camera
from tracker_service.estimators.base import Observation
from tracker_service.estimators.condensation import Condensation, CondensationParams
from tracker_service.estimators.hierarchical_pf import HierarchicalPF, HPFParams
from tracker_service.estimators.likelihood import (
    PoseLikelihood,
    placement_of_root,
    pose_distances,
    pose_distances_reference,
)
from tracker_service.estimators.particles import world_pose
from tracker_service.estimators.resampling import (
    deterministic_resample,
    multinomial_resample,
    normalised_weights,
    stratified_resample,
)
from tracker_service.silhouette.distance import dense_distance
from tracker_service.silhouette.features import LevelFeatures, preprocess, pyramid
from tracker_service.silhouette.placement import observed_placement, placement_to_root


def _body_and_camera():  # type: ignore[no-untyped-def]
    return body_model("mMA").body, default_camera()


def test_pose_distances_match_the_dense_reference_and_the_xor_definition(rng: np.random.Generator) -> None:
    body, cam = _body_and_camera()
    truth = standing_pose(body)
    mask = render_silhouette(fk(truth, body), body.capsule_radii, cam)
    poses = truth + rng.normal(0.0, 0.1, (6, truth.size)) * (np.arange(truth.size) >= 3)
    poses[0] = truth
    for distance in ("xor", "nwxor"):
        feats = preprocess(mask, distance)
        for level in (1, 2):
            fast = pose_distances(poses, feats[level], body, cam)
            np.testing.assert_allclose(fast, pose_distances_reference(poses, feats[level], body, cam), atol=1e-9)
            assert np.argmin(fast) == 0  # the observed pose explains its silhouette best
    feats = preprocess(mask, "xor")
    lvl_cam = cam.scaled(0.5)
    rendered = render_silhouette(fk(poses[3], body), body.capsule_radii, lvl_cam)
    want = dense_distance(pyramid(mask)[1], rendered, "xor", window_area=feats[1].window_area)
    assert pose_distances(poses[3:4], feats[1], body, cam)[0] == pytest.approx(want)
    lik = PoseLikelihood(body, cam, level=1, sigma=0.02)(poses, feats)
    assert lik.evaluations == 6
    np.testing.assert_allclose(lik.neg_log, 0.5 * (lik.distance / 0.02) ** 2)


def test_placement_of_root_inverts_placement_to_root() -> None:
    _, cam = _body_and_camera()
    ref = np.array([0.0, 0.93, 0.0])
    for root in ([0.0, 0.93, 0.0], [0.3, 1.0, -0.5], [-0.2, 0.8, 0.4]):
        p = placement_of_root(np.asarray(root), ref, cam)
        np.testing.assert_allclose(placement_to_root(p, ref, cam), root, atol=1e-9)
    np.testing.assert_allclose(placement_of_root(ref, ref, cam), [0.0, 0.0, 1.0], atol=1e-9)


def test_stratified_counts_follow_the_weights(rng: np.random.Generator) -> None:
    for _ in range(20):
        w = rng.dirichlet(np.full(37, 0.5))
        n = int(rng.integers(50, 400))
        sys_idx = stratified_resample(w, n, rng, systematic=True)
        strat = stratified_resample(w, n, rng)
        assert len(sys_idx) == len(strat) == n and np.all(np.diff(strat) >= 0)
        # systematic: every count is floor or ceil of N w; independent strata: within two, unbiased
        assert np.all(np.abs(np.bincount(sys_idx, minlength=len(w)) - n * w) < 1.0 + 1e-9)
        assert np.all(np.abs(np.bincount(strat, minlength=len(w)) - n * w) < 2.0)
    w = np.array([0.5, 0.0, 0.25, 0.25])
    assert 1 not in stratified_resample(w, 1000, rng)
    mean = np.mean([np.bincount(stratified_resample(w, 10, rng), minlength=4) for _ in range(2000)], axis=0)
    np.testing.assert_allclose(mean, 10 * w, atol=0.1)
    counts = np.bincount(multinomial_resample(w, 20000, rng), minlength=4)
    np.testing.assert_allclose(counts / 20000, w, atol=0.02)


def test_deterministic_resampling_keeps_the_best_and_the_top_fraction(rng: np.random.Generator) -> None:
    x = rng.normal(size=(50, 4))
    cost = rng.random(50)
    cost[17] = np.nan  # a failed evaluation ranks last
    order = np.argsort(np.where(np.isnan(cost), np.inf, cost))
    out = deterministic_resample(x, cost, 0.2, 0.0, rng)  # no noise: the selection itself
    assert out.shape == x.shape
    np.testing.assert_array_equal(out[:10], x[order[:10]])  # eq. 11-12: the best 20 % in rank order
    np.testing.assert_array_equal(out[10:], np.repeat(x[order[:1]], 40, axis=0))  # eq. 13: around the best
    noisy = deterministic_resample(x, cost, 0.4, np.array([0.1, 0.1, 0.1, 0.1]), rng, n=80)
    assert noisy.shape == (80, 4)
    np.testing.assert_array_equal(noisy[0], x[order[0]])  # the best survives unchanged
    assert np.all(np.abs(noisy[1:32] - x[order[1:32]]) < 1.0)  # survivors only perturbed
    assert np.linalg.norm(noisy[32:] - x[order[0]], axis=1).mean() < 0.4
    single = deterministic_resample(x, cost, 0.0, 0.0, rng)
    np.testing.assert_array_equal(single, np.repeat(x[order[:1]], 50, axis=0))


def test_normalised_weights() -> None:
    w = normalised_weights(np.array([1000.0, 1001.0, np.inf, np.nan]))
    assert w.sum() == pytest.approx(1.0) and np.all(np.isfinite(w)) and w[2] == w[3] == 0
    assert w[0] / w[1] == pytest.approx(np.e)
    np.testing.assert_allclose(normalised_weights(np.full(3, np.inf)), 1 / 3)


def test_condensation_weights_are_normalised_and_reproducible() -> None:
    body, cam = _body_and_camera()
    mask = render_silhouette(fk(standing_pose(body), body), body.capsule_radii, cam)
    obs = Observation(preprocess(mask), observed_placement(mask, cam))
    prm = CondensationParams(n_particles=200)
    runs = []
    for _ in range(2):
        cond = Condensation(body, cam, prm, np.random.default_rng(7))
        st = cond.init()
        for _ in range(2):
            st, est = cond.step(st, obs)
            assert st.weights.shape == (200,) and np.all(np.isfinite(st.weights)) and np.all(st.weights >= 0)
            assert st.weights.sum() == pytest.approx(1.0)
            assert est.evaluations == (200,) and est.leaf == -1 and 0.0 <= est.confidence <= 1.0
            assert np.all(np.isfinite(est.pose_mean)) and est.visibility.shape == (15,)
        runs.append(world_pose(est, cam))
    np.testing.assert_array_equal(runs[0], runs[1])  # the same seed: the same track
    # an observation that every pose explains equally well: the weights stay uniform
    flat = [LevelFeatures(np.zeros((h, w + 1)), 1.0, 1.0, (h, w)) for w, h in ((80, 60), (160, 120), (320, 240))]
    st, _ = cond.step(st, Observation(flat, None))
    np.testing.assert_allclose(st.weights, 1.0 / 200)


def test_hierarchical_pf_names_and_evaluations() -> None:
    body, cam = _body_and_camera()
    mask = render_silhouette(fk(standing_pose(body), body), body.capsule_radii, cam)
    obs = Observation(preprocess(mask), observed_placement(mask, cam))
    for kind in ("drs", "srs"):
        pf = HierarchicalPF(body, cam, HPFParams(kind), np.random.default_rng(3))
        assert pf.name == kind and pf.params.n_particles == 600
        st = pf.init()
        st, est = pf.step(st, obs)
        st, est = pf.step(st, obs)
        assert est.evaluations == tuple(s.n_particles for s in pf.params.stages)
        assert len(st.particles) == len(pf.params.stages) and est.distance < (0.01 if kind == "drs" else 0.03)
        # the standing subject at the reference spot: the root is found within a few cm
        assert np.linalg.norm(world_pose(est, cam)[:3] - standing_pose(body)[:3]) < 0.1


def _track(estimator, small_db, frames: int = 30, step: int = 2) -> float:  # type: ignore[no-untyped-def]
    """Mean root-relative joint error (m) of the posterior-mean pose over the first ``frames`` frames
    (every ``step``-th) of the both-hands raise of the small database, rendered with its body."""
    _, body, motions, _, _ = small_db
    cam = default_camera()
    poses = motions[0].poses[:frames].copy()
    poses = set_heading(poses, heading_of(poses) - heading_of(poses[:1])[0])
    truth = fk(poses, body)
    st = estimator.init()
    errs = []
    for f in range(0, len(poses), step):
        mask = render_silhouette(truth[f], body.capsule_radii, cam)
        st, est = estimator.step(st, Observation(preprocess(mask), observed_placement(mask, cam)))
        j = fk(world_pose(est, cam, mean=True), body)
        errs.append(np.linalg.norm((j - j[0]) - (truth[f] - truth[f, 0]), axis=1).mean())
    return float(np.mean(errs))


def test_condensation_tracks_an_arm_raise(small_db) -> None:  # type: ignore[no-untyped-def]
    """Measured 0.114 m (seed 0; seeds 0-4: 0.114-0.125 m), 1000 particles, 15 frames at 15 Hz of the
    both-hands raise. The bound leaves room for another platform's rounding to change the track."""
    _, body, _, _, _ = small_db
    err = _track(Condensation(body, default_camera(), CondensationParams(), np.random.default_rng(0)), small_db)
    assert err < 0.17


@pytest.mark.parametrize("kind", ["drs", "srs"])
def test_hierarchical_pf_tracks_an_arm_raise(small_db, kind: str) -> None:  # type: ignore[no-untyped-def]
    """Measured drs 0.091 m, srs 0.188 m (seed 0; seeds 0-4: drs 0.063-0.146 m, srs 0.157-0.188 m),
    600 particles, 15 frames at 15 Hz of the both-hands raise; SRS with Table I's flat eq. 8 is
    nearly a random walk. Bounds with margin (a platform's rounding can change the track)."""
    _, body, _, _, _ = small_db
    err = _track(HierarchicalPF(body, default_camera(), HPFParams(kind), np.random.default_rng(0)), small_db)
    assert err < (0.20 if kind == "drs" else 0.26)


@pytest.mark.parametrize("kind", ["drs", "srs"])
def test_hierarchical_pf_with_the_cardbox_model_tracks_an_arm_raise(small_db, kind: str) -> None:  # type: ignore[no-untyped-def]
    """The paper's 3D cardbox model in the likelihood (its sizes fitted on the first frame by
    Algorithm 1), tracking the capsule body's silhouettes. Measured drs 0.138 m, srs 0.178 m (seed 0);
    the capsule likelihood's drs 0.091 m: the frames are the capsule body's, which the cardbox is not."""
    from tracker_service.body.cardbox import CardboxModel

    _, body, _, _, _ = small_db
    pf = HierarchicalPF(body, default_camera(), HPFParams(kind, cardbox=CardboxModel.from_body(body)),
                        np.random.default_rng(0))
    assert pf.name == f"{kind}-cardbox"
    err = _track(pf, small_db)
    assert err < (0.22 if kind == "drs" else 0.28)
