"""The shoe cue: colour model, shoe pixels, the feet cost and the legs' re-weighting."""

import numpy as np

from protocol.skeleton import JOINT_INDEX, N_JOINTS, POSE_SIZE, ROT_JOINTS
from tracker_service.cues.shoes import (
    LEG_POSE_INDEX,
    ShoeParams,
    band_pixels,
    feet_cost,
    feet_cost_reference,
    foot_points,
    learn_shoes,
    reweight_legs,
    shoe_mask,
    shoe_pixels,
)
from tracker_service.estimators.tree_filter.filter import mean_pose, tempered

SHOE, LEG, SHIRT = (30, 200, 40), (150, 60, 20), (40, 40, 200)


def _person(rng: np.random.Generator, feet_rows: tuple[int, int] = (200, 200), shoe=SHOE, leg=LEG
            ) -> tuple[np.ndarray, np.ndarray]:
    """A 240x320 frame: a person from row 60 to the feet; two legs (x 140-152 and 166-178), each
    ending in a 6-row shoe at its own bottom row."""
    img = np.full((240, 320, 3), 128, np.float64)
    mask = np.zeros((240, 320), bool)
    mask[60:140, 135:185] = True
    img[60:140, 135:185] = SHIRT
    for (x0, x1), bottom in zip(((140, 152), (166, 178)), feet_rows, strict=True):
        mask[140: bottom + 1, x0:x1] = True
        img[140: bottom + 1, x0:x1] = leg
        img[bottom - 5: bottom + 1, x0:x1] = shoe
    img += rng.normal(0, 3.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8), mask


def test_the_shoes_colour_is_learned_unless_the_legs_look_the_same(rng: np.random.Generator) -> None:
    p = ShoeParams()
    img, mask = _person(rng)
    shoes, legs = band_pixels(img, mask, p)
    assert len(shoes) >= p.min_samples and len(legs) > 0
    model = learn_shoes(shoes, legs, p)
    assert model is not None
    np.testing.assert_allclose(model.mean, SHOE, atol=2.0)
    same, _ = _person(rng, shoe=LEG)
    assert learn_shoes(*band_pixels(same, mask, p), p) is None  # black shoes under black trousers: off
    assert learn_shoes(shoes[:5], legs, p) is None  # too few samples
    assert [len(a) for a in band_pixels(img, np.zeros_like(mask), p)] == [0, 0]


def test_shoe_pixels_are_the_shoes_in_the_lowest_part_only(rng: np.random.Generator) -> None:
    p = ShoeParams()
    img, mask = _person(rng)
    model = learn_shoes(*band_pixels(img, mask, p), p)
    assert model is not None
    walk, wmask = _person(rng, feet_rows=(185, 205))
    walk[70:76, 140:152] = SHOE  # a shoe-coloured patch on the shirt is not a shoe
    s = shoe_mask(walk, wmask, model, p)
    assert s[180:186, 141:151].all() and s[200:206, 167:177].all()
    assert not s[:150].any() and not (s & ~wmask).any()
    assert s.sum() <= 2 * 6 * 12
    assert not shoe_mask(walk, np.zeros_like(wmask), model, p).any()


def test_the_shoe_pixel_kernel_equals_the_numpy_mask(rng: np.random.Generator) -> None:
    p = ShoeParams()
    img, mask = _person(rng)
    model = learn_shoes(*band_pixels(img, mask, p), p)
    assert model is not None
    for case in range(8):
        walk, wmask = _person(rng, feet_rows=(int(rng.integers(180, 236)), int(rng.integers(180, 240))))
        speckle = rng.random(wmask.shape) < 0.05  # isolated shoe-coloured pixels: the opening removes them
        walk[speckle & wmask] = SHOE
        if case % 2:
            wmask[:, 160:] = False  # the box at a silhouette's edge
        su, sv = shoe_pixels(walk, wmask, model, p)
        ref_v, ref_u = np.nonzero(shoe_mask(walk, wmask, model, p))
        np.testing.assert_array_equal(su, ref_u)
        np.testing.assert_array_equal(sv, ref_v)
        assert len(su) > 0
        cost = feet_cost((su, sv), np.array([[[146.0, 200.0], [172.0, 200.0]]]), p, wmask.shape)
        assert cost is not None
        ref = feet_cost_reference(shoe_mask(walk, wmask, model, p), np.array([[[146.0, 200.0], [172.0, 200.0]]]), p)
        assert ref is not None
        np.testing.assert_allclose(cost, ref, rtol=1e-12)  # the fast path end to end against the numpy one
    empty = np.zeros_like(mask)
    assert [len(a) for a in shoe_pixels(img, empty, model, p)] == [0, 0]


