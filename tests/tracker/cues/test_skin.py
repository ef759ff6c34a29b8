"""Skin cue: colour locus, distance map, template hand points, hand cost, and its use by the filter."""

from __future__ import annotations

import numpy as np
import pytest

from protocol import fk
from protocol.skeleton import PARTS, rest_pose
from tracker_service.body.family import body_model
from tracker_service.body.raster import render_labels_with_areas
from tracker_service.camera import default_camera
from tracker_service.cues.skin import (
    HAND_PARTS,
    SkinModel,
    cover_cost,
    hand_cost,
    hand_points,
    leaf_joint_points,
    observe_skin,
    skin_mask,
)

SKIN_RGB = [(241, 204, 177), (224, 172, 138), (198, 134, 96), (141, 85, 54), (92, 58, 40)]
FABRIC_RGB = [(74, 115, 128), (90, 189, 85), (140, 52, 113), (48, 50, 85), (230, 230, 230), (20, 20, 20),
              (113, 44, 76)]


def _patches(colours: list[tuple[int, int, int]]) -> np.ndarray:
    img = np.zeros((10, 10 * len(colours), 3), np.uint8)
    for i, (r, g, b) in enumerate(colours):
        img[:, 10 * i: 10 * i + 10] = (b, g, r)  # BGR
    return img


def test_skin_tones_are_skin_and_fabrics_are_not() -> None:
    skin = _patches(SKIN_RGB)
    fabric = _patches(FABRIC_RGB)
    assert skin_mask(skin, np.ones(skin.shape[:2], bool)).all()
    assert not skin_mask(fabric, np.ones(fabric.shape[:2], bool)).any()


