"""Global placement: the observed shift and scale, the per-template column (kernel vs reference),
the placement of templates for a subject of another size, and the world root it gives back."""

import numpy as np
import pytest

from protocol import fk
from protocol.skeleton import CAPSULE_INDEX, JOINT_INDEX, ROT_SLOT, standing_pose
from tracker_service.body.family import body_model
from tracker_service.body.raster import render_silhouette, silhouette_runs
from tracker_service.camera import default_camera
from tracker_service.cues.appearance import camera_joints
from tracker_service.pipeline.body_selection import (
    SIZE_MARGIN_M,
    STATURE_RANGE_M,
    BodyChoice,
    measured_stature,
    shoulder_row,
    shoulder_top,
)
from tracker_service.silhouette.distance import RunSet, mask_to_runs, runs_to_mask
from tracker_service.silhouette.placement import (
    feet_in_view,
    feet_scale,
    height_scale,
    lower_body_column,
    lower_body_column_reference,
    observed_placement,
    placement_to_root,
    reference_floor_row,
    scaled_placement,
    silhouette_rows,
    template_bottoms,
    template_columns,
    template_columns_reference,
    template_tops,
)


def test_template_columns_kernel_matches_reference(small_db, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    db, *_ = small_db
    shapes = ((60, 80), (120, 160), (240, 320))
    for lvl, shape in enumerate(shapes):
        runs = db.level_runs[lvl]
        pick = rng.choice(len(runs), size=min(60, len(runs)), replace=False)
        sub = RunSet([runs.runs(int(i)) for i in pick] + [np.zeros((0, 3), np.int16)])  # and an empty one
        got = template_columns(sub, db.level_scale[lvl])
        want = template_columns_reference(sub, db.level_scale[lvl], shape)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
        np.testing.assert_allclose(got[:-1], want[:-1], atol=1e-9)
        assert np.isnan(got[-1])
    # the database carries them, one per node and level
    assert [len(c) for c in db.level_column] == list(db.tree.level_sizes)


def test_template_column_is_the_silhouette_column_at_full_resolution() -> None:
    cam = default_camera()
    body = body_model("mMA").body
    pose = standing_pose(body)
    slot = ROT_SLOT[JOINT_INDEX["l_shoulder"]]
    pose[3 + 3 * slot: 6 + 3 * slot] = [0.0, 0.0, 1.2]  # an arm raised to one side
    mask = render_silhouette(fk(pose, body), body.capsule_radii, cam)
    col = template_columns(RunSet([mask_to_runs(mask)]), 1.0)[0]
    assert col == lower_body_column(runs_to_mask(mask_to_runs(mask), mask.shape))
    assert col == pytest.approx(lower_body_column(mask))


@pytest.mark.parametrize("subject_name", ["wSY", "mLA", "cMA"])
@pytest.mark.parametrize("spot", [(0.0, 0.0), (0.35, -0.6), (-0.3, -1.2)])
def test_scaled_placement_recovers_the_root_of_another_size(subject_name: str, spot: tuple[float, float]) -> None:
    """A subject k times the templates' height, standing anywhere on the floor: the template drawn
    at the scaled placement has its feet on the observed feet row and gives back the subject's
    root position."""
    cam = default_camera()
    tpl_body = body_model("mMA").body
    subject = body_model(subject_name).body
    k = subject.height / tpl_body.height
    truth = standing_pose(subject)
    truth[0], truth[2] = spot
    mask = render_silhouette(fk(truth, subject), subject.capsule_radii, cam)
    obs = observed_placement(mask, cam)
    assert obs is not None
    place = scaled_placement(obs, k, cam)
    # the template's floor row lands on the subject's
    floor = reference_floor_row(cam)
    assert cam.cy + place[1] + place[2] * (floor - cam.cy) == pytest.approx(cam.cy + obs[2] * (floor - cam.cy))
    # and the template's root maps to the subject's root
    tpl = standing_pose(tpl_body)
    root = placement_to_root(place, tpl[:3], cam, body_scale=k)
    # depth to a pixel of the feet row (a child's shorter foot is 2 px higher: 5 cm at 3 m)
    np.testing.assert_allclose(root[:2], truth[:2], atol=0.03)
    d_true, d_est = cam.depth(truth[:3]), cam.depth(root)
    assert abs(d_est / d_true - 1.0) < 0.025
    # the template drawn there overlaps the subject's silhouette well
    runs = silhouette_runs(fk(tpl, tpl_body), tpl_body.capsule_radii, cam)
    drawn = np.zeros_like(mask)
    for y, x0, x1 in runs:
        yy0 = int(np.floor(cam.cy + place[1] + place[2] * (y - cam.cy) + 0.5))
        yy1 = int(np.floor(cam.cy + place[1] + place[2] * (y + 1 - cam.cy) + 0.5))
        xa = int(np.floor(cam.cx + place[0] + place[2] * (x0 - cam.cx) + 0.5))
        xb = int(np.floor(cam.cx + place[0] + place[2] * (x1 - cam.cx) + 0.5))
        drawn[max(yy0, 0):max(yy1, 0), max(xa, 0):max(xb, 0)] = True
    iou = (drawn & mask).sum() / (drawn | mask).sum()
    assert iou > 0.75
    rows = np.flatnonzero(mask.any(axis=1))
    drawn_rows = np.flatnonzero(drawn.any(axis=1))
    assert abs(int(drawn_rows[-1]) - int(rows[-1])) <= 2  # feet on the same row


@pytest.mark.parametrize("spot", [(0.0, 0.0), (0.35, -0.6), (-0.3, -1.2)])
def test_measured_stature_of_standing_bodies(spot: tuple[float, float]) -> None:
    cam = default_camera()
    db_body = body_model("mMA").body
    for name in ("wSY", "mMA", "mTA", "cMA", "wTY"):
        b = body_model(name).body
        pose = standing_pose(b)
        pose[0], pose[2] = spot
        mask = render_silhouette(fk(pose, b), b.capsule_radii, cam)
        obs = observed_placement(mask, cam)
        assert obs is not None
        # within a pixel of the head and feet rows at that distance (children's feet are shorter)
        tol = 0.03 * float(cam.depth(pose[:3])) / 3.0
        assert measured_stature(mask, obs, cam, db_body) == pytest.approx(b.height, abs=tol), name


def test_measured_stature_of_a_silhouette_that_lost_its_head() -> None:
    """The head and neck lost to a background of their colour (skin before a pink wall): the top is
    the shoulders, and the stature is measured from them; whole silhouettes are not taken for it."""
    cam = default_camera()
    db_body = body_model("mMA").body
    for name in ("wSY", "mMA", "mTA", "cMA"):
        b = body_model(name).body
        pose = standing_pose(b)
        joints = fk(pose, b)
        whole = render_silhouette(joints, b.capsule_radii, cam)
        radii = b.capsule_radii.copy()
        radii[[CAPSULE_INDEX["neck"], CAPSULE_INDEX["skull"]]] = 0.0
        headless = render_silhouette(joints, radii, cam)
        radii[CAPSULE_INDEX["neck"]] = 0.3 * b.capsule_radii[CAPSULE_INDEX["neck"]]
        scrap = render_silhouette(joints, radii, cam)  # a thin scrap of neck above the shoulders
        obs = observed_placement(whole, cam)
        assert obs is not None and shoulder_row(whole) is None, name
        assert shoulder_row(headless) is not None and shoulder_row(scrap) is not None, name
        tol = 0.03 * float(cam.depth(pose[:3])) / 3.0
        assert measured_stature(whole, obs, cam, db_body) == pytest.approx(b.height, abs=tol), name
        for mask in (headless, scrap):
            assert measured_stature(mask, obs, cam, db_body) == pytest.approx(b.height, abs=2 * tol), name
        assert 0.8 < shoulder_top(b) < 0.9
    assert shoulder_row(np.zeros((240, 320), bool)) is None


def _raised_left_arm(rotvec: np.ndarray, name: str) -> tuple[np.ndarray, float]:
    b = body_model(name).body
    pose = standing_pose(b)
    slot = ROT_SLOT[JOINT_INDEX["l_shoulder"]]
    pose[3 + 3 * slot: 6 + 3 * slot] = rotvec
    return fk(pose, b), b.height


#: The left arm (pointing along +x in the T-pose) raised sideways, or swung forward (toward the
#: camera) and up by 40-75 degrees above the horizontal, or up and back past the vertical (110).
_RAISES = {"side 69": [0.0, 0.0, 1.2], "side 115": [0.0, 0.0, 2.0],
           **{f"front {th}": list(np.pi / 2 * np.array([0.0, -np.cos(np.radians(th)), np.sin(np.radians(th))]))
              for th in (40, 75, 110)}}


@pytest.mark.parametrize("raise_name", list(_RAISES))
def test_measured_stature_with_a_hand_above_the_head(raise_name: str) -> None:
    """A raised hand tops the silhouette: without the pose the extent overshoots the stature by
    the hand's height over the head; with the pose's joints as the network reads them (camera
    axes, units of height) it is the stature, also for a hand held toward the camera or behind
    the head (perspective)."""
    cam = default_camera()
    db_body = body_model("mMA").body
    for name in ("wSY", "mMA", "mTA", "cMA"):
        joints, height = _raised_left_arm(np.array(_RAISES[raise_name]), name)
        assert int(np.argmax(joints[:, 1])) == JOINT_INDEX["l_hand_tip"]
        mask = render_silhouette(joints, body_model(name).body.capsule_radii, cam)
        obs = observed_placement(mask, cam)
        assert obs is not None
        assert measured_stature(mask, obs, cam, db_body) > height + 0.1, name
        got = measured_stature(mask, obs, cam, db_body, camera_joints(joints, cam, height))
        assert got == pytest.approx(height, abs=0.03), name  # about a pixel at 3 m, as standing


def test_measured_stature_with_the_head_on_top_ignores_the_pose() -> None:
    cam = default_camera()
    db_body = body_model("mMA").body
    b = body_model("mLA").body
    pose = standing_pose(b)
    joints = fk(pose, b)
    mask = render_silhouette(joints, b.capsule_radii, cam)
    obs = observed_placement(mask, cam)
    assert obs is not None
    read = camera_joints(joints, cam, b.height)
    assert measured_stature(mask, obs, cam, db_body, read) == measured_stature(mask, obs, cam, db_body)
    assert np.isnan(measured_stature(np.zeros_like(mask), obs, cam, db_body, read))
    read[3, 2] = np.nan
    assert np.isnan(measured_stature(mask, obs, cam, db_body, read))


def test_body_choice_keeps_a_man_taller_than_the_family_at_its_tallest() -> None:
    db_body = body_model("mMA").body
    scores = {"mTA": [0.30, 0.32], "mLY": [0.25, 0.27], "mLA": [0.28, 0.26]}  # the shorter match better
    assert BodyChoice.from_scores(scores, db_body, 1.87).body.name == "mTA"  # 1.80 m: the nearest height
    # within the tolerance the silhouette decides, as before
    assert BodyChoice.from_scores(scores, db_body, 1.79).body.name == "mLY"
    choice = BodyChoice.from_scores(scores, db_body, float("nan"))
    assert choice.body.name == "mLY"
    assert choice.scale == pytest.approx(1.75 / db_body.height)
    assert BodyChoice.from_scores({}, db_body, 1.87).body is db_body


def test_body_choice_is_as_tall_as_the_measured_stature() -> None:
    """The winner gives the build; the body is that model at the measured stature (the family's
    steps are 4-5 cm), its proportions kept; out of range it is clamped."""
    db_body = body_model("mMA").body
    scores = {"mTA": [0.30], "mLY": [0.25], "mLA": [0.28]}
    choice = BodyChoice.from_scores(scores, db_body, 1.77)
    assert choice.body.name == "mLY" and choice.body.height == pytest.approx(1.77)
    assert choice.scale == pytest.approx(1.77 / db_body.height)
    ly = body_model("mLY").body
    assert np.allclose(choice.body.offsets / 1.77, ly.offsets / ly.height, atol=5e-4)
    assert np.allclose(choice.body.capsule_radii / 1.77, ly.capsule_radii / ly.height, atol=1e-3)
    assert BodyChoice.from_scores(scores, db_body, 1.77, sized=False).body is ly
    # a man of 2.02 m, taller than every model of the family (1.80 m at most), keeps his stature
    assert BodyChoice.from_scores(scores, db_body, 2.02).body.height == pytest.approx(2.02)
    # a measurement far beyond the scored models (a broken silhouette) is held near them
    assert BodyChoice.from_scores(scores, db_body, 2.6).body.height == pytest.approx(
        min(1.80 + SIZE_MARGIN_M, STATURE_RANGE_M[1]))
    assert BodyChoice.from_scores({"cPA": [0.2]}, db_body, 2.6).body.height == pytest.approx(
        body_model("cPA").body.height + SIZE_MARGIN_M)
    assert BodyChoice.from_scores({"cPA": [0.2]}, db_body, 0.5).body.height == pytest.approx(STATURE_RANGE_M[0])


def test_template_bottoms_at_every_level(small_db) -> None:  # type: ignore[no-untyped-def]
    db, *_ = small_db
    shapes = ((60, 80), (120, 160), (240, 320))
    for lvl, shape in enumerate(shapes):
        runs = db.level_runs[lvl]
        sub = RunSet([runs.runs(i) for i in range(min(40, len(runs)))] + [np.zeros((0, 3), np.int16)])
        got = template_bottoms(sub, db.level_scale[lvl])
        for i in range(len(sub) - 1):
            rows = np.flatnonzero(runs_to_mask(sub.runs(i), shape).any(axis=1))
            assert got[i] == pytest.approx((rows[-1] + 0.5) / db.level_scale[lvl] - 0.5)
        assert np.isnan(got[-1])
    assert [len(b) for b in db.level_bottom] == list(db.tree.level_sizes)


def test_a_leaping_template_gets_a_larger_predicted_scale(small_db) -> None:  # type: ignore[no-untyped-def]
    """Its feet are off the floor: the observed feet line must meet its own lowest row."""
    from tracker_service.estimators.tree_filter.filter import _node_predictions

    db, *_ = small_db
    lvl = db.tree.n_levels - 1
    b = db.level_bottom[lvl]
    standing, airborne = int(np.nanargmin(np.abs(b - db.ref_bottom))), int(np.nanargmin(b))
    assert b[airborne] < db.ref_bottom - 3
    obs = np.array([0.0, 0.0, 1.1])
    pred = _node_predictions(db, lvl, np.array([standing, airborne]), obs, 1.0, obs)[:, 0]
    cy = db.center[1]
    assert pred[0, 2] == pytest.approx(1.1 * (db.ref_bottom - cy) / (b[standing] - cy), rel=1e-9)
    assert pred[1, 2] == pytest.approx(1.1 * (db.ref_bottom - cy) / (b[airborne] - cy), rel=1e-9)
    assert pred[1, 2] > pred[0, 2]
    # no observation (feet out of view): the motion prediction for every node
    none = _node_predictions(db, lvl, np.array([standing, airborne]), obs, 0.0, None)
    np.testing.assert_array_equal(none[:, 0], np.repeat(obs[None], 2, axis=0))
    assert none.shape == (2, 1, 3)


def test_height_hypothesis_gives_the_silhouettes_height_and_lowest_row(small_db) -> None:  # type: ignore[no-untyped-def]
    """The second hypothesis scales each template to the observed height and puts its lowest row
    on the observed one (a body off the floor keeps its height; its feet line lies)."""
    from tracker_service.estimators.tree_filter.filter import _node_predictions

    db, *_ = small_db
    lvl = db.tree.n_levels - 1
    nodes = np.arange(0, len(db.level_bottom[lvl]), 7)
    rows = np.array([40.0, 190.0])
    obs = np.array([1.0, 0.0, 1.0])
    hyp = _node_predictions(db, lvl, nodes, obs, 0.7, obs, rows, (0.7, 1.3))
    assert hyp.shape == (len(nodes), 2, 3)
    top, bottom, cy = db.level_top[lvl][nodes], db.level_bottom[lvl][nodes], db.center[1]
    s = np.clip(150.0 / (bottom - top), 0.7, 1.3)
    np.testing.assert_allclose(hyp[:, 1, 2], s)
    ok = s == 150.0 / (bottom - top)
    assert ok.mean() > 0.9
    # a template row y is drawn at c_y + s (y - c_y) + dy: the lowest row lands on the observed one
    np.testing.assert_allclose((cy + hyp[:, 1, 2] * (bottom - cy) + hyp[:, 1, 1]), 190.0)
    np.testing.assert_allclose((cy + hyp[ok, 1, 2] * (top[ok] - cy) + hyp[ok, 1, 1]), 40.0)


def test_template_tops_at_every_level(small_db) -> None:  # type: ignore[no-untyped-def]
    db, *_ = small_db
    shapes = ((60, 80), (120, 160), (240, 320))
    for lvl, shape in enumerate(shapes):
        runs = db.level_runs[lvl]
        got = template_tops(runs, db.level_scale[lvl])
        for i in range(0, len(runs), max(1, len(runs) // 30)):
            rows = np.flatnonzero(runs_to_mask(runs.runs(i), shape).any(axis=1))
            assert got[i] == pytest.approx((rows[0] + 0.5) / db.level_scale[lvl] - 0.5)
        np.testing.assert_array_equal(got, db.level_top[lvl])
    mask = np.zeros((240, 320), bool)
    assert silhouette_rows(mask) is None
    mask[30:201, 100:140] = True
    np.testing.assert_array_equal(silhouette_rows(mask), [30.0, 200.0])


def test_feet_cut_off_by_the_image_border_measure_nothing() -> None:
    cam = default_camera()
    body = body_model("mMA").body
    mask = render_silhouette(fk(standing_pose(body), body), body.capsule_radii, cam)
    assert feet_in_view(mask) and observed_placement(mask, cam) is not None
    runs = mask_to_runs(mask)
    assert feet_scale(mask, runs, cam.cy) == pytest.approx(1.0)
    close = np.zeros_like(mask)
    close[40:] = mask[: mask.shape[0] - 40]  # the same person 40 px lower: the feet leave the image
    assert not feet_in_view(close)
    assert observed_placement(close, cam) is None
    assert feet_scale(close, runs, cam.cy) is None


def test_a_leap_moves_the_feet_line_not_the_height() -> None:
    """The same silhouette 12 px higher (the body off the floor): the feet line reads the person
    farther, the silhouette's height reads them where they are."""
    cam = default_camera()
    body = body_model("mMA").body
    mask = render_silhouette(fk(standing_pose(body), body), body.capsule_radii, cam)
    runs = mask_to_runs(mask)
    col = lower_body_column(mask)
    assert height_scale(mask, runs, col) == pytest.approx(1.0)
    leap = np.zeros_like(mask)
    leap[: mask.shape[0] - 12] = mask[12:]
    s_feet = feet_scale(leap, runs, cam.cy)
    assert s_feet is not None and s_feet < 0.9
    assert height_scale(leap, runs, col) == pytest.approx(1.0)
    half = mask[::2]  # a template half as tall: twice the scale
    assert height_scale(mask, mask_to_runs(half), lower_body_column(half)) == pytest.approx(2.0, rel=0.02)
    assert height_scale(np.zeros_like(mask), runs, col) is None and height_scale(mask, runs[:0], col) is None
    # a hand raised above the head beside it does not make the person taller
    waving = mask.copy()
    rows = np.flatnonzero(mask.any(axis=1))
    waving[rows[0] - 20: rows[0], int(col) + 25: int(col) + 29] = True
    assert height_scale(waving, runs, col) == pytest.approx(1.0)


def test_lower_body_column_equals_its_reference(rng: np.random.Generator) -> None:
    """The column histogram gives exactly ``np.median`` of the lower pixels' columns."""
    for i in range(400):
        h, w = rng.integers(1, 50, 2)
        m = rng.random((h, w)) < rng.random() * 0.5
        got, want = lower_body_column(m), lower_body_column_reference(m)
        assert (np.isnan(got) and np.isnan(want)) or got == want, (i, got, want)
    assert np.isnan(lower_body_column(np.zeros((4, 4), bool)))


def test_body_scores_search_once_per_height(small_db, monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[no-untyped-def]
    """Models of one height (``wMA``, ``wMB``: 1.58 m) get the same score from one search; another
    height (``mPA``: 1.60 m) its own."""
    import tracker_service.pipeline.body_selection as bs
    from tracker_service.estimators.tree_filter.filter import FilterParams
    from tracker_service.silhouette.features import preprocess

    db, body, motions, *_ = small_db
    cam = default_camera()
    mask = render_silhouette(fk(motions[0].poses[0], body), body.capsule_radii, cam)
    placed = observed_placement(mask, cam)
    assert placed is not None
    searches: list[float] = []
    real_step = bs.step

    def counted(state, *args):  # type: ignore[no-untyped-def]
        searches.append(float(state.placement[2]))
        return real_step(state, *args)

    monkeypatch.setattr(bs, "step", counted)
    names = ("wMA", "mPA", "wMB")
    scores = bs.score_bodies({"wMA": [0.5]}, preprocess(mask, "xor"), placed, db, body, cam, FilterParams(), names)
    assert len(searches) == 2 and searches[0] != searches[1]
    assert scores["wMA"][0] == 0.5 and scores["wMA"][1] == scores["wMB"][0] != scores["mPA"][0]
    assert all(np.isfinite(v).all() for v in scores.values())
