"""Body-normalised features: invariance to size, facing and position; height estimate; visibility."""

from __future__ import annotations

import math

import numpy as np
import pytest

from game_client.features import FeatureExtractor
from protocol.kinematics import fk
from protocol.skeleton import JOINT_INDEX, N_PARTS, PARTS, ROT_JOINTS, body_from_measurements, standing_pose


def _pose(height: float, l_sh_z: float = -80.0, r_sh_z: float = 80.0, yaw_deg: float = 0.0,
          at: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Joints (24, 3) of a standing body with the given shoulder angles, facing and ground position."""
    body = body_from_measurements(height)
    p = standing_pose(body)
    rot = p[3:].reshape(-1, 3)
    rot[ROT_JOINTS.index("l_shoulder")] = (0, 0, math.radians(l_sh_z))
    rot[ROT_JOINTS.index("r_shoulder")] = (0, 0, math.radians(r_sh_z))
    rot[0] = (0, math.radians(yaw_deg), 0)
    p[0], p[2] = at
    return fk(p, body)


def test_arm_features_do_not_depend_on_body_size_facing_or_position() -> None:
    ref = FeatureExtractor().update(0.0, _pose(1.70, 60.0, -20.0))
    for height, yaw, at in ((1.45, 0.0, (0.0, 0.0)), (1.95, 75.0, (2.0, -1.0)), (1.70, -140.0, (-3.0, 4.0))):
        f = FeatureExtractor().update(0.0, _pose(height, 60.0, -20.0, yaw, at))
        assert f.ok
        assert f.height == pytest.approx(height, rel=0.03)
        np.testing.assert_allclose(np.array(f.wrist_l), np.array(ref.wrist_l), atol=0.01)
        np.testing.assert_allclose(np.array(f.wrist_r), np.array(ref.wrist_r), atol=0.01)
        assert math.degrees(f.yaw) == pytest.approx(yaw, abs=1.0)


def test_wrist_heights_follow_the_arm() -> None:
    f = FeatureExtractor().update(0.0, _pose(1.70, 80.0, 80.0))  # left arm up, right arm down
    assert f.wrist_l is not None and f.wrist_r is not None
    assert f.wrist_l[1] > 0.25 and f.wrist_r[1] < -0.25
    t_pose = FeatureExtractor().update(0.0, _pose(1.70, 0.0, 0.0))
    assert t_pose.wrist_l is not None and t_pose.wrist_r is not None
    assert abs(t_pose.wrist_l[1]) < 0.02 and t_pose.wrist_l[0] > 0.4 and t_pose.wrist_r[0] > 0.4  # outward both


def test_elbow_bend_is_the_angle_between_upper_arm_and_forearm() -> None:
    """The elbow's flexion, whatever the arm's direction, the side and the facing (0 = straight)."""
    body = body_from_measurements(1.70)
    for bend, l_sh_z, yaw in ((0.0, 0.0, 0.0), (0.0, -80.0, 35.0), (30.0, -60.0, 0.0), (90.0, 0.0, -120.0),
                              (120.0, -80.0, 35.0)):
        p = standing_pose(body)
        rot = p[3:].reshape(-1, 3)
        rot[ROT_JOINTS.index("l_shoulder")] = (0, 0, math.radians(l_sh_z))
        rot[ROT_JOINTS.index("l_elbow")] = (0, math.radians(-bend), 0)
        rot[ROT_JOINTS.index("r_elbow")] = (0, math.radians(bend), 0)
        rot[0] = (0, math.radians(yaw), 0)
        f = FeatureExtractor().update(0.0, fk(p, body))
        assert f.bend_l == pytest.approx(bend, abs=1.0) and f.bend_r == pytest.approx(bend, abs=1.0)


def test_crouch_ratio_standing_is_one() -> None:
    f = FeatureExtractor().update(0.0, _pose(1.80))
    assert f.legs_ok and f.crouch == pytest.approx(1.0, abs=0.02)


def test_height_comes_from_bones_not_posture() -> None:
    """A player whose first frames are crouched is still measured at full height (bone lengths)."""
    body = body_from_measurements(1.62)
    p = standing_pose(body)
    rot = p[3:].reshape(-1, 3)
    for side in ("l", "r"):
        rot[ROT_JOINTS.index(f"{side}_hip")] = (math.radians(-80), 0, 0)
        rot[ROT_JOINTS.index(f"{side}_knee")] = (math.radians(110), 0, 0)
    f = FeatureExtractor().update(0.0, fk(p, body))
    assert f.height == pytest.approx(1.62, rel=0.03)
    assert f.crouch < 0.7


def test_occluded_parts_and_non_finite_joints_are_flagged() -> None:
    j = _pose(1.70)
    vis = np.ones(N_PARTS)
    vis[PARTS.index("l_forearm")] = 0.0
    f = FeatureExtractor().update(0.0, j, vis)
    assert f.ok and not f.arm_l_ok and f.arm_r_ok
    vis[PARTS.index("r_shin")] = 0.05
    f = FeatureExtractor().update(0.0, j, vis)
    assert not f.legs_ok and math.isnan(f.crouch) and f.ankle_l_xz is None
    bad = j.copy()
    bad[JOINT_INDEX["r_wrist"]] = np.nan
    f = FeatureExtractor().update(0.0, bad)
    assert f.ok and f.arm_l_ok and not f.arm_r_ok
    torso_hidden = np.ones(N_PARTS)
    torso_hidden[PARTS.index("torso")] = 0.0
    assert not FeatureExtractor().update(0.0, j, torso_hidden).ok


def test_shape_errors_are_reported() -> None:
    fx = FeatureExtractor()
    with pytest.raises(ValueError, match="joints"):
        fx.update(0.0, np.zeros((10, 3)))
    with pytest.raises(ValueError, match="visibility"):
        fx.update(0.0, _pose(1.7), np.ones(3))


def test_smoothing_is_rate_independent() -> None:
    """A step change reaches the same level after the same time at 15 and 120 Hz."""
    down, up = _pose(1.70, -80.0, 80.0), _pose(1.70, 80.0, -80.0)
    levels = []
    for hz in (15.0, 120.0):
        fx = FeatureExtractor()
        fx.update(0.0, down)
        f = None
        for k in range(1, int(0.2 * hz) + 1):
            f = fx.update(k / hz, up)
        assert f is not None and f.wrist_l is not None
        levels.append(f.wrist_l[1])
    assert levels[0] == pytest.approx(levels[1], abs=0.01)
