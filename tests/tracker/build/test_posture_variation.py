"""Posture variation of the network's training poses: stooped, knees bent, feet kept on the floor."""

import numpy as np
import pytest

from protocol.kinematics import fk
from protocol.skeleton import JOINT_INDEX, default_body, limit_violation_deg, standing_pose
from tracker_service.build.posture_variation import PostureParams, vary_posture

J = JOINT_INDEX


def _poses(n: int) -> np.ndarray:
    body = default_body()
    p = np.tile(standing_pose(body), (n, 1))
    p[:, 0] = np.linspace(-1.0, 1.0, n)  # walking across, facing +Z
    return p


def test_varied_frames_stoop_and_bend_the_knees_with_the_feet_on_the_floor() -> None:
    body = default_body()
    poses = _poses(40)
    out = vary_posture(poses, body, np.random.default_rng(3), PostureParams(share=1.0))
    a, b = fk(poses, body), fk(out, body)
    lean_a = a[:, J["neck"], 2] - a[:, J["pelvis"], 2]
    lean_b = b[:, J["neck"], 2] - b[:, J["pelvis"], 2]
    assert np.all(lean_b >= lean_a - 1e-9) and np.mean(lean_b - lean_a) > 0.05  # the trunk leans forward
    for side in "lr":  # the knee goes forward of the hip-ankle line, the pelvis drops
        knee_fwd = b[:, J[f"{side}_knee"], 2] - 0.5 * (b[:, J[f"{side}_hip"], 2] + b[:, J[f"{side}_ankle"], 2])
        assert np.all(knee_fwd >= -1e-9) and knee_fwd.max() > 0.1
    assert np.all(out[:, 1] <= poses[:, 1] + 1e-9) and np.max(poses[:, 1] - out[:, 1]) > 0.06
    feet = [J[n] for n in ("l_ankle", "r_ankle", "l_toe", "r_toe")]
    assert np.allclose(b[:, feet, 1].min(axis=1), a[:, feet, 1].min(axis=1))
    assert np.allclose(out[:, [0, 2, 3, 4, 5]], poses[:, [0, 2, 3, 4, 5]])  # root place and orientation kept
    assert limit_violation_deg(out).max() < 1e-6


def test_share_and_seed() -> None:
    body = default_body()
    poses = _poses(400)
    assert np.array_equal(vary_posture(poses, body, np.random.default_rng(0), PostureParams(share=0.0)), poses)
    out = vary_posture(poses, body, np.random.default_rng(0), PostureParams(share=0.5))
    changed = np.any(np.abs(out - poses) > 1e-12, axis=1)
    assert 0.4 < changed.mean() < 0.6
    again = vary_posture(poses, body, np.random.default_rng(0), PostureParams(share=0.5))
    assert np.array_equal(out, again)
    assert np.array_equal(poses, _poses(400))  # the input is not modified


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="share"):
        PostureParams(share=1.5)
    with pytest.raises(ValueError, match="knee_deg"):
        PostureParams(knee_deg=-1.0)
    with pytest.raises(ValueError, match="shape"):
        vary_posture(np.zeros((3, 7)), default_body(), np.random.default_rng(0))


def test_the_turns_are_about_the_parents_left_right_axis_of_any_recorded_pose() -> None:
    """On recorded rotations that are not the identity, each turned joint's new local rotation is a
    rotation about +X (the parent's left-right axis) times the recorded one, with the documented
    signs and proportions; the joints not turned are left exactly as recorded."""
    from protocol.rotations import rotvec_to_matrix
    from protocol.skeleton import ROT_JOINTS

    body = default_body()
    rng = np.random.default_rng(5)
    poses = _poses(30)
    poses[:, 3:] += rng.uniform(-0.25, 0.25, poses[:, 3:].shape)  # twisted, abducted, turned root
    out = vary_posture(poses, body, np.random.default_rng(9), PostureParams(share=1.0, trunk_deg=20.0, knee_deg=40.0))
    r0 = rotvec_to_matrix(poses[:, 3:].reshape(len(poses), -1, 3))
    r1 = rotvec_to_matrix(out[:, 3:].reshape(len(out), -1, 3))
    turned = ("spine", "chest", "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle")

    def angle_x(name: str) -> np.ndarray:
        k = ROT_JOINTS.index(name)
        d = r1[:, k] @ np.swapaxes(r0[:, k], 1, 2)  # the turn, applied before the recorded rotation
        assert np.allclose(d[:, 0], [1.0, 0.0, 0.0], atol=1e-9) and np.allclose(d[:, :, 0], [1.0, 0.0, 0.0], atol=1e-9)
        return np.arctan2(d[:, 2, 1], d[:, 1, 1])

    spine, chest = angle_x("spine"), angle_x("chest")
    assert np.all(spine >= 0) and np.allclose(spine * 0.4, chest * 0.6) and spine.max() <= np.radians(12.0) + 1e-9
    for side in "lr":
        knee, hip, ankle = angle_x(f"{side}_knee"), angle_x(f"{side}_hip"), angle_x(f"{side}_ankle")
        assert np.all(knee >= 0) and np.allclose(hip, -0.5 * knee) and np.allclose(ankle, -0.5 * knee)
    full = np.maximum(angle_x("l_knee"), angle_x("r_knee"))
    assert np.all(np.minimum(angle_x("l_knee"), angle_x("r_knee")) >= 0.6 * full - 1e-9)
    for k, name in enumerate(ROT_JOINTS[1:], start=1):
        if name not in turned:
            assert np.array_equal(out[:, 3 + 3 * k: 6 + 3 * k], poses[:, 3 + 3 * k: 6 + 3 * k]), name


def test_a_knee_bent_near_its_limit_is_clamped() -> None:
    from protocol.skeleton import ROT_JOINTS

    body = default_body()
    poses = _poses(20)
    k = ROT_JOINTS.index("l_knee")
    poses[:, 3 + 3 * k] = np.radians(160.0)  # the limit is 170 degrees
    out = vary_posture(poses, body, np.random.default_rng(1), PostureParams(share=1.0, knee_deg=70.0))
    assert limit_violation_deg(out).max() < 1e-6
    assert np.degrees(out[:, 3 + 3 * k]).max() == pytest.approx(170.0)
