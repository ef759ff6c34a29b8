"""The per-frame pipeline (phases, body selection, outputs) on frames painted from capsule
silhouettes over a textured room, with the small fixture database."""

import cv2
import numpy as np
import pytest
from conftest import constant_reading_net

from protocol import fk
from protocol.motion import ground
from protocol.skeleton import JOINT_INDEX, ROT_SLOT, Body, standing_pose
from tracker_service.body.family import body_model
from tracker_service.body.measured import given_body
from tracker_service.body.raster import render_silhouette
from tracker_service.camera import default_camera
from tracker_service.cues.appearance import camera_joints
from tracker_service.pipeline.process import TrackerConfig, new_state, process_frame
from tracker_service.templates.database import load_db


def _room(rng: np.random.Generator, cam) -> np.ndarray:  # type: ignore[no-untyped-def]
    img = np.zeros((cam.height, cam.width, 3), np.float32)
    img[:] = (170, 175, 160)
    img[cam.height // 2:] = (90, 110, 140)
    for _ in range(8):
        x, y = rng.integers(0, cam.width - 40), rng.integers(0, cam.height - 40)
        img[y: y + 35, x: x + 38] = rng.uniform(40, 220, 3)
    return img


def _frame(room: np.ndarray, mask: np.ndarray | None, rng: np.random.Generator) -> np.ndarray:
    img = room.copy()
    if mask is not None:
        img[mask] = (40, 60, 200)
    return np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)


def _scene(small_db, rng: np.random.Generator, subject: Body):  # type: ignore[no-untyped-def]
    """The fixture database, its camera, a room and the first motion's joints on ``subject``."""
    _, _, motions, _, path = small_db
    loaded = load_db(path)
    truth = fk(ground(motions[0].poses, subject), subject)  # feet on the floor for this body
    return loaded, loaded.camera, _room(rng, loaded.camera), truth


