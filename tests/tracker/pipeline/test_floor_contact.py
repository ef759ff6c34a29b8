"""Floor contact (``pipeline/floor_contact.py``): a leg through the floor bends back onto it."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.kinematics import fk, fk_global
from protocol.skeleton import JOINT_INDEX, ROT_SLOT, default_body, standing_pose
from tracker_service.pipeline.floor_contact import FloorParams, ankle_floor_height, floor_contact

J = JOINT_INDEX
BODY = default_body()


def _set(pose: np.ndarray, joint: str, rotvec: tuple[float, float, float]) -> None:
    k = ROT_SLOT[J[joint]]
    pose[3 + 3 * k: 6 + 3 * k] = rotvec


def _crouch(sink: float, knee: float = 1.6, hip: float = -0.8) -> np.ndarray:
    """A crouch whose legs are straighter than the pelvis height allows: ankles ``sink`` below their
    floor level."""
    p = standing_pose(BODY)
    for s in "lr":
        _set(p, f"{s}_hip", (hip, 0.0, 0.0))
        _set(p, f"{s}_knee", (knee, 0.0, 0.0))
        _set(p, f"{s}_ankle", (-0.5, 0.0, 0.0))
    low = fk(p, BODY)[[J["l_ankle"], J["r_ankle"]], 1].min()
    p[1] += ankle_floor_height(BODY) - sink - low
    return p


def test_the_standing_pose_has_its_ankles_at_their_floor_level() -> None:
    j = fk(standing_pose(BODY), BODY)
    assert j[J["l_ankle"], 1] == pytest.approx(ankle_floor_height(BODY), abs=1e-9)
    assert floor_contact(standing_pose(BODY), BODY, FloorParams()) == pytest.approx(standing_pose(BODY))


@pytest.mark.parametrize("sink", [0.05, 0.12, 0.2])
def test_a_sunk_leg_bends_onto_the_floor_hip_and_bones_kept(sink: float) -> None:
    params = FloorParams(tolerance_m=0.02)
    p = _crouch(sink, knee=0.9, hip=-0.4)
    q = floor_contact(p, BODY, params)
    (a, ga), (b, gb) = fk_global(p, BODY), fk_global(q, BODY)
    for s in "lr":
        assert b[J[f"{s}_ankle"], 1] == pytest.approx(ankle_floor_height(BODY) - params.tolerance_m, abs=1e-6)
        # the ankle goes straight up: its place on the floor is kept
        assert b[J[f"{s}_ankle"], [0, 2]] == pytest.approx(a[J[f"{s}_ankle"], [0, 2]], abs=1e-6)
        assert b[J[f"{s}_hip"]] == pytest.approx(a[J[f"{s}_hip"]], abs=1e-9)
        # the knee bends further, forward (+z, the way the body faces)
        assert b[J[f"{s}_knee"], 2] > a[J[f"{s}_knee"], 2]
        # the foot keeps its world orientation
        assert gb[J[f"{s}_ankle"]] == pytest.approx(ga[J[f"{s}_ankle"]], abs=1e-9)
    bones = [("hip", "knee"), ("knee", "ankle"), ("ankle", "toe")]
    for u, v in bones:
        assert np.linalg.norm(b[J[f"l_{v}"]] - b[J[f"l_{u}"]]) == pytest.approx(
            np.linalg.norm(a[J[f"l_{v}"]] - a[J[f"l_{u}"]]), abs=1e-9)
    assert q[:6] == pytest.approx(p[:6])  # root and upper body untouched
    assert q[6: 3 + 3 * ROT_SLOT[J["l_hip"]]] == pytest.approx(p[6: 3 + 3 * ROT_SLOT[J["l_hip"]]])


def test_within_tolerance_airborne_and_lying_poses_are_left_alone() -> None:
    params = FloorParams(tolerance_m=0.03)
    p = _crouch(0.02, knee=0.9, hip=-0.4)  # 2 cm below: within tolerance
    assert floor_contact(p, BODY, params) == pytest.approx(p)
    up = _crouch(-0.3)  # a jump
    assert floor_contact(up, BODY, params) == pytest.approx(up)
    lying = standing_pose(BODY)
    lying[1] = 0.1  # pelvis on the floor
    lying[3:6] = (np.pi / 2, 0.0, 0.0)
    lying[1] -= 0.2  # and through it: no leg to bend the floor out of
    assert floor_contact(lying, BODY, params) == pytest.approx(lying)
    bad = p.copy()
    bad[7] = np.nan
    assert np.isnan(floor_contact(bad, BODY, params)[7])


def test_the_knee_never_bends_past_its_limit() -> None:
    p = _crouch(0.6, knee=2.7, hip=-1.5)  # unreachable without over-bending
    q = floor_contact(p, BODY, FloorParams())
    k = ROT_SLOT[J["l_knee"]]
    assert np.linalg.norm(q[3 + 3 * k: 6 + 3 * k]) <= np.radians(170) + 1e-6


def test_params_are_checked() -> None:
    with pytest.raises(ValueError, match="tolerance_m"):
        FloorParams(tolerance_m=-0.1)
    with pytest.raises(ValueError, match="min_hip_clearance_m"):
        FloorParams(min_hip_clearance_m=float("nan"))
    with pytest.raises(ValueError, match="shape"):
        floor_contact(np.zeros(5), BODY, FloorParams())
