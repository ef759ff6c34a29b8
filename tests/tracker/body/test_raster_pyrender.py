"""The fast capsule silhouettes against the true mesh silhouettes rendered by pyrender (EGL)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import trimesh

from protocol.formats.load import load_motion
from protocol.formats.mocap_data import mocap_root
from protocol.kinematics import fk
from protocol.rotations import matrix_to_rotvec, rotvec_to_matrix
from protocol.skeleton import CAPSULE_PART, N_PARTS
from tracker_service.body.family import BODY_MODELS, body_model
from tracker_service.body.mesh import BodyMesh
from tracker_service.body.raster import render_labels, render_silhouette
from tracker_service.camera import default_camera, look_at
from tracker_service.scene.gl import MeshRasterizer
from tracker_service.templates.pruning import prune_poses

RECORDINGS = ("bandai/dataset-1_dance-short_normal_001.bvh", "bandai/dataset-1_kick_normal_001.bvh",
              "bandai/dataset-1_slash_normal_001.bvh", "bandai/dataset-1_punch_normal_002.bvh",
              "bandai/dataset-2_raise-up-both-hands_masculine_001.bvh")


@pytest.fixture(scope="module")
def database_poses() -> np.ndarray:
    """200 poses drawn from the 5-degree pruned database of five recordings, centred on the stage,
    each turned to a random heading."""
    poses = np.concatenate([load_motion(mocap_root() / f).poses for f in RECORDINGS])
    kept = poses[prune_poses(poses, 5.0).kept]
    rng = np.random.default_rng(2024)
    p = kept[rng.choice(len(kept), 200, replace=False)].copy()
    p[:, [0, 2]] = 0.0
    yaw = rng.uniform(-np.pi, np.pi, len(p))
    ry = rotvec_to_matrix(np.stack([np.zeros_like(yaw), yaw, np.zeros_like(yaw)], axis=1))
    p[:, 3:6] = matrix_to_rotvec(ry @ rotvec_to_matrix(p[:, 3:6]))
    return p


@pytest.fixture(scope="module")
def rasterizer() -> Iterator[MeshRasterizer]:
    with MeshRasterizer(default_camera()) as r:
        yield r


def test_camera_conventions_match_pyrender(rasterizer: MeshRasterizer) -> None:
    """A small sphere on the optical axis renders centred on its projection (pixel-centre convention)."""
    cam = rasterizer.camera
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    for centre in ([0.0, 1.2, 0.0], [0.0, 1.2, 1.5]):
        mask = rasterizer.silhouette(sphere.vertices + centre, sphere.faces)
        ys, xs = np.nonzero(mask)
        u, v = cam.project(np.array(centre))
        assert abs(xs.mean() - u) < 0.05 and abs(ys.mean() - v) < 0.05
    moved = cam.moved(look_at((1.0, 1.6, 2.5), (0.3, 1.0, 0.0)))
    rasterizer.set_camera(moved)
    try:
        mask = rasterizer.silhouette(sphere.vertices + np.array([0.3, 1.0, 0.0]), sphere.faces)
        ys, xs = np.nonzero(mask)
        assert abs(xs.mean() - moved.cx) < 0.1 and abs(ys.mean() - moved.cy) < 0.1
    finally:
        rasterizer.set_camera(cam)


def test_fast_silhouettes_match_pyrender_meshes(database_poses: np.ndarray, rasterizer: MeshRasterizer) -> None:
    """IoU >= 0.95 for every one of 200 database poses, over all 30 models."""
    cam = rasterizer.camera
    ious = []
    for k, pose in enumerate(database_poses):
        body = BODY_MODELS[k % len(BODY_MODELS)].body
        mesh = BodyMesh(body, segments=20, rings=5)
        joints = fk(pose, body)
        verts, _ = mesh.vertices(joints)
        truth = rasterizer.silhouette(verts, mesh.faces)
        fast = render_silhouette(joints, body.capsule_radii, cam)
        ious.append((fast & truth).sum() / max((fast | truth).sum(), 1))
    ious_a = np.array(ious)
    assert ious_a.min() >= 0.95, f"worst IoU {ious_a.min():.4f} at pose {ious_a.argmin()}"
    assert ious_a.mean() >= 0.98


def test_part_labels_match_pyrender_segmentation(database_poses: np.ndarray, rasterizer: MeshRasterizer) -> None:
    """Where both renderers see the person, they name the same body part almost everywhere
    (disagreements are confined to the joints, where two parts' spheres coincide)."""
    body = body_model("mMA").body
    mesh = BodyMesh(body)
    agree = []
    for pose in database_poses[:20]:
        joints = fk(pose, body)
        verts, _ = mesh.vertices(joints)
        truth = rasterizer.labels(verts, mesh.faces, mesh.face_part, N_PARTS)
        fast, counts = render_labels(joints, body.capsule_radii, rasterizer.camera)
        both = (truth >= 0) & (fast >= 0)
        agree.append((truth[both] == fast[both]).mean())
        # parts the mesh renderer sees are (almost) never reported invisible by the fast one
        seen = np.bincount(truth[truth >= 0].astype(np.int64), minlength=N_PARTS)
        assert np.all((seen < 10) | (counts > 0))
    assert np.mean(agree) > 0.93 and np.min(agree) > 0.88
    assert set(np.unique(CAPSULE_PART)) == set(range(N_PARTS))