def test_phases_and_outputs(small_db, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    subject = body_model("mLA").body
    loaded, cam, room, truth = _scene(small_db, rng, subject)
    cfg = TrackerConfig(background_frames=8, body_candidates=("mSA", "mMA", "mLA", "mTA"), init_frames=3)
    st = new_state(loaded.body)
    phases = []
    for _ in range(8):  # empty room: learn the background
        st, res = process_frame(st, _frame(room, None, rng), loaded.db, loaded.body, cam, cfg)
        phases.append(res.phase)
        assert res.pose is None
    assert phases[-1] == "waiting" and st.background is not None
    # a person far off-centre: still waiting
    off = np.roll(render_silhouette(truth[0], subject.capsule_radii, cam), 110, axis=1)
    st, res = process_frame(st, _frame(room, off, rng), loaded.db, loaded.body, cam, cfg)
    assert res.phase == "waiting" and res.silhouette is not None and res.silhouette.any()
    errs = []
    for k, f in enumerate(range(0, 40, 2)):
        mask = render_silhouette(truth[f], subject.capsule_radii, cam)
        st, res = process_frame(st, _frame(room, mask, rng), loaded.db, loaded.body, cam, cfg)
        phases.append(res.phase)
        if k < cfg.confirm_frames - 1:  # the first good poses after learning the room are held back
            assert res.pose is None and res.rejected == "confirming"
            continue
        assert res.pose is not None and res.joints is not None
        assert np.all(np.isfinite(res.joints))
        assert 0.0 <= res.confidence <= 1.0
        assert set(res.stage_ms) >= {"background", "preprocess", "estimate", "total"}
        iou = (res.silhouette & mask).sum() / (res.silhouette | mask).sum()
        assert iou > 0.9
        j = res.joints
        errs.append(np.linalg.norm((j - j[0]) - (truth[f] - truth[f, 0]), axis=1).mean())
        assert np.linalg.norm(j[JOINT_INDEX["pelvis"]] - truth[f, 0]) < 0.3
    assert "initialising" in phases and phases[-1] == "tracking"
    assert st.body.name in ("mMA", "mLA", "mTA")  # body selection picks a model of about the right size
    assert np.median(errs) < 0.10


def test_the_stature_is_measured_under_a_raised_hand(small_db, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    """A tall man waving with a hand above his head through the whole initialisation: the stature
    is measured on every frame (it once measured none: the head was never the silhouette's
    top) from the silhouette's top down to the head's, as the network reads the pose."""
    subject = body_model("mTA").body
    loaded, cam, room, _ = _scene(small_db, rng, subject)
    pose = standing_pose(subject)
    slot = ROT_SLOT[JOINT_INDEX["l_shoulder"]]
    pose[3 + 3 * slot: 6 + 3 * slot] = [0.0, 0.0, 2.0]  # the left hand high above the head
    joints = fk(pose, subject)
    assert int(np.argmax(joints[:, 1])) == JOINT_INDEX["l_hand_tip"]
    net = constant_reading_net(camera_joints(joints, cam, subject.height), -8.0)  # sure of it
    cfg = TrackerConfig(background_frames=6, init_frames=4, body_candidates=("mMA", "mLA", "mTA"), appearance=net,
                        appearance_mirror=False)  # (a constant reading mirrored would be another pose)
    st = new_state(loaded.body)
    for _ in range(6):
        st, res = process_frame(st, _frame(room, None, rng), loaded.db, loaded.body, cam, cfg)
    mask = render_silhouette(joints, subject.capsule_radii, cam)
    for _ in range(6):
        st, res = process_frame(st, _frame(room, mask, rng), loaded.db, loaded.body, cam, cfg)
    assert res.phase == "tracking"
    assert len(st.statures) == cfg.init_frames  # every initialisation frame
    assert np.median(st.statures) == pytest.approx(subject.height, abs=0.04)
    assert st.body.height >= 1.75  # the tall models only (the hand's 2.2 m would leave just mTA too)


def test_a_given_body_is_used_after_the_initialisation(small_db, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    given = given_body({"height": 1.76, "group": "men", "leg": 1.05, "arm": 0.95})
    loaded, cam, room, truth = _scene(small_db, rng, given)
    cfg = TrackerConfig(background_frames=6, init_frames=3, body=given)
    st = new_state(loaded.body)
    for _ in range(6):
        st, res = process_frame(st, _frame(room, None, rng), loaded.db, loaded.body, cam, cfg)
    changed = []
    for f in range(0, 16, 2):
        mask = render_silhouette(truth[f], given.capsule_radii, cam)
        st, res = process_frame(st, _frame(room, mask, rng), loaded.db, loaded.body, cam, cfg)
        changed.append(res.body_changed)
    assert res.phase == "tracking" and changed.count(True) == 1
    assert st.body is given and st.body_scale == pytest.approx(1.76 / loaded.body.height)
    j = res.joints  # the published skeleton is the given body's
    assert j is not None
    for a, b in (("l_hip", "l_knee"), ("r_knee", "r_ankle"), ("l_shoulder", "l_elbow")):
        bone = np.linalg.norm(j[JOINT_INDEX[b]] - j[JOINT_INDEX[a]])
        assert bone == pytest.approx(given.bone_lengths[JOINT_INDEX[b]], abs=1e-6)
    # the root is raised for the longer legs: the feet stay on the floor, not 4 cm through it
    feet = [JOINT_INDEX[n] for n in ("l_ankle", "l_toe", "r_ankle", "r_toe")]
    assert abs(j[feet, 1].min() - truth[14][feet, 1].min()) < 0.02
    with pytest.raises(ValueError, match="not both"):
        TrackerConfig(body=given, body_candidates=("mMA",))


def test_the_shoes_colour_is_learned_while_initialising(small_db, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    subject = body_model("mMA").body
    loaded, cam, room, truth = _scene(small_db, rng, subject)
    cfg = TrackerConfig(background_frames=6, init_frames=3)
    for shod in (False, True):
        st = new_state(loaded.body)
        for _ in range(6):
            st, _res = process_frame(st, _frame(room, None, rng), loaded.db, loaded.body, cam, cfg)
        for f in range(0, 12, 2):
            mask = render_silhouette(truth[f], subject.capsule_radii, cam)
            img = _frame(room, mask, rng)
            if shod:  # the lowest rows of the person in another colour
                ys = np.flatnonzero(mask.any(axis=1))
                low = mask.copy()
                low[: ys[-1] - 4] = False
                img[low] = (20, 220, 230)
            st, res = process_frame(st, img, loaded.db, loaded.body, cam, cfg)
        assert res.phase == "tracking" and res.joints is not None and np.all(np.isfinite(res.joints))
        if shod:
            assert st.shoes is not None and np.allclose(st.shoes.mean, (20, 220, 230), atol=12)
        else:
            assert st.shoes is None  # shoes the colour of the legs: the cue is off


def _shod(room: np.ndarray, mask: np.ndarray, rng: np.random.Generator, shoes: tuple[int, int, int]) -> np.ndarray:
    img = _frame(room, mask, rng)
    ys = np.flatnonzero(mask.any(axis=1))
    low = mask.copy()
    low[: ys[-1] - 4] = False
    img[low] = shoes
    return img


def test_the_shoe_cue_weighs_the_filter_and_the_published_legs(small_db, rng: np.random.Generator,
                                                                monkeypatch) -> None:  # type: ignore[no-untyped-def]
    import tracker_service.pipeline.observe as observe_stage
    import tracker_service.pipeline.publish as publish_stage
    from tracker_service.cues.shoes import ShoeParams
    from tracker_service.estimators.tree_filter.model import FilterParams

    subject = body_model("mMA").body
    loaded, cam, room, truth = _scene(small_db, rng, subject)
    empty = [_frame(room, None, rng) for _ in range(6)]
    masks = [render_silhouette(truth[f], subject.capsule_radii, cam) for f in range(0, 40, 2)]
    frames = empty + [_shod(room, m, rng, (20, 220, 230)) for m in masks]
    calls: list[np.ndarray] = []
    real = observe_stage.feet_cost

    def recording(shoes, feet, params, shape=None):  # type: ignore[no-untyped-def]
        calls.append(feet.copy())
        return real(shoes, feet, params, shape)

    def run(cfg: TrackerConfig) -> tuple[list[np.ndarray], list[np.ndarray]]:
        st = new_state(loaded.body)
        poses, weights = [], []
        for i, img in enumerate(frames):
            st, res = process_frame(st, img, loaded.db, loaded.body, cam, cfg, i / 30)
            if res.phase == "tracking" and res.pose is not None:
                poses.append(res.pose.copy())
                weights.append(np.sort(st.filter.weights))
        assert st.shoes is not None and len(poses) >= 10
        return poses, weights

    monkeypatch.setattr(observe_stage, "feet_cost", recording)  # the filter's leaf cost
    monkeypatch.setattr(publish_stage, "feet_cost", recording)  # the published legs
    base = TrackerConfig(background_frames=6, init_frames=3)
    poses, weights = run(base)
    # the cue is computed on feet placed where the templates stand: within the person's box
    assert calls
    bottom = max(int(np.flatnonzero(m.any(axis=1))[-1]) for m in masks)
    for feet in calls:  # (K, 2 feet, (u, v))
        assert bottom - 40 < np.median(feet[..., 1]) < bottom + 15
    # each use of the cue changes what it should: the filter's weights, the published legs
    _, w_nof = run(TrackerConfig(background_frames=6, init_frames=3, filter=FilterParams(shoe_weight=0.0)))
    p_nol, w_nol = run(TrackerConfig(background_frames=6, init_frames=3, shoes=ShoeParams(weight=0.0)))
    assert any(a.shape != b.shape or not np.allclose(a, b) for a, b in zip(weights, w_nof, strict=True))
    assert all(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(weights, w_nol, strict=True))
    assert any(not np.allclose(a[3:], b[3:]) for a, b in zip(poses, p_nol, strict=True))


def test_the_shoe_model_is_relearned_when_the_person_comes_back(small_db, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    subject = body_model("mMA").body
    loaded, cam, room, truth = _scene(small_db, rng, subject)
    cfg = TrackerConfig(background_frames=6, init_frames=3)
    st = new_state(loaded.body)
    for _ in range(6):
        st, _ = process_frame(st, _frame(room, None, rng), loaded.db, loaded.body, cam, cfg)
    masks = [render_silhouette(truth[f], subject.capsule_radii, cam) for f in range(0, 16, 2)]
    for m in masks:
        st, res = process_frame(st, _shod(room, m, rng, (20, 220, 230)), loaded.db, loaded.body, cam, cfg)
    assert res.phase == "tracking" and st.shoes is not None and np.allclose(st.shoes.mean, (20, 220, 230), atol=12)
    for _ in range(3):  # the person leaves
        st, res = process_frame(st, _frame(room, None, rng), loaded.db, loaded.body, cam, cfg)
    assert res.phase == "waiting"
    st, res = process_frame(st, _shod(room, masks[0], rng, (230, 40, 30)), loaded.db, loaded.body, cam, cfg)
    assert res.phase == "initialising" and st.shoes is None  # the old colour is forgotten
    for m in masks[1:]:
        st, res = process_frame(st, _shod(room, m, rng, (230, 40, 30)), loaded.db, loaded.body, cam, cfg)
    assert res.phase == "tracking" and st.shoes is not None and np.allclose(st.shoes.mean, (230, 40, 30), atol=12)


def test_bad_frame_is_rejected(small_db) -> None:  # type: ignore[no-untyped-def]
    _, _, _, _, path = small_db
    loaded = load_db(path)
    st = new_state(loaded.body)
    with pytest.raises(ValueError, match="frame must be"):
        process_frame(st, np.zeros((10, 10, 3), np.uint8), loaded.db, loaded.body, loaded.camera, TrackerConfig())
    with pytest.raises(ValueError, match="frame must be"):
        process_frame(st, np.zeros((240, 320), np.uint8), loaded.db, loaded.body, loaded.camera, TrackerConfig())
    assert default_camera().width == 320 and cv2 is not None


def test_feet_cut_off_by_the_border_bound_the_depth_by_the_last_feet_line() -> None:
    from tracker_service.pipeline.observe import FEET_CUT_TOLERANCE, nearest_scale

    mask = np.zeros((240, 320), bool)
    mask[60:200, 140:180] = True  # feet in view: the feet line measures, no bound
    assert nearest_scale(mask, 1.05, 0.95) is None
    mask[200:240, 150:170] = True  # the legs run off the bottom border
    assert nearest_scale(mask, None, 0.95) is None  # feet never seen: nothing to bound by
    assert nearest_scale(mask, 1.05, 0.95) == pytest.approx(0.95 * 1.05 * (1.0 - FEET_CUT_TOLERANCE))
