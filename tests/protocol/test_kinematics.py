import numpy as np
import pytest

from protocol import JOINT_NAMES, POSE_SIZE, ROT_JOINTS, default_body, fk, fk_global
from protocol.skeleton import JOINT_INDEX as J
from protocol.skeleton import PARENTS


def _pose(**joints_deg: tuple[float, float, float]) -> np.ndarray:
    p = np.zeros(POSE_SIZE)
    for name, rv in joints_deg.items():
        k = ROT_JOINTS.index(name)
        p[3 + 3 * k: 6 + 3 * k] = np.radians(rv)
    return p


def test_rest_pose_is_cumulative_offsets() -> None:
    b = default_body()
    joints = fk(np.zeros(POSE_SIZE), b)
    for j, name in enumerate(JOINT_NAMES):
        expected = np.zeros(3)
        k = j
        while k > 0:
            expected += b.offsets[k]
            k = PARENTS[k]
        np.testing.assert_allclose(joints[j], expected, atol=1e-12, err_msg=name)


def test_left_elbow_flexion_brings_forearm_forward() -> None:
    b = default_body()
    joints = fk(_pose(l_elbow=(0, -90, 0)), b)
    fore = np.linalg.norm(b.offsets[J["l_wrist"]])
    np.testing.assert_allclose(joints[J["l_wrist"]], joints[J["l_elbow"]] + [0, 0, fore], atol=1e-12)
    # the hand continues along the forearm
    hand = np.linalg.norm(b.offsets[J["l_hand_tip"]])
    np.testing.assert_allclose(joints[J["l_hand_tip"]], joints[J["l_wrist"]] + [0, 0, hand], atol=1e-12)


def test_knee_flexion_moves_shin_backwards_and_chains() -> None:
    b = default_body()
    joints = fk(_pose(l_hip=(-90, 0, 0), l_knee=(90, 0, 0)), b)
    thigh = np.linalg.norm(b.offsets[J["l_knee"]])
    shin = np.linalg.norm(b.offsets[J["l_ankle"]])
    hip = joints[J["l_hip"]]
    np.testing.assert_allclose(joints[J["l_knee"]], hip + np.array([0, 0, thigh]), atol=1e-12)  # thigh forward
    np.testing.assert_allclose(joints[J["l_ankle"]], hip + np.array([0, -shin, thigh]), atol=1e-12)  # shin down


def test_root_translation_and_heading() -> None:
    b = default_body()
    p = np.zeros(POSE_SIZE)
    p[:3] = [1.0, 2.0, 3.0]
    p[3:6] = [0, np.pi / 2, 0]  # turn left by 90 degrees: facing +X
    joints = fk(p, b)
    hip_off = b.offsets[J["l_hip"]][0]
    np.testing.assert_allclose(joints[J["pelvis"]], [1, 2, 3], atol=1e-12)
    np.testing.assert_allclose(joints[J["l_hip"]], [1, 2, 3 - hip_off], atol=1e-12)


def test_shoulder_lowering_arm() -> None:
    b = default_body()
    joints = fk(_pose(l_shoulder=(0, 0, -90), r_shoulder=(0, 0, 90)), b)
    for s in ("l_", "r_"):
        d = joints[J[s + "elbow"]] - joints[J[s + "shoulder"]]
        np.testing.assert_allclose(d / np.linalg.norm(d), [0, -1, 0], atol=1e-12)


def test_batch_equals_single_and_global_rotations(rng: np.random.Generator) -> None:
    b = default_body()
    poses = rng.normal(0, 0.4, (3000, POSE_SIZE))
    batch, rots = fk_global(poses, b)
    assert batch.shape == (3000, len(JOINT_NAMES), 3)
    for i in (0, 17, 2999):
        np.testing.assert_allclose(fk(poses[i], b), batch[i], atol=1e-12)
    # bone lengths are preserved by any pose
    for j in range(1, len(JOINT_NAMES)):
        d = np.linalg.norm(batch[:, j] - batch[:, PARENTS[j]], axis=-1)
        np.testing.assert_allclose(d, np.linalg.norm(b.offsets[j]), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(rots), 1.0, atol=1e-9)


def test_bad_shape_is_rejected() -> None:
    with pytest.raises(ValueError, match="shape"):
        fk(np.zeros((2, 7)), default_body())
