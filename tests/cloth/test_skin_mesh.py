"""The avatar's smooth skinned surface (``cloth_client/avatar/skin_mesh.py``)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cloth_client.avatar.capsules import capsule_endpoints
from cloth_client.avatar.skin_mesh import CAPSULE_OWNER, build_skinned_mesh, pose_vertices
from protocol.skeleton import JOINT_INDEX, ROT_SLOT, body_from_measurements, default_body, rest_pose, standing_pose

BODY = default_body()


@pytest.fixture(scope="module")
def mesh():  # type: ignore[no-untyped-def]
    return build_skinned_mesh(BODY)


def _distance_to_capsules(v: np.ndarray, a: np.ndarray, b: np.ndarray, radii: np.ndarray) -> np.ndarray:
    ab = b - a
    ap = v[:, None] - a[None]
    t = np.clip(np.einsum("ncd,cd->nc", ap, ab) / np.einsum("cd,cd->c", ab, ab), 0, 1)
    d = np.linalg.norm(ap - t[..., None] * ab[None], axis=2) - (radii[:, 0] + t * (radii[:, 1] - radii[:, 0]))
    return d.min(axis=1)


def test_a_closed_outward_surface_that_the_rest_pose_leaves_in_place(mesh) -> None:  # type: ignore[no-untyped-def]
    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    assert tm.is_watertight and tm.volume > 0.03  # a person's volume is 0.05-0.1 m^3
    assert np.allclose(mesh.weights.sum(axis=1), 1.0) and (mesh.weights >= 0).all()
    np.testing.assert_allclose(pose_vertices(mesh, BODY, rest_pose()), mesh.vertices, atol=1e-12)
    assert CAPSULE_OWNER[3] == JOINT_INDEX["chest"] and CAPSULE_OWNER[0] == JOINT_INDEX["pelvis"]


@pytest.mark.parametrize("raise_arms", [False, True])
def test_the_posed_surface_wraps_the_posed_capsules(mesh, raise_arms: bool) -> None:  # type: ignore[no-untyped-def]
    pose = standing_pose(BODY)
    if raise_arms:
        for side, sign in (("l", 1.0), ("r", -1.0)):
            k = ROT_SLOT[JOINT_INDEX[f"{side}_shoulder"]]
            pose[3 + 3 * k: 6 + 3 * k] = (0.0, 0.0, sign * 1.3)
    v = pose_vertices(mesh, BODY, pose)
    a, b = capsule_endpoints(BODY, pose)
    d = _distance_to_capsules(v, a, b, BODY.capsule_radii)
    # on the capsules' surface, up to the fillets and the blend across the joints
    assert np.percentile(np.abs(d), 90) < 0.015 and np.abs(d).max() < 0.06
    if raise_arms:  # the hands went up with the arms
        assert v[:, 1].max() > BODY.height + 0.2


def test_the_surface_follows_capsules_moved_by_the_simulation(mesh) -> None:  # type: ignore[no-untyped-def]
    pose = standing_pose(BODY)
    a, b = capsule_endpoints(BODY, pose)
    a2, b2 = a.copy(), b.copy()
    fore = 7  # the left forearm turned out sideways, as the limb clearance does
    b2[fore] = a2[fore] + np.linalg.norm(b[fore] - a[fore]) * np.array([1.0, 0.0, 0.0])
    v = pose_vertices(mesh, BODY, pose, a2, b2)
    owned = (mesh.capsules[:, 0] == fore) & (mesh.weights[:, 0] > 0.95)
    assert owned.sum() > 20
    d = _distance_to_capsules(v[owned], a2[fore:fore + 1], b2[fore:fore + 1], BODY.capsule_radii[fore:fore + 1])
    assert np.abs(d).max() < 0.01


def test_any_body_gets_its_own_surface() -> None:
    child = body_from_measurements(1.1, weight_kg=20.0, name="kid")
    m = build_skinned_mesh(child)
    assert m.vertices[:, 1].max() - m.vertices[:, 1].min() == pytest.approx(child.height, abs=0.08)
    with pytest.raises(ValueError, match="voxel_m"):
        build_skinned_mesh(child, voxel_m=0.0)
