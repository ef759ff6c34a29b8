import numpy as np
import pytest

from protocol import JOINT_NAMES, POSE_SIZE, body_from_measurements, default_body, fk, standing_pose
from protocol.skeleton import (
    CAPSULES,
    JOINT_INDEX,
    LIMIT_HI,
    LIMIT_LO,
    MIRROR_JOINTS,
    N_PARTS,
    PARENTS,
    PARTS,
    Body,
    clamp_pose,
    limit_violation_deg,
    mirror_pose,
)


def test_tree_is_topological_and_sized() -> None:
    assert 20 <= len(JOINT_NAMES) <= 27
    assert PARENTS[0] == -1
    assert all(0 <= p < j for j, p in enumerate(PARENTS) if j > 0)
    assert POSE_SIZE == 60
    assert N_PARTS == 15
    assert {c[1] for c in CAPSULES} == set(PARTS)


def test_taller_and_heavier_bodies_are_larger() -> None:
    small, tall = body_from_measurements(1.50), body_from_measurements(1.90)
    assert np.all(tall.bone_lengths >= small.bone_lengths)
    assert tall.leg_length > small.leg_length
    thin = body_from_measurements(1.75, weight_kg=55)
    heavy = body_from_measurements(1.75, weight_kg=95, chest_m=1.10, waist_m=1.00, hip_m=1.10)
    assert np.all(heavy.capsule_radii >= thin.capsule_radii - 1e-12)
    assert heavy.capsule_radii.sum() > thin.capsule_radii.sum()


def test_standing_height_matches_measurement() -> None:
    skull = [c[0] for c in CAPSULES].index("skull")
    for h in (1.2, 1.6, 1.85):
        b = body_from_measurements(h)
        joints = fk(standing_pose(b), b)
        top = joints[JOINT_INDEX["head_top"], 1] + b.capsule_radii[skull, 1]  # top of the skull surface
        assert top == pytest.approx(h, rel=0.015)
        assert b.height == pytest.approx(h)


def test_standing_pose_feet_on_floor() -> None:
    b = default_body()
    joints = fk(standing_pose(b), b)
    foot_r = b.capsule_radii[[c[0] for c in CAPSULES].index("l_foot"), 1]
    assert joints[JOINT_INDEX["l_toe"], 1] - foot_r == pytest.approx(0.0, abs=1e-9)


def test_body_validation() -> None:
    with pytest.raises(ValueError):
        body_from_measurements(3.0)
    b = default_body()
    with pytest.raises(ValueError):
        Body("x", b.offsets[:3], b.capsule_radii)
    bad = b.capsule_radii.copy()
    bad[0, 0] = -1
    with pytest.raises(ValueError):
        Body("x", b.offsets, bad)


def test_mirror_reflects_joint_positions(rng: np.random.Generator) -> None:
    b = default_body()  # symmetric body
    poses = rng.normal(0, 0.3, (200, POSE_SIZE))
    mj = fk(mirror_pose(poses), b)
    j = fk(poses, b)
    reflected = j[:, list(MIRROR_JOINTS)] * np.array([-1, 1, 1])
    np.testing.assert_allclose(mj, reflected, atol=1e-9)
    np.testing.assert_allclose(mirror_pose(mirror_pose(poses)), poses, atol=1e-12)


def test_limits_are_mirrored_and_clamp_works(rng: np.random.Generator) -> None:
    le, re = [list(JOINT_NAMES).index(n) for n in ("l_elbow", "r_elbow")]
    from protocol.skeleton import ROT_JOINTS

    kl, kr = ROT_JOINTS.index("l_elbow"), ROT_JOINTS.index("r_elbow")
    np.testing.assert_allclose(LIMIT_LO[kr, 1], -LIMIT_HI[kl, 1])
    assert le != re
    poses = rng.normal(0, 3.0, (100, POSE_SIZE))
    c = clamp_pose(poses)
    assert np.all(limit_violation_deg(c) < 1e-9)
    assert np.all(limit_violation_deg(poses)[:, 0] == 0)  # the root is unlimited
    assert limit_violation_deg(poses).max() > 10
