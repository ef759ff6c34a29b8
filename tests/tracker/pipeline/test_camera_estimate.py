"""The camera's tilt and roll from the room's verticals, its height from a standing person."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tracker_service.camera import Camera, placed_camera
from tracker_service.pipeline.camera_estimate import CameraEstimate, camera_height, level_tilt


def _rolled(cam: Camera, roll_deg: float) -> Camera:
    """``cam`` turned about its optical axis by ``roll_deg``."""
    r = math.radians(roll_deg)
    rz = np.array([[math.cos(r), -math.sin(r), 0, 0], [math.sin(r), math.cos(r), 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    return cam.moved(cam.pose @ rz)


def _room_verticals(cam: Camera, rng: np.random.Generator, n: int = 12) -> np.ndarray:
    """Projected vertical edges 0.3-2.0 m tall standing 1-4 m behind the person's spot."""
    segs = []
    while len(segs) < n:
        x, z = rng.uniform(-2.5, 2.5), rng.uniform(-4.0, -1.0)
        y0 = rng.uniform(0.0, 1.0)
        p = cam.project(np.array([[x, y0, z], [x, y0 + rng.uniform(0.6, 1.5), z]]))
        if np.all((p >= 0) & (p < [cam.width, cam.height])):
            segs.append(p.reshape(-1))
    return np.asarray(segs) + rng.normal(0, 0.3, (n, 4))


@pytest.mark.parametrize(("height", "tilt", "roll"), [(1.2, 0.0, 0.0), (1.8, 15.0, 0.0), (0.8, -5.0, 0.0),
                                                      (1.5, 10.0, 4.0), (1.0, 20.0, -3.0)])
def test_tilt_and_roll_from_the_rooms_verticals(height: float, tilt: float, roll: float,
                                                rng: np.random.Generator) -> None:
    cam = _rolled(placed_camera(height_m=height, tilt_deg=tilt), roll)
    assert cam.tilt_deg == pytest.approx(tilt, abs=1e-6) and cam.roll_deg == pytest.approx(roll, abs=1e-6)
    t, r = level_tilt(_room_verticals(cam, rng), cam)
    assert t == pytest.approx(tilt, abs=1.0) and r == pytest.approx(roll, abs=1.0)  # 0.3 px endpoint noise


def test_too_few_verticals_give_no_tilt() -> None:
    cam = placed_camera()
    assert all(math.isnan(v) for v in level_tilt(np.zeros((2, 4)), cam))


@pytest.mark.parametrize(("height", "tilt"), [(1.2, 0.0), (1.8, 15.0), (0.8, -5.0), (2.2, 25.0)])
def test_height_from_a_standing_person(height: float, tilt: float) -> None:
    cam = placed_camera(height_m=height, tilt_deg=tilt)
    stature = 1.64
    feet, head = cam.project(np.array([[0.0, 0.0, 0.0], [0.0, stature, 0.0]]))
    assert camera_height(feet[1], head[1], cam, tilt, stature) == pytest.approx(height, rel=1e-6)
    # a wrong stature scales the height in proportion
    assert camera_height(feet[1], head[1], cam, tilt, 1.70) == pytest.approx(height * 1.70 / stature, rel=1e-6)


def test_feet_above_the_horizon_give_no_height() -> None:
    cam = placed_camera()
    assert math.isnan(camera_height(10.0, 5.0, cam, 0.0))


def test_estimate_reports_only_what_was_measured() -> None:
    assert CameraEstimate().as_dict() == {}
    assert CameraEstimate(tilt_deg=3.0, roll_deg=0.5, segments=9).as_dict() == {"tilt_deg": 3.0, "roll_deg": 0.5}
    assert CameraEstimate(tilt_deg=3.0, roll_deg=0.0, height_m=1.4).as_dict()["stature_m"] == 1.7


def test_rows_height_and_the_difference_from_the_working_camera() -> None:
    from tracker_service.pipeline.camera_estimate import differs, silhouette_rows, with_height

    cam = placed_camera(height_m=1.6, tilt_deg=12.0)
    feet, head = cam.project(np.array([[0.0, 0.0, 0.0], [0.0, 1.70, 0.0]]))
    mask = np.zeros((240, 320), bool)
    mask[round(float(head[1]) + 0.5): round(float(feet[1]) - 0.5), 150:170] = True
    rows = silhouette_rows(mask)
    assert rows is not None and abs(rows[0] - feet[1]) <= 1.0 and abs(rows[1] - head[1]) <= 1.0
    assert silhouette_rows(np.zeros((4, 4), bool)) is None
    est = with_height(CameraEstimate(tilt_deg=12.0, roll_deg=0.0, segments=8), [rows] * 3, cam)
    assert est.height_m == pytest.approx(1.6, abs=0.03)
    assert not differs(est, cam)
    assert differs(est, placed_camera())  # the default camera: 1.2 m, level
    # a height 17 cm off for an assumed stature is what a 1.50 m or 1.95 m person gives: no warning
    level = CameraEstimate(tilt_deg=0.0, roll_deg=0.0, height_m=1.37, segments=8)
    assert differs(level, placed_camera()) and not differs(level, placed_camera(), stature_known=False)
    assert differs(replace(level, height_m=1.6), placed_camera(), stature_known=False)
    assert with_height(CameraEstimate(), [rows], cam) == CameraEstimate()  # no tilt, no height


@pytest.mark.slow
def test_the_tracker_measures_a_camera_it_was_not_told_about(small_db, mocap_dir, caplog) -> None:  # type: ignore[no-untyped-def]
    """The scene filmed 1.8 m high, 15 degrees down; the tracker assumes its default camera (1.2 m,
    level): it measures the tilt from the room and warns once initialised."""
    import logging

    from protocol.formats.load import load_motion
    from tracker_service.pipeline.process import TrackerConfig, new_state, process_frame
    from tracker_service.scene.synthetic import SceneConfig, SyntheticScene
    from tracker_service.templates.database import load_db

    loaded = load_db(small_db[-1])
    motion = load_motion(mocap_dir / "bandai" / "dataset-2_raise-up-both-hands_normal_001.bvh", fps=30.0)
    scene = SyntheticScene(motion, seed=1, config=SceneConfig(fps=30.0, empty_prefix=10,
                                                             camera=placed_camera(height_m=1.8, tilt_deg=15.0)))
    cfg = TrackerConfig(distance="xor", background_frames=10)
    state = new_state(loaded.body)
    try:
        with caplog.at_level(logging.INFO, logger="tracker_service.pipeline.process"):
            for i in range(24):
                fr = scene.frame(i)
                state, _ = process_frame(state, fr.image, loaded.db, loaded.body, loaded.camera, cfg, fr.timestamp)
    finally:
        scene.close()
    est = state.camera_estimate
    assert est is not None and est.tilt_deg == pytest.approx(15.0, abs=3.0) and est.segments >= 4
    assert state.phase == "tracking" and est.height_m == pytest.approx(1.8, abs=0.3)  # stature 1.70 assumed
    assert any("camera seems not to be where" in r.getMessage() for r in caplog.records)
