from dataclasses import replace

import cv2
import numpy as np
import pytest

from tracker_service.silhouette.distance import (
    RunSet,
    dense_distance,
    evaluate_templates,
    evaluate_templates_reference,
    mask_to_runs,
    placed_run,
    runs_to_mask,
)
from tracker_service.silhouette.features import distance_maps, match_image, preprocess, pyramid, shape_skeleton


def _person(h: int = 240, w: int = 320, dx: int = 0, arm: float = 0.0) -> np.ndarray:
    """A stick person: torso ellipse, head, legs, one arm at angle ``arm`` (radians from down)."""
    m = np.zeros((h, w), np.uint8)
    cx = w // 2 + dx
    cv2.ellipse(m, (cx, 100), (22, 45), 0, 0, 360, 1, -1)
    cv2.circle(m, (cx, 42), 14, 1, -1)
    cv2.line(m, (cx - 10, 140), (cx - 14, 225), 1, 11)
    cv2.line(m, (cx + 10, 140), (cx + 14, 225), 1, 11)
    cv2.line(m, (cx - 22, 65), (cx - 30, 140), 1, 8)
    ex = int(cx + 22 + 70 * np.sin(arm))
    ey = int(65 + 70 * np.cos(arm))
    cv2.line(m, (cx + 22, 65), (ex, ey), 1, 8)
    return m.astype(bool)


def test_runs_round_trip(rng: np.random.Generator) -> None:
    m = rng.random((60, 80)) > 0.6
    runs = mask_to_runs(m)
    assert runs.dtype == np.int16 and runs.shape[1] == 3
    np.testing.assert_array_equal(runs_to_mask(runs, m.shape), m)


@pytest.mark.parametrize("distance", ["xor", "cwxor", "nwxor"])
def test_integral_form_equals_definition(distance: str) -> None:
    """eq. 11 + eq. 12 (integral images over runs) == eq. 7 / 8 / 10 summed pixel by pixel."""
    s = _person(arm=0.3)
    feats = preprocess(s, distance)  # type: ignore[arg-type]
    lvl = feats[2]
    for arm in (0.3, 1.2, 2.5):
        t = _person(arm=arm, dx=3)
        rs = RunSet([mask_to_runs(t)])
        got = evaluate_templates(lvl, rs, np.array([0]), np.array([[0.0, 0.0, 1.0]]), (160.0, 120.0))[0]
        want = dense_distance(s, t, distance, window_area=lvl.window_area)  # type: ignore[arg-type]
        assert got == pytest.approx(want, rel=1e-6, abs=1e-9)
    # identical silhouettes have distance 0
    same = evaluate_templates(lvl, RunSet([mask_to_runs(s)]), np.array([0]), np.array([[0.0, 0.0, 1.0]]), (0, 0))
    assert same[0] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("distance", ["xor", "cwxor", "nwxor"])
def test_kernel_equals_reference_with_offsets_and_scales(distance: str, rng: np.random.Generator) -> None:
    s = _person(arm=0.8)
    feats = preprocess(s, distance)  # type: ignore[arg-type]
    lvl = feats[1]
    a, _ = match_image(pyramid(s)[1], distance)  # type: ignore[arg-type]
    arms, shifts = rng.uniform(0, 3, 12), rng.integers(-30, 30, 12)
    temps = [mask_to_runs(pyramid(_person(arm=x, dx=int(d)))[1]) for x, d in zip(arms, shifts, strict=True)]
    rs = RunSet(temps)
    ids = rng.integers(0, len(temps), 200)
    tr = np.stack([rng.uniform(-70, 70, 200), rng.uniform(-50, 50, 200), rng.uniform(0.7, 1.4, 200)], axis=1)
    got = evaluate_templates(lvl, rs, ids, tr, (80.0, 60.0))
    want = evaluate_templates_reference(lvl, a, rs, ids, tr, (80.0, 60.0))
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