def test_skin_needs_the_silhouette_and_light() -> None:
    img = _patches(SKIN_RGB[:1])
    assert not skin_mask(img, np.zeros(img.shape[:2], bool)).any()
    dark = (img // 40).astype(np.uint8)  # same chromaticity, too dark to trust
    assert not skin_mask(dark, np.ones(img.shape[:2], bool)).any()
    strict = SkinModel(max_mahalanobis=0.1)
    assert not skin_mask(_patches(SKIN_RGB[3:4]), np.ones((10, 10), bool), strict).any()


def test_distance_map_and_fraction() -> None:
    img = np.zeros((40, 50, 3), np.uint8)
    img[20, 10] = (131, 163, 212)  # one skin pixel (BGR)
    sil = np.zeros((40, 50), bool)
    sil[10:30, 5:45] = True
    obs = observe_skin(img, sil)
    assert obs.mask.sum() == 1 and obs.distance[20, 10] == 0
    assert obs.distance[20, 40] == pytest.approx(30.0, abs=0.5)
    assert obs.distance[24, 13] == pytest.approx(5.0, abs=0.3)
    assert obs.fraction == pytest.approx(1 / sil.sum())
    none = observe_skin(np.zeros_like(img), sil)
    assert none.fraction == 0 and none.distance.min() > 100


def test_leaf_hand_points_fall_on_the_rendered_hands() -> None:
    body = body_model("mMA").body
    cam = default_camera()
    poses = rest_pose(3)
    poses[1, 3:6] = (0.0, 0.8, 0.0)  # turned
    poses[2, 3:6] = (0.3, 0.0, 0.0)  # leaning
    pts = hand_points(leaf_joint_points(fk(poses, body), cam))
    assert pts.shape == (3, 2, 2) and pts.dtype == np.float32
    joints = fk(poses, body)
    for k in range(3):
        labels, counts, areas = render_labels_with_areas(joints[k], body.capsule_radii, cam)
        for h, part in enumerate(("l_hand", "r_hand")):
            if counts[PARTS.index(part)] < 0.5 * areas[PARTS.index(part)]:
                continue  # hidden hand: nothing to check
            u, v = np.rint(pts[k, h]).astype(int)
            window = labels[v - 1: v + 2, u - 1: u + 2]
            assert (window == PARTS.index(part)).any(), (k, part)


def test_hand_cost_placement_hidden_and_outside() -> None:
    dist = np.full((100, 120), 1e3, np.float32)
    img = np.zeros((100, 120, 3), np.uint8)
    img[50, 60] = img[50, 80] = (131, 163, 212)
    dist = observe_skin(img, np.ones((100, 120), bool)).distance
    pts = np.array([[[60.0, 50.0], [80.0, 50.0]]], np.float32)
    vis = np.array([[True, True]])
    center = (60.0, 50.0)
    places = np.array([[[0.0, 0.0, 1.0], [3.0, 0.0, 1.0], [0.0, 0.0, 1.5], [500.0, 0.0, 1.0]]])
    c = hand_cost(dist, pts, vis, places, center, sigma_px=2.0, cap_px=8.0, hidden_cost=0.7)
    assert c.shape == (1, 4)
    assert c[0, 0] == pytest.approx(0.0)
    assert c[0, 1] == pytest.approx(2 * 0.5 * (3.0 / 2.0) ** 2, rel=0.05)  # both hands 3 px off
    # scaling about the left hand keeps it on skin, moves the right one 10 px (capped at 8)
    assert c[0, 2] == pytest.approx(0.5 * (8.0 / 2.0) ** 2, rel=0.01)
    assert c[0, 3] == pytest.approx(2 * 0.5 * (8.0 / 2.0) ** 2)  # off the image: capped
    hidden = hand_cost(dist, pts, np.array([[True, False]]), places[:, :2], center, 2.0, 8.0, 0.7)
    assert hidden[0, 0] == pytest.approx(0.7)


def test_filter_prefers_the_leaf_whose_hands_are_on_skin(small_db) -> None:  # type: ignore[no-untyped-def]
    """Two leaves with near-identical silhouettes: the skin evidence decides between them."""
    from dataclasses import replace

    from tracker_service.cues.skin import HAND_PARTS
    from tracker_service.estimators.base import Observation
    from tracker_service.estimators.tree_filter.filter import FilterParams, initial_state, step
    from tracker_service.silhouette.distance import runs_to_mask
    from tracker_service.silhouette.features import preprocess

    db = small_db[0]
    cam = default_camera()
    runs = db.level_runs[-1]
    vis = (db.leaf_visible[:, list(HAND_PARTS)] > 0.25).all(axis=1) & db.leaf_facing
    # a leaf with both hands visible, and the leaf with the most similar silhouette whose hands differ
    masks = {i: runs_to_mask(runs.runs(i), (cam.height, cam.width)) for i in np.flatnonzero(vis)[:300]}
    ids = list(masks)
    best = None
    for a in ids[:60]:
        for b in ids:
            if a == b:
                continue
            sep = np.linalg.norm(hand_points(db.leaf_points)[a] - hand_points(db.leaf_points)[b], axis=1).min()
            if sep < 12:
                continue
            d = np.count_nonzero(masks[a] ^ masks[b])
            if best is None or d < best[0]:
                best = (d, a, b)
    assert best is not None
    _, a, b = best
    sil = masks[a] | masks[b]
    feats = preprocess(sil, "xor")
    params = replace(FilterParams(), keep_rel=0.0, max_keep=(10**6, 10**6), skin_weight=5.0)
    for target in (a, b):
        img = np.zeros((cam.height, cam.width, 3), np.uint8)
        for u, v in np.rint(hand_points(db.leaf_points)[target]).astype(int):
            img[v - 2: v + 3, u - 2: u + 3] = (131, 163, 212)
        skin = observe_skin(img, sil)
        _, est = step(initial_state(), db, Observation(feats, None, skin=skin),
                      replace(params, refine=len(db.leaf_poses)))
        hands = hand_points(db.leaf_points)[est.leaf]
        assert np.linalg.norm(hands - hand_points(db.leaf_points)[target], axis=1).max() < 6.0, (target, est.leaf)


def test_cover_cost_counts_skin_no_limb_explains() -> None:
    from protocol.skeleton import JOINT_INDEX, N_JOINTS

    pts = np.full((1, N_JOINTS, 2), 10.0, np.float32)  # every joint at (10, 10) ...
    pts[0, JOINT_INDEX["l_wrist"]] = (10.0, 50.0)  # ... but the left wrist: the forearm is (10, 10)-(10, 50)
    places = np.array([[[0.0, 0.0, 1.0], [20.0, 0.0, 1.0]]])
    on = np.array([[10.0, 30.0], [12.0, 45.0]])  # on the forearm (within the 6 px radius)
    off = np.array([[10.0, 30.0], [30.0, 30.0]])  # the second one 20 px to the side
    c_on = cover_cost(on, pts, places, (0.0, 0.0), radius_px=6.0, sigma_px=4.0, cap_px=16.0)
    c_off = cover_cost(off, pts, places, (0.0, 0.0), radius_px=6.0, sigma_px=4.0, cap_px=16.0)
    assert c_on[0, 0] == pytest.approx(0.0)
    assert c_off[0, 0] == pytest.approx(2.0 * 0.5 * 0.5 * (14.0 / 4.0) ** 2)  # mean over 2 samples, x2
    assert c_off[0, 1] == pytest.approx(2.0 * 0.5 * 0.5 * (14.0 / 4.0) ** 2)  # moved 20 px: the other one is off
    assert cover_cost(np.zeros((0, 2)), pts, places, (0.0, 0.0), 6.0, 4.0, 16.0).shape == (1, 2)


def test_skin_cost_kernel_matches_the_numpy_references() -> None:
    from tracker_service.cues.skin import SkinObservation, skin_cost

    rng = np.random.default_rng(3)
    body = body_model("wTY").body
    cam = default_camera()
    poses = rest_pose(5)
    poses[:, 3:] += rng.normal(0, 0.4, (5, poses.shape[1] - 3))
    pts = leaf_joint_points(fk(poses, body), cam)
    pts[4, 3] = np.nan  # a joint behind the camera
    img = np.zeros((cam.height, cam.width, 3), np.uint8)
    img[rng.integers(0, cam.height, 40), rng.integers(0, cam.width, 40)] = (131, 163, 212)
    obs = observe_skin(img, np.ones((cam.height, cam.width), bool))
    assert isinstance(obs, SkinObservation) and len(obs.samples) == 40
    vis = rng.random((5, 2)) > 0.3
    places = np.stack([rng.normal(0, 10, (5, 7)), rng.normal(0, 10, (5, 7)), rng.uniform(0.8, 1.2, (5, 7))], -1)
    center = (cam.cx, cam.cy)
    ref = hand_cost(obs.distance, hand_points(pts), vis, places, center, 4.0, 16.0, 1.0) + 0.7 * cover_cost(
        obs.samples, pts, places, center, 6.0, 4.0, 16.0)
    frac = np.zeros((5, 15), np.float32)  # visible fraction per part: the hands' columns decide
    frac[:, list(HAND_PARTS)] = np.where(vis, 0.6, 0.1)
    frac[:, 0] = 1.0
    got = skin_cost(obs, pts, frac, np.arange(5), places, center, 4.0, 16.0, 1.0, 0.7, 6.0, 0.25)
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-6)  # float32 joints
    # read through rows (repeated, out of order) as the filter does; the hand term alone (no cover)
    rows = np.array([4, 0, 0, 2, 3, 1, 4])
    hand_only = skin_cost(obs, pts, frac, rows, places[rows], center, 4.0, 16.0, 1.0, 0.0, 6.0, 0.25)
    want = hand_cost(obs.distance, hand_points(pts)[rows], vis[rows], places[rows], center, 4.0, 16.0, 1.0)
    np.testing.assert_allclose(hand_only, want, rtol=1e-6, atol=1e-6)
    with pytest.raises(ValueError, match="rows must index"):
        skin_cost(obs, pts, frac, np.array([0, 5]), places[:2], center, 4.0, 16.0, 1.0, 0.7, 6.0, 0.25)
    # shapes the kernel (no bounds checks) would read or write out of range are errors
    with pytest.raises(ValueError, match="joint points"):
        skin_cost(obs, pts[:, :3], frac, np.arange(5), places, center, 4.0, 16.0, 1.0, 0.0, 6.0, 0.25)
    with pytest.raises(ValueError, match="hand"):
        skin_cost(obs, pts, frac[:, :3], np.arange(5), places, center, 4.0, 16.0, 1.0, 0.0, 6.0, 0.25)
    with pytest.raises(ValueError, match="places"):
        skin_cost(obs, pts, frac, np.arange(5), places[..., :2], center, 4.0, 16.0, 1.0, 0.0, 6.0, 0.25)


def test_distance_transform_is_reproducible_and_exact() -> None:
    """OpenCV 5's distance transform changed in the last bit with its output buffer's address (a
    60x80 image alternated between two results); ``distance_transform`` gives one answer, the
    exact Euclidean distance."""
    from scipy import ndimage

    from tracker_service.silhouette.features import distance_transform

    rng = np.random.default_rng(0)
    for shape in ((150, 120), (60, 80), (61, 83)):
        src = np.ones(shape, np.uint8)
        src[rng.integers(0, shape[0], 30), rng.integers(0, shape[1], 30)] = 0
        first = distance_transform(src)
        for k in range(12):
            pad = np.empty(k * 5 + 1, np.float32)  # shift the allocator between calls
            np.testing.assert_array_equal(distance_transform(src), first)
            del pad
        assert first.dtype == np.float32 and first.shape == shape
        np.testing.assert_allclose(first, ndimage.distance_transform_edt(src), atol=1e-4)