def test_feet_on_both_shoes_cost_least(rng: np.random.Generator) -> None:
    p = ShoeParams()
    shoes = np.zeros((240, 320), bool)
    shoes[180:186, 140:152] = True  # back foot, higher
    shoes[200:206, 166:178] = True  # front foot
    right = [[146.0, 183.0], [172.0, 203.0]]
    both_front = [[160.0, 203.0], [172.0, 203.0]]  # a short stride: both feet at the front shoe
    off = [[100.0, 120.0], [220.0, 120.0]]
    cost = feet_cost(shoes, np.array([right, both_front, off]), p)
    assert cost is not None
    assert cost[0] < 0.1 * cost[1] and cost[1] < cost[2]  # the shoes' corners are a few px from the centres
    # the forward term alone cannot see the short stride's bare back shoe; the reverse term does
    fwd_only = feet_cost(shoes, np.array([right, both_front]), ShoeParams(reverse=0.0))
    assert fwd_only is not None and fwd_only[1] < 0.5 * 16.0**2
    assert cost[1] > 4.0 * 10.0**2 / 3  # about a third of the shoe pixels are 10+ px from a foot
    assert feet_cost(np.zeros_like(shoes), np.array([right]), p) is None


def test_the_feet_cost_kernel_equals_its_numpy_reference(rng: np.random.Generator) -> None:
    h, w = 240, 320
    for case in range(12):
        p = ShoeParams(cap_px=float(rng.choice([8.0, 16.0, 16.5])), dead_px=float(rng.uniform(0, 4)),
                       forward=float(rng.uniform(0, 1)), reverse=float(rng.uniform(0, 5)))
        shoes = np.zeros((h, w), bool)
        for _ in range(int(rng.integers(1, 4))):  # blobs, some at the image border
            y, x = int(rng.integers(0, h)), int(rng.integers(0, w))
            shoes[max(y - 3, 0): y + 3, max(x - 6, 0): x + 6] = True
        shoes &= rng.random((h, w)) < 0.9
        k = int(rng.integers(1, 60))
        feet = rng.uniform([-40, -40], [w + 40, h + 40], (k, 2, 2))  # some outside the image
        near = rng.integers(0, k, k // 2)
        sv, su = np.nonzero(shoes)
        pick = rng.integers(0, len(su), (len(near), 2))
        feet[near] = np.stack([su[pick], sv[pick]], axis=-1) + rng.normal(0, 3, (len(near), 2, 2))
        feet[0, 0] = (su[0] + 0.5, sv[0] + 0.5)  # a half-pixel tie of the rounding
        a, b = feet_cost(shoes, feet, p), feet_cost_reference(shoes, feet, p)
        assert a is not None and b is not None
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9, err_msg=f"case {case}")
    assert feet_cost(np.zeros((h, w), bool), feet, ShoeParams()) is None
    assert feet_cost(np.zeros((h, w), bool), feet, ShoeParams(min_pixels=0)) is None  # never an empty mean


def test_foot_points_move_with_the_placement() -> None:
    pts = np.zeros((1, N_JOINTS, 2), np.float32)
    pts[0, JOINT_INDEX["l_ankle"]] = (150, 200)
    pts[0, JOINT_INDEX["l_toe"]] = (150, 210)
    pts[0, JOINT_INDEX["r_ankle"]] = (170, 200)
    pts[0, JOINT_INDEX["r_toe"]] = (170, 206)
    centre = (160.0, 120.0)
    f = foot_points(pts, np.array([[0.0, 0.0, 1.0]]), centre)
    np.testing.assert_allclose(f[0], [[150, 205], [170, 203]])
    g = foot_points(pts, np.array([[5.0, -2.0, 2.0]]), centre)
    np.testing.assert_allclose(g[0], [[165 - 20, 120 - 2 + 2 * 85], [165 + 20, 120 - 2 + 2 * 83]])


def test_the_legs_follow_the_cheaper_feet_and_nothing_else_moves(rng: np.random.Generator) -> None:
    poses = rng.normal(0.0, 0.3, (3, POSE_SIZE))
    w = np.array([0.6, 0.3, 0.1])
    pose = mean_pose(poses, tempered(w, 5.0))
    out = reweight_legs(pose, poses, w, np.array([400.0, 0.0, 400.0]), 5.0, ShoeParams(weight=0.05))
    others = np.setdiff1d(np.arange(POSE_SIZE), LEG_POSE_INDEX)
    np.testing.assert_array_equal(out[others], pose[others])
    knee = 3 + 3 * ROT_JOINTS.index("l_knee")
    # exp(-20): all the legs' weight on leaf 1
    np.testing.assert_allclose(out[knee: knee + 3], poses[1, knee: knee + 3], atol=1e-6)
    same = reweight_legs(pose, poses, w, np.full(3, 7.0), 5.0, ShoeParams())
    np.testing.assert_allclose(same, pose, atol=1e-12)
    assert len(LEG_POSE_INDEX) == 18 and len(set(LEG_POSE_INDEX.tolist())) == 18
