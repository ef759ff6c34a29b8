"""The appearance network's reading turned from a level camera's axes into a tilted or rolled
camera's (:mod:`tracker_service.cues.level_frame`), and its wiring into the pipeline."""

from __future__ import annotations

import numpy as np
from conftest import constant_reading_net

from protocol.skeleton import N_JOINTS
from tracker_service.camera import Camera, default_camera, look_at, placed_camera
from tracker_service.cues.appearance import camera_joints, predict_joints
from tracker_service.cues.level_frame import level_to_camera, rotate_reading


def _rx(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])


def test_a_level_camera_needs_no_rotation() -> None:
    """The default camera, and a level one at another height, distance or lens: None (the reading
    is used as it is, bit for bit)."""
    assert level_to_camera(default_camera()) is None
    assert level_to_camera(placed_camera(height_m=1.6, distance_m=4.0, hfov_deg=50.0)) is None


def test_a_tilted_camera_turns_the_reading_about_its_x_axis_by_the_tilt() -> None:
    for tilt in (15.0, -5.0, 20.0):
        m = level_to_camera(placed_camera(height_m=1.2, tilt_deg=tilt))
        assert m is not None
        assert np.allclose(m, _rx(tilt), atol=1e-12)


def test_the_level_frame_is_the_cameras_heading_with_the_worlds_up() -> None:
    """For any camera pose, up in the level frame is the world's up seen from the camera, and the
    level frame's z axis is horizontal: a body upright in the world reads upright in the level frame
    whatever the camera's tilt and roll, and the camera's joints are the level reading turned by M."""
    cam = placed_camera(height_m=1.7, tilt_deg=12.0)
    rolled = cam.moved(look_at((0.8, 1.7, 3.0), (0.0, 1.0, 0.0), up=(0.2, 1.0, 0.0)))
    assert abs(rolled.roll_deg) > 3.0
    for c in (cam, rolled):
        m = level_to_camera(c)
        assert m is not None
        assert np.allclose(m.T @ m, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(m), 1.0)
        r = c.pose[:3, :3]
        assert np.allclose(m @ [0.0, 1.0, 0.0], r.T @ [0.0, 1.0, 0.0], atol=1e-12)
        level_z_world = r @ (m @ [0.0, 0.0, 1.0])
        assert abs(level_z_world[1]) < 1e-12
        # world joints in the camera's axes (what the leaves are scored in) = M @ the level frame's
        rng = np.random.default_rng(3)
        joints = rng.normal(0.0, 0.4, (N_JOINTS, 3))
        level_cam = c.moved(c.pose @ np.block([[m, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]]))
        assert level_to_camera(level_cam) is None
        in_level = camera_joints(joints, level_cam, 1.7).astype(np.float64)
        in_camera = camera_joints(joints, c, 1.7).astype(np.float64)
        assert np.allclose(in_level @ m.T, in_camera, atol=1e-6)


def test_rotate_reading_keeps_distances_and_total_variance(rng: np.random.Generator) -> None:
    mu = rng.normal(0.0, 0.2, (N_JOINTS, 3))
    var = rng.uniform(1e-4, 1e-2, (N_JOINTS, 3))
    m = _rx(15.0)
    got_mu, got_var = rotate_reading(mu, var, m)
    assert np.allclose(np.linalg.norm(got_mu[1:] - got_mu[:1], axis=1), np.linalg.norm(mu[1:] - mu[:1], axis=1))
    assert np.allclose(got_var.sum(axis=1), var.sum(axis=1))
    assert np.allclose(got_var[:, 0], var[:, 0])  # x is the axis of the turn
    assert np.allclose(got_mu, (m @ mu.T).T)
    same_mu, same_var = rotate_reading(mu, var, np.eye(3))
    assert np.array_equal(same_mu, mu) and np.array_equal(same_var, var)


def test_predict_joints_turns_its_pooled_reading(rng: np.random.Generator) -> None:
    """With a tilted ``camera``: the pooled reading (mirrored views included) turned into the
    camera's axes; with a level one, or none, the reading as it is."""
    mu = rng.normal(0.0, 0.2, (N_JOINTS, 3))
    net = constant_reading_net(mu, log_var=-6.0)
    frame = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
    mask = np.zeros((240, 320), bool)
    mask[60:200, 140:180] = True
    cam = placed_camera(height_m=0.8, tilt_deg=-10.0)
    level = predict_joints(net, frame, mask, mirror=True)
    turned = predict_joints(net, frame, mask, mirror=True, camera=cam)
    same = predict_joints(net, frame, mask, mirror=True, camera=default_camera())
    assert level is not None and turned is not None and same is not None
    want = rotate_reading(*level, _rx(-10.0))
    assert np.allclose(turned[0], want[0], atol=1e-9) and np.allclose(turned[1], want[1], atol=1e-12)
    assert np.array_equal(same[0], level[0]) and np.array_equal(same[1], level[1])


def _pole_mask(camera: Camera, x: float) -> np.ndarray:
    """A vertical pole from the floor to 1.7 m at ``(x, 0)``, 0.3 m wide, as ``camera`` sees it."""
    import cv2

    ys = np.linspace(0.0, 1.7, 30)
    pts = np.stack([np.full_like(ys, x), ys, np.zeros_like(ys)], axis=1)
    uv = camera.project(pts)
    mask = np.zeros((camera.height, camera.width), np.uint8)
    cv2.polylines(mask, [np.round(uv).astype(np.int32)], False, 1, thickness=9)
    return mask.astype(bool)


def _lean(crop_mask: np.ndarray) -> float:
    """The slope (columns per row) of a crop's mask: 0 for an upright pole."""
    v, u = np.nonzero(crop_mask)
    return float(np.polyfit(v, u, 1)[0])


def test_the_crop_is_turned_upright_on_a_rolled_or_tilted_camera() -> None:
    """A pole upright in the world is upright in the crop whatever the camera's roll and tilt (as
    every training view was); without the camera it leans with the roll. A level camera's crop is
    the plain one, bit for bit."""
    from tracker_service.cues.appearance import person_crop

    base = placed_camera(height_m=1.2, tilt_deg=0.0)
    a = np.radians(12.0)
    roll = np.array([[np.cos(a), -np.sin(a), 0.0, 0.0], [np.sin(a), np.cos(a), 0.0, 0.0], [0, 0, 1, 0], [0, 0, 0, 1]])
    rolled = base.moved(base.pose @ roll)
    assert abs(abs(rolled.roll_deg) - 12.0) < 1e-9
    tilted = placed_camera(height_m=1.8, tilt_deg=20.0)
    frame = np.full((240, 320, 3), 128, np.uint8)
    for cam, x in ((rolled, 0.0), (tilted, 1.0)):
        mask = _pole_mask(cam, x)
        plain = person_crop(frame, mask, 64)
        upright = person_crop(frame, mask, 64, cam)
        assert plain is not None and upright is not None
        assert abs(_lean(upright[1])) < 0.02
        if cam is rolled:
            assert abs(_lean(plain[1])) > 0.15
    mask = _pole_mask(base, 0.4)
    plain, same = person_crop(frame, mask, 64), person_crop(frame, mask, 64, base)
    assert plain is not None and same is not None
    assert np.array_equal(plain[0], same[0]) and np.array_equal(plain[1], same[1])
