"""Pinhole camera: defaults of the paper's setup, projection against hand-computed points."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.kinematics import fk
from protocol.skeleton import ROT_JOINTS, standing_pose
from tracker_service.body.family import body_model
from tracker_service.body.raster import render_silhouette
from tracker_service.camera import Camera, default_camera, look_at


def test_default_camera_is_the_papers_setup() -> None:
    cam = default_camera()
    assert cam.size == (320, 240)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (262.5, 262.5, 159.5, 119.5)
    np.testing.assert_allclose(cam.position, [0.0, 1.2, 3.0])
    np.testing.assert_allclose(cam.pose[:3, 2], [0.0, 0.0, 1.0])  # looks along -Z
    big = default_camera(640, 480)
    assert (big.fx, big.cx, big.cy) == (525.0, 319.5, 239.5)
    with pytest.raises(ValueError, match="4:3"):
        default_camera(320, 200)


def test_projection_of_hand_computed_points() -> None:
    cam = default_camera()
    pts = np.array([[0.0, 1.2, 0.0], [0.3, 1.5, 0.0], [-0.6, 0.0, 1.0], [0.0, 1.2, 4.0]])
    uv, depth = cam.project_with_depth(pts)
    np.testing.assert_allclose(uv[0], [159.5, 119.5])
    np.testing.assert_allclose(uv[1], [159.5 + 262.5 * 0.3 / 3, 119.5 - 262.5 * 0.3 / 3])
    np.testing.assert_allclose(uv[2], [159.5 - 262.5 * 0.6 / 2, 119.5 + 262.5 * 1.2 / 2])
    np.testing.assert_allclose(depth[:3], [3.0, 3.0, 2.0])
    assert np.all(np.isnan(uv[3])) and depth[3] < 0  # behind the camera
    np.testing.assert_allclose(cam.K @ np.array([0.3, -0.3, 3.0]) / 3.0, [uv[1, 0], uv[1, 1], 1.0])


def test_projection_is_vectorised_and_consistent_with_to_camera() -> None:
    rng = np.random.default_rng(3)
    cam = default_camera().moved(look_at((1.0, 1.6, 2.5), (0.2, 0.9, 0.0)))
    pts = rng.uniform([-1, 0, -1], [1, 2, 1], (5, 24, 3))
    uv = cam.project(pts)
    assert uv.shape == (5, 24, 2)
    pc = cam.to_camera(pts)
    np.testing.assert_allclose(uv[..., 0], cam.cx + cam.fx * pc[..., 0] / -pc[..., 2])
    np.testing.assert_allclose(uv[..., 1], cam.cy - cam.fy * pc[..., 1] / -pc[..., 2])
    back = (cam.world_to_camera @ np.c_[pts.reshape(-1, 3), np.ones(120)].T).T[:, :3]
    np.testing.assert_allclose(back, pc.reshape(-1, 3), atol=1e-12)
    r = cam.pose[:3, :3]
    np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)


def test_look_at_points_the_optical_axis_at_the_target() -> None:
    pose = look_at((2.0, 1.0, 3.0), (0.0, 1.5, 0.0))
    cam = default_camera().moved(pose)
    np.testing.assert_allclose(cam.project(np.array([0.0, 1.5, 0.0])), [cam.cx, cam.cy], atol=1e-9)
    assert cam.project(np.array([0.0, 2.5, 0.0]))[1] < cam.cy  # world up is image up
    with pytest.raises(ValueError):
        look_at((0, 0, 0), (0, 0, 0))


def test_scaled_camera_keeps_pixel_centres() -> None:
    cam = default_camera()
    pts = np.array([[0.4, 1.7, 0.2], [-0.5, 0.1, -0.3]])
    for f in (0.25, 0.5, 2.0):
        s = cam.scaled(f)
        assert s.size == (round(320 * f), round(240 * f))
        np.testing.assert_allclose(s.project(pts), (cam.project(pts) + 0.5) * f - 0.5, atol=1e-9)
    shifted = cam.shifted(0.7, -0.4)
    np.testing.assert_allclose(shifted.project(pts), cam.project(pts) + np.array([0.7, -0.4]))


def test_radial_distortion() -> None:
    cam = default_camera(dist=(-0.2, 0.05))
    assert cam.has_distortion
    p = np.array([0.6, 1.8, 0.0])
    x, y = 0.6 / 3.0, -(1.8 - 1.2) / 3.0
    r2 = x * x + y * y
    s = 1 - 0.2 * r2 + 0.05 * r2 * r2
    np.testing.assert_allclose(cam.project(p), [159.5 + 262.5 * s * x, 119.5 + 262.5 * s * y])
    np.testing.assert_allclose(cam.project(np.array([0.0, 1.2, 0.0])), [159.5, 119.5])


def test_invalid_cameras_are_rejected() -> None:
    with pytest.raises(ValueError):
        Camera(0, 240, 100, 100, 0, 0)
    with pytest.raises(ValueError):
        Camera(320, 240, -1, 100, 0, 0)
    with pytest.raises(ValueError):
        Camera(320, 240, 100, 100, 0, 0, pose=np.diag([2.0, 1, 1, 1]))


def test_full_body_in_view_for_the_tallest_model_with_arms_up() -> None:
    cam = default_camera()
    for name in ("mTA", "cPA"):
        b = body_model(name).body
        pose = standing_pose(b)
        k_l, k_r = ROT_JOINTS.index("l_shoulder"), ROT_JOINTS.index("r_shoulder")
        pose[3 + 3 * k_l: 6 + 3 * k_l] = (0, 0, np.radians(80))  # both arms straight up
        pose[3 + 3 * k_r: 6 + 3 * k_r] = (0, 0, np.radians(-80))
        mask = render_silhouette(fk(pose, b), b.capsule_radii, cam)
        ys, xs = np.nonzero(mask)
        assert ys.min() > 2 and ys.max() < cam.height - 3, name
        assert xs.min() > 2 and xs.max() < cam.width - 3, name
