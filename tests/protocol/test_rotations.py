import numpy as np
import pytest

from protocol.rotations import (
    axis_rotation,
    euler_to_matrix,
    matrix_to_euler,
    matrix_to_quat,
    matrix_to_rotvec,
    quat_slerp,
    quat_to_matrix,
    quat_to_rotvec,
    rotation_angle_between,
    rotvec_to_matrix,
    rotvec_to_quat,
    two_axis_frame,
)


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"])
def test_euler_round_trip_every_order(order: str, rng: np.random.Generator) -> None:
    a = rng.uniform(-np.pi, np.pi, (500, 3))
    a[:, 1] = rng.uniform(-1.5, 1.5, 500)
    m = euler_to_matrix(a, order)
    back = matrix_to_euler(m, order)
    np.testing.assert_allclose(euler_to_matrix(back, order), m, atol=1e-12)
    np.testing.assert_allclose(back, a, atol=1e-9)


def test_euler_matches_hand_computed_product() -> None:
    m = euler_to_matrix(np.radians([90.0, 0.0, 0.0]), "ZXY")
    np.testing.assert_allclose(m @ [1, 0, 0], [0, 1, 0], atol=1e-12)  # Z by 90: x -> y
    m = euler_to_matrix(np.radians([90.0, 90.0, 0.0]), "ZXY")  # Rz(90) @ Rx(90)
    np.testing.assert_allclose(m @ [0, 1, 0], axis_rotation("Z", np.pi / 2) @ [0, 0, 1], atol=1e-12)


def test_gimbal_lock_still_reconstructs() -> None:
    m = euler_to_matrix([0.3, np.pi / 2, 0.2], "ZXY")
    np.testing.assert_allclose(euler_to_matrix(matrix_to_euler(m, "ZXY"), "ZXY"), m, atol=1e-9)


def test_rotvec_quat_matrix_agree(rng: np.random.Generator) -> None:
    r = rng.normal(size=(1000, 3))
    r[:10] *= 1e-10  # tiny angles
    m = rotvec_to_matrix(r)
    np.testing.assert_allclose(m @ np.swapaxes(m, -1, -2), np.broadcast_to(np.eye(3), m.shape), atol=1e-12)
    np.testing.assert_allclose(rotvec_to_matrix(matrix_to_rotvec(m)), m, atol=1e-10)
    np.testing.assert_allclose(quat_to_matrix(matrix_to_quat(m)), m, atol=1e-12)
    assert np.all(np.linalg.norm(matrix_to_rotvec(m), axis=-1) <= np.pi + 1e-12)


def test_rotvec_near_pi() -> None:
    r = np.array([[np.pi - 1e-9, 0, 0], [0, 0, np.pi]])
    m = rotvec_to_matrix(r)
    np.testing.assert_allclose(rotvec_to_matrix(matrix_to_rotvec(m)), m, atol=1e-8)


def test_slerp_endpoints_and_midpoint() -> None:
    q0 = matrix_to_quat(np.eye(3))
    q1 = matrix_to_quat(axis_rotation("Y", np.pi / 2))
    np.testing.assert_allclose(quat_slerp(q0, q1, 0.0), q0, atol=1e-12)
    np.testing.assert_allclose(np.abs(quat_slerp(q0, q1, 1.0)), np.abs(q1), atol=1e-12)
    mid = quat_to_matrix(quat_slerp(q0, q1, 0.5))
    np.testing.assert_allclose(mid, axis_rotation("Y", np.pi / 4), atol=1e-12)
    # shorter arc even when the quaternions have opposite signs
    np.testing.assert_allclose(quat_to_matrix(quat_slerp(q0, -q1, 0.5)), axis_rotation("Y", np.pi / 4), atol=1e-12)


def test_two_axis_frame_aligns_primary_exactly(rng: np.random.Generator) -> None:
    a_r, a_t, b_r, b_t = (rng.normal(size=(100, 3)) for _ in range(4))
    r = two_axis_frame(a_r, a_t, b_r, b_t)
    got = np.einsum("nij,nj->ni", r, a_r / np.linalg.norm(a_r, axis=1, keepdims=True))
    np.testing.assert_allclose(got, a_t / np.linalg.norm(a_t, axis=1, keepdims=True), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-12)


def test_angle_between() -> None:
    assert rotation_angle_between(np.eye(3), axis_rotation("X", 0.3)) == pytest.approx(0.3)


def test_direct_quaternion_conversions_equal_the_matrix_route() -> None:
    """rotvec <-> quaternion without matrices: the same as through them, near zero and at half turns."""
    rng = np.random.default_rng(11)
    r = rng.normal(0.0, 1.5, (500, 3))
    r[0] = 0.0
    r[1] = 1e-10
    r[2] = [np.pi, 0.0, 0.0]
    r[3] = [0.0, 0.0, 1.5 * np.pi]  # past a half turn: w >= 0 all the same
    q = rotvec_to_quat(r)
    np.testing.assert_allclose(q, matrix_to_quat(rotvec_to_matrix(r)), rtol=0, atol=1e-12)
    assert (q[:, 0] >= 0).all() and np.allclose(np.linalg.norm(q, axis=1), 1.0)
    raw = rng.normal(size=(500, 4))  # not normalised, either sign
    np.testing.assert_allclose(quat_to_rotvec(raw), matrix_to_rotvec(quat_to_matrix(raw)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(quat_to_rotvec(q[4:]), matrix_to_rotvec(rotvec_to_matrix(r[4:])), rtol=0, atol=1e-9)
    assert quat_to_rotvec(q[:2]).shape == (2, 3) and np.abs(quat_to_rotvec(q[:2])).max() < 1e-9
