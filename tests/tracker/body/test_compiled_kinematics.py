"""The compiled forward kinematics of the tracker's per-frame path equals its reference,
:func:`protocol.kinematics.fk_global`, on batches and single poses, near-zero rotations included."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.kinematics import fk_global as fk_global_reference
from protocol.skeleton import N_JOINTS, POSE_SIZE
from tracker_service.body import kinematics
from tracker_service.body.family import body_model


@pytest.mark.parametrize("name", ["mMA", "wTY"])
def test_compiled_fk_equals_the_reference(name: str) -> None:
    body = body_model(name).body
    rng = np.random.default_rng(3)
    poses = rng.normal(0.0, 1.2, (40, POSE_SIZE))
    poses[:, :3] = rng.normal(0.0, 2.0, (40, 3))
    poses[1, 3:] = 0.0  # the rest pose
    poses[2, 3:] = 1e-10  # every rotation on the Taylor branch
    poses[3, 6:9] = np.pi  # a half turn
    want_j, want_r = fk_global_reference(poses, body)
    got_j, got_r = kinematics.fk_global(poses, body)
    assert got_j.shape == (40, N_JOINTS, 3) and got_r.shape == (40, N_JOINTS, 3, 3)
    np.testing.assert_allclose(got_j, want_j, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got_r, want_r, rtol=0, atol=1e-12)
    one_j, one_r = kinematics.fk_global(poses[5], body)  # a single pose keeps its shape
    np.testing.assert_allclose(one_j, want_j[5], rtol=0, atol=1e-12)
    np.testing.assert_allclose(one_r, want_r[5], rtol=0, atol=1e-12)
    np.testing.assert_allclose(kinematics.fk(poses[:3].tolist(), body), want_j[:3], rtol=0, atol=1e-12)


def test_a_wrong_pose_shape_is_refused() -> None:
    with pytest.raises(ValueError, match=f"poses must have shape \\(N, {POSE_SIZE}\\)"):
        kinematics.fk(np.zeros((2, POSE_SIZE - 1)), body_model("mMA").body)