def test_nwxor_prefers_the_right_arm_pose_more_sharply() -> None:
    """The normalised weight keeps limbs as important as the torso (paper Fig. 3/4)."""
    s = _person(arm=1.5)
    scores = {}
    for dist in ("xor", "cwxor", "nwxor"):
        lvl = preprocess(s, dist)[2]  # type: ignore[arg-type]
        cands = np.linspace(0, 3, 31)
        rs = RunSet([mask_to_runs(_person(arm=x)) for x in cands])
        d = evaluate_templates(lvl, rs, np.arange(len(cands)), np.tile([0.0, 0.0, 1.0], (len(cands), 1)), (0, 0))
        assert abs(cands[np.argmin(d)] - 1.5) < 0.11, dist
        scores[dist] = d
    # relative contrast between the best and a torso-only mismatch
    assert scores["nwxor"].min() == pytest.approx(0.0, abs=1e-9)


def test_skeleton_and_distance_maps() -> None:
    m = np.zeros((40, 60), bool)
    m[10:30, 5:55] = True
    d_s, d_sbar = distance_maps(m)
    assert d_s[m].max() == 0 and d_sbar[~m].max() == 0
    assert d_sbar[20, 30] == pytest.approx(10.0, abs=0.6)
    skl = shape_skeleton(d_sbar)
    assert skl[19:21, 15:45].any(axis=0).all()  # the ridge runs along the middle rows
    assert not skl[~m].any()


def test_grid_kernel_equals_flat_kernel(rng: np.random.Generator) -> None:
    from tracker_service.silhouette.distance import evaluate_template_grid, evaluate_templates
    from tracker_service.silhouette.features import preprocess
    h, w = 60, 80
    obs = np.zeros((h, w), bool)
    obs[10:50, 30:45] = True
    obs[20:28, 15:65] = True
    feats = preprocess(obs, "nwxor", sizes=((w, h),))[0]
    masks = []
    for _ in range(5):
        m = np.zeros((h, w), bool)
        y0, x0 = rng.integers(0, 20), rng.integers(0, 40)
        m[y0: y0 + rng.integers(10, 40), x0: x0 + rng.integers(5, 35)] = True
        masks.append(m)
    rs = RunSet([mask_to_runs(m) for m in masks])
    ids = np.array([0, 3, 4, 1], np.int64)
    tr = np.stack([rng.normal(0, 4, (4, 9)), rng.normal(0, 2, (4, 9)), rng.uniform(0.8, 1.2, (4, 9))], -1)
    tr[0, 0] = (-70.0, 0.0, 1.0)  # partly outside the image
    grid = evaluate_template_grid(feats, rs, ids, tr, (40.0, 30.0))
    flat = evaluate_templates(feats, rs, np.repeat(ids, 9), tr.reshape(-1, 3), (40.0, 30.0))
    assert grid.shape == (4, 9)
    assert len(np.unique(grid)) > 9  # placements differ: the comparison is not vacuous
    np.testing.assert_array_equal(grid.ravel(), flat)
    one = evaluate_template_grid(feats, rs, np.repeat(ids, 9), tr.reshape(-1, 1, 3), (40.0, 30.0))  # G = 1
    np.testing.assert_array_equal(one.ravel(), flat)


def _plain_run_sums(integral: np.ndarray, runs: np.ndarray, tr: np.ndarray, cx: float, cy: float,
                    outside: float) -> np.ndarray:
    """eq. 12 in its plain form, run by run in the kernel's order (the kernel's shortcuts removed)."""
    h, w = integral.shape[0], integral.shape[1] - 1
    out = np.zeros(len(tr))
    for m, (dx, dy, s) in enumerate(tr):
        acc = 0.0
        for y, x0, x1 in runs.astype(np.int64):
            ya, yb, xl, xr = placed_run(y, x0, x1, dx, dy, s, cx, cy)
            if xr <= xl:
                continue
            cl, cr = min(max(xl, 0), w), min(max(xr, 0), w)
            for yy in range(ya, yb):
                if yy < 0 or yy >= h:
                    acc += outside * (xr - xl)
                else:
                    acc += integral[yy, cr] - integral[yy, cl] + outside * ((xr - xl) - (cr - cl))
        out[m] = acc
    return out


