"""The per-frame pipeline (phases, body selection, outputs) on frames painted from capsule
silhouettes over a textured room, with the small fixture database."""

import cv2
import numpy as np
import pytest

from protocol import fk
from protocol.motion import ground
from protocol.skeleton import JOINT_INDEX
from tracker_service.body_models import body_model
from tracker_service.camera import default_camera
from tracker_service.pipeline import TrackerConfig, new_state, process_frame
from tracker_service.silhouette_render import render_silhouette
from tracker_service.template_db import load_db


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


def test_phases_and_outputs(small_db, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    _, _, motions, _, path = small_db
    loaded = load_db(path)
    cam = loaded.camera
    room = _room(rng, cam)
    subject = body_model("mLA").body
    truth = fk(ground(motions[0].poses, subject), subject)  # feet on the floor for this body
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
    for f in range(0, 40, 2):
        mask = render_silhouette(truth[f], subject.capsule_radii, cam)
        st, res = process_frame(st, _frame(room, mask, rng), loaded.db, loaded.body, cam, cfg)
        phases.append(res.phase)
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


def test_bad_frame_is_rejected(small_db) -> None:  # type: ignore[no-untyped-def]
    _, _, _, _, path = small_db
    loaded = load_db(path)
    st = new_state(loaded.body)
    with pytest.raises(ValueError, match="frame must be"):
        process_frame(st, np.zeros((10, 10, 3), np.uint8), loaded.db, loaded.body, loaded.camera, TrackerConfig())
    with pytest.raises(ValueError, match="frame must be"):
        process_frame(st, np.zeros((240, 320), np.uint8), loaded.db, loaded.body, loaded.camera, TrackerConfig())
    assert default_camera().width == 320 and cv2 is not None
