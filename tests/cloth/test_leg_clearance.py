"""The knees kept apart for the skirt (cloth_client.avatar.leg_clearance)."""

from __future__ import annotations

import numpy as np

from cloth_client.avatar.capsules import avatar_capsules, capsule_endpoints, pose_keys
from cloth_client.avatar.leg_clearance import LEG_CLEARANCE, LEG_MAX_PUSH, LEG_MAX_TOE, LEGS, clear_legs, leg_gap
from protocol.skeleton import CAPSULE_INDEX, ROT_JOINTS, default_body, standing_pose

BODY = default_body()
LEG_CAPS = LEGS.ravel()


def _knees_in(angle: float) -> np.ndarray:
    """The standing pose with both hips turned in by ``angle`` radians (knees together when > 0)."""
    pose = standing_pose(BODY)
    for side, sign in (("l_hip", -1.0), ("r_hip", 1.0)):
        k = 3 + 3 * ROT_JOINTS.index(side)
        pose[k + 2] += sign * angle
    return pose


def _ends(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b = capsule_endpoints(BODY, pose[None])
    return a, b


def test_standing_legs_are_left_alone() -> None:
    a, b = _ends(standing_pose(BODY))
    assert leg_gap(a, b, BODY.capsule_radii)[0][0] > LEG_CLEARANCE
    a2, b2 = clear_legs(a, b, BODY.capsule_radii)
    np.testing.assert_array_equal(a2, a)
    np.testing.assert_array_equal(b2, b)


def test_knees_that_nearly_touch_are_turned_apart_about_the_hips() -> None:
    """Knees 5 mm apart end (within 1 mm) the clearance apart; each leg turns rigidly about its hip joint (bone
    lengths and the hip joints kept), only the legs move, and by the same amount either side."""
    a, b = _ends(_knees_in(0.05))
    radii = BODY.capsule_radii
    gap0 = leg_gap(a, b, radii)[0][0]
    assert 0.0 < gap0 < LEG_CLEARANCE
    a2, b2 = clear_legs(a, b, radii)
    assert leg_gap(a2, b2, radii)[0][0] > LEG_CLEARANCE - 1e-3  # four rounds: within 1 mm of it
    others = np.setdiff1d(np.arange(len(radii)), LEG_CAPS)
    np.testing.assert_array_equal(a2[:, others], a[:, others])
    np.testing.assert_array_equal(b2[:, others], b[:, others])
    np.testing.assert_allclose(np.linalg.norm(b2 - a2, axis=-1), np.linalg.norm(b - a, axis=-1), atol=1e-12)
    for side in range(2):
        thigh, shin, foot = LEGS[side]
        np.testing.assert_array_equal(a2[:, thigh], a[:, thigh])  # the hip joint stays
        np.testing.assert_allclose(a2[:, shin], b2[:, thigh], atol=1e-12)  # joints stay shared
        np.testing.assert_allclose(a2[:, foot], b2[:, shin], atol=1e-12)
    knee = [b2[0, LEGS[s, 0]] - b[0, LEGS[s, 0]] for s in range(2)]
    assert knee[0][0] > 0.0 > knee[1][0]  # the left knee moves left (+x), the right one right
    np.testing.assert_allclose(knee[0], -knee[1] * [1.0, -1.0, -1.0], atol=1e-9)  # mirror images


def test_the_push_grows_continuously_and_is_capped() -> None:
    """The turn-out grows from zero as the knees come within the clearance, without a jump while the
    legs are side by side; no knee moves more than ``LEG_MAX_PUSH``; and however deep the legs
    cross (past 0.1 rad of this path the closest points swap sides) no gap ever gets smaller."""
    angles = np.linspace(0.0, 0.12, 241)
    poses = np.stack([_knees_in(t) for t in angles])
    a, b = capsule_endpoints(BODY, poses)
    a2, b2 = clear_legs(a, b, BODY.capsule_radii)
    move = np.linalg.norm(b2 - b, axis=-1)  # (N, C)
    knee = move[:, LEGS[0, 0]]
    assert knee[0] == 0.0 and knee.max() > 0.005
    side_by_side = angles <= 0.09
    assert np.abs(np.diff(knee[side_by_side])).max() < 1e-3  # 0.5 mrad steps: sub-millimetre changes
    assert knee.max() <= LEG_MAX_PUSH + 1e-9
    before, after = leg_gap(a, b, BODY.capsule_radii)[0], leg_gap(a2, b2, BODY.capsule_radii)[0]
    assert np.all(after >= before - 1e-12)
    assert after[side_by_side].min() > before[side_by_side].min() + 0.015  # deep but side by side: opened
    assert after[-1] < 0.0  # a deep crossing is not undone


def test_the_toe_cap_holds() -> None:
    """With a knee cap the toe cap would not bind first, the toe still moves at most ``max_toe``."""
    poses = np.stack([_knees_in(t) for t in np.linspace(0.04, 0.09, 21)])
    a, b = capsule_endpoints(BODY, poses)
    _a2, b2 = clear_legs(a, b, BODY.capsule_radii, max_push=0.05, max_toe=0.02)
    toe = np.linalg.norm(b2 - b, axis=-1)[:, LEGS[:, 2]]
    assert toe.max() <= 0.02 + 1e-9 and toe.max() > 0.019
    assert LEG_MAX_TOE > LEG_MAX_PUSH


def test_crossed_legs_are_turned_apart_the_way_they_cross() -> None:
    """A cross-step (the left leg's closest point to the right of the right leg's): the legs turn
    further apart the way they are crossed, not into each other."""
    pose = standing_pose(BODY)
    for joint, rv in (("l_hip", [-0.12, 0.0, -0.49]), ("r_hip", [-0.5, 0.0, -0.23]), ("r_knee", [0.71, 0.0, 0.0])):
        k = 3 + 3 * ROT_JOINTS.index(joint)
        pose[k:k + 3] = rv
    a, b = _ends(pose)
    gap, left, right = leg_gap(a, b, BODY.capsule_radii)
    lateral = a[0, CAPSULE_INDEX["pelvis"]] - b[0, CAPSULE_INDEX["pelvis"]]
    assert gap[0] < 0.0 and (left[0] - right[0]) @ lateral < 0.0  # crossed
    a2, b2 = clear_legs(a, b, BODY.capsule_radii)
    assert leg_gap(a2, b2, BODY.capsule_radii)[0][0] > gap[0] + 0.003  # -27 -> -22 mm (-53 turned the wrong way)


def test_the_avatar_the_cloth_sees_has_the_knees_apart() -> None:
    """``pose_keys`` and ``avatar_capsules`` (what the cloth collides with and the renderer draws)
    apply the rule; without the clearance rules the legs are the recorded ones."""
    pose = _knees_in(0.05)
    keys = pose_keys(BODY, np.stack([pose, pose]))
    assert leg_gap(keys.track.a, keys.track.b, BODY.capsule_radii)[0].min() > LEG_CLEARANCE - 1e-3
    a, b = avatar_capsules(BODY, pose)
    np.testing.assert_allclose(a, keys.track.a[0], atol=1e-12)
    np.testing.assert_allclose(b, keys.track.b[0], atol=1e-12)
    raw = pose_keys(BODY, np.stack([pose, pose]), clearance=None)
    ra, rb = _ends(pose)
    np.testing.assert_array_equal(raw.track.a[0], ra[0])
    np.testing.assert_array_equal(raw.track.b[0], rb[0])
    assert CAPSULE_INDEX["l_thigh"] in LEG_CAPS and CAPSULE_INDEX["r_foot"] in LEG_CAPS