def test_kernel_sums_are_bit_equal_to_the_plain_form(rng: np.random.Generator) -> None:
    """The kernel's shortcuts (a row's start carried from the previous row's end, the outside term
    skipped inside the image) change no bit, also for placements partly outside the image."""
    from tracker_service.silhouette._kernels import eval_runs_grid_kernel

    s = _person(arm=0.8)
    feats = preprocess(s, "nwxor")[1]  # real-valued weights: any change of order would show
    t = mask_to_runs(pyramid(_person(arm=2.0, dx=9))[1])
    rs = RunSet([t])
    tr = np.stack([rng.uniform(-90, 90, 60), rng.uniform(-70, 70, 60), rng.uniform(0.6, 1.5, 60)], axis=1)
    tr[0] = (0.0, 0.0, 1.0)
    got = np.empty((len(tr), 1))  # one placement per template: the kernel's register path
    eval_runs_grid_kernel(feats.integral, rs.data, rs.ptr, np.zeros(len(tr), np.int64), tr[:, None, :].copy(),
                          80.0, 60.0, 5.0, got)
    got = got[:, 0]
    want = _plain_run_sums(feats.integral, t, tr, 80.0, 60.0, 5.0)
    inside = (np.abs(tr[:, 0]) < 20) & (np.abs(tr[:, 1]) < 10)
    assert inside.any() and (~inside).any()  # both of the kernel's paths are exercised
    np.testing.assert_array_equal(got, want)


def test_run_rectangles_cover_the_runs_and_match_the_reference(rng: np.random.Generator) -> None:
    from tracker_service.silhouette.distance import run_rectangles, run_rectangles_reference

    masks = [pyramid(_person(arm=a, dx=d))[1] for a, d in ((0.3, 0), (2.0, 30))] + [rng.random((60, 80)) > 0.5]
    masks.append(np.zeros((60, 80), bool))  # a template without runs
    rs = RunSet([mask_to_runs(m) for m in masks])
    rects, rptr = run_rectangles(rs.data, rs.ptr)
    assert rects.dtype == np.int16 and rects.shape[1] == 4 and rptr[-1] == len(rects) and len(rptr) == len(rs) + 1
    assert rptr[2] < 0.7 * rs.ptr[2]  # the two people's rows merge (about half their runs)
    for i, m in enumerate(masks):
        got = rects[rptr[i]: rptr[i + 1]]
        np.testing.assert_array_equal(got, run_rectangles_reference(rs.runs(i)))
        back = np.zeros(m.shape, int)
        for y0, y1, x0, x1 in got.astype(np.int64):
            back[y0:y1, x0:x1] += 1
        np.testing.assert_array_equal(back, m.astype(int))  # every pixel in exactly one rectangle
    cols, cptr = rs.rectangle_columns()  # the copy the run set keeps: the same rectangles, column-wise
    assert cols.flags.c_contiguous and cols.shape == (4, len(rects))
    np.testing.assert_array_equal(cols.T, rects)
    np.testing.assert_array_equal(rs.rectangles()[0], rects)
    np.testing.assert_array_equal(cptr, rptr)
    with pytest.raises(ValueError, match="pointer"):
        run_rectangles(rs.data, rs.ptr[:-2])


def test_summed_area_kernel_is_bit_equal_to_the_row_kernel(rng: np.random.Generator) -> None:
    """XOR's A is integer-valued, so the summed-area kernel (four lookups per rectangle) gives the row
    kernel's sums to the bit, at one placement per template and on grids, inside and partly outside
    the image; cwXOR / nwXOR (real-valued A) keep the row kernel."""
    from tracker_service.silhouette._kernels import eval_rects_sat_kernel, eval_runs_grid_kernel

    s = _person(arm=0.8)
    assert all(f.sat is None for f in preprocess(s, "nwxor")) and all(f.sat is None for f in preprocess(s, "cwxor"))
    for level, feats in enumerate(preprocess(s, "xor")):
        assert feats.sat is not None and feats.sat.shape == (feats.shape[0] + 1, feats.shape[1] + 1)
        a = np.diff(feats.integral, axis=1)
        np.testing.assert_array_equal(feats.sat[1:, 1:], np.cumsum(np.cumsum(a, 0), 1))
        h, w = feats.shape
        masks = [pyramid(_person(arm=arm, dx=dx))[level] for arm, dx in ((2.0, 9), (0.3, -20), (1.2, 40))]
        rs = RunSet([mask_to_runs(m) for m in masks])
        n, g = 12, 9
        ids = rng.integers(0, 3, n).astype(np.int64)
        tr = np.stack([rng.uniform(-0.6, 0.6, (n, g)) * w, rng.uniform(-0.5, 0.5, (n, g)) * h,
                       rng.uniform(0.6, 1.5, (n, g))], axis=-1)
        tr[0, 0] = (0.0, 0.0, 1.0)
        cx, cy, oc = w / 2.0, h / 2.0, w / 16.0
        for grid in (tr, tr.reshape(-1, 1, 3)):
            idx = ids if grid.shape[1] == g else np.repeat(ids, g)
            want = np.empty(grid.shape[:2])
            got = np.empty(grid.shape[:2])
            eval_runs_grid_kernel(feats.integral, rs.data, rs.ptr, idx, np.ascontiguousarray(grid), cx, cy, oc, want)
            cols, rptr = rs.rectangle_columns()
            eval_rects_sat_kernel(feats.sat, cols, rptr, idx, np.ascontiguousarray(grid), cx, cy, oc, got)
            assert len(np.unique(want)) > g  # placements differ: the comparison is not vacuous
            np.testing.assert_array_equal(got, want)
        # through the public functions: the XOR features take the summed-area path, same numbers
        flat = evaluate_templates(feats, rs, np.repeat(ids, g), tr.reshape(-1, 3), (cx, cy))
        rows = evaluate_templates(replace(feats, sat=None), rs, np.repeat(ids, g), tr.reshape(-1, 3), (cx, cy))
        np.testing.assert_array_equal(flat, rows)


def test_xor_features_kernel_equals_the_numpy_path(rng: np.random.Generator) -> None:
    """preprocess's one-pass XOR kernel gives the numpy path's row sums, summed-area table, B and
    window to the bit (every sum an exact integer), for people, noise, empty and full frames."""
    from tracker_service.silhouette.features import preprocess_reference

    masks = [_person(arm=1.0), _person(dx=150), rng.random((240, 320)) > 0.7, np.zeros((240, 320), bool),
             np.ones((240, 320), bool)]
    for m in masks:
        got, want = preprocess(m, "xor"), preprocess_reference(m, "xor")
        for g, w in zip(got, want, strict=True):
            assert g.sat is not None and w.sat is not None and g.shape == w.shape
            np.testing.assert_array_equal(g.integral, w.integral)
            np.testing.assert_array_equal(g.sat, w.sat)
            assert (g.b, g.window_area) == (w.b, w.window_area)
    assert preprocess(masks[0], "xor")[2].b == masks[0].sum() > 0  # not vacuous


def test_bad_input_to_the_new_kernels_is_an_error_not_a_crash() -> None:
    """The rectangle and skin kernels have no bounds checks: their wrappers reject what would
    make them read or write out of range."""
    from tracker_service.silhouette.distance import run_rectangles

    with pytest.raises(ValueError, match="rows"):
        run_rectangles(np.array([[-1, 0, 4]], np.int16), np.array([0, 1]))
    with pytest.raises(ValueError, match="rows"):
        run_rectangles(np.array([[32767, 0, 4]], np.int16), np.array([0, 1]))
