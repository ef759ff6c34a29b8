"""A smooth skinned body mesh of the avatar, built from the ``BodyInfo`` alone.

The cloth is simulated on the body's tapered capsules (:mod:`cloth_client.avatar.capsules`); drawn
as fifteen separate capsules the avatar looks like a mannequin of tubes. This module builds one
closed, smooth surface around them and moves it with the avatar:

1. **Rest surface.** In the T-pose the signed distance to every tapered capsule (distance to its
   segment minus the radius interpolated along it) is combined by a polynomial *smooth minimum*
   (blend width ``blend_m``), so the limbs grow into the trunk with fillets instead of creases.
   Its level set ``inset_m`` inside, on a ``voxel_m`` grid, is extracted by marching cubes
   (scikit-image) and relaxed by a few Taubin smoothing steps (trimesh), which smooth without
   shrinking.
2. **Skinning weights.** Each vertex is bound to its ``bones`` nearest capsules, weighted by
   ``exp(-(d_c - d_min) / falloff_m)`` of its distance ``d_c`` to each capsule's surface, so it
   follows one capsule in the middle of a limb and blends two across a joint.
3. **Posing** (linear blend skinning): every capsule gets a rigid transform per frame -- the
   global rotation of the joint it hangs from, swung so that its axis points along the capsule
   the cloth was simulated on (which may have been turned out of the trunk or kept from crossing
   the other leg), moved to that capsule's first end. So the surface drawn is around the avatar
   the cloth collided with, not only around the pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from numpy.typing import NDArray
from skimage.measure import marching_cubes

from cloth_client.avatar.capsules import swing_vectors
from protocol.kinematics import fk_global
from protocol.skeleton import CAPSULE_JOINTS, CAPSULE_OWNER, N_CAPSULES, Body, rest_pose

__all__ = ["CAPSULE_OWNER", "SkinnedMesh", "build_skinned_mesh", "capsule_frames", "pose_vertices"]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class SkinnedMesh:
    """A skinned surface around a body's capsules.

    Attributes
    ----------
    vertices : (V, 3) float64
        The surface in the T-pose (the pose vector's identity rotations, the root at the origin),
        metres.
    faces : (F, 3) int64
        Triangles, counter-clockwise seen from outside.
    capsules : (V, K) int64
        The capsules each vertex follows.
    weights : (V, K) float64
        Their weights (each row sums to 1).
    rest_a, rest_b : (C, 3) float64
        The capsules' ends in the T-pose.
    """

    vertices: F64
    faces: NDArray[np.int64]
    capsules: NDArray[np.int64]
    weights: F64
    rest_a: F64
    rest_b: F64


def _capsule_distance(p: F64, a: F64, b: F64, radii: F64) -> F64:
    """Signed distance (metres) of points ``p (N, 3)`` to each tapered capsule: ``(N, C)``."""
    ab = b - a  # (C, 3)
    ap = p[:, None, :] - a[None]  # (N, C, 3)
    den = np.maximum(np.einsum("cd,cd->c", ab, ab), 1e-12)
    t = np.clip(np.einsum("ncd,cd->nc", ap, ab) / den, 0.0, 1.0)
    d = np.linalg.norm(ap - t[..., None] * ab[None], axis=2)
    return d - (radii[:, 0] + t * (radii[:, 1] - radii[:, 0]))


def _smooth_min(d: F64, k: float) -> F64:
    """Polynomial smooth minimum over the last axis (blend width ``k``)."""
    out = d[..., 0].copy()
    for c in range(1, d.shape[-1]):
        b = d[..., c]
        h = np.maximum(k - np.abs(out - b), 0.0) / k
        out = np.minimum(out, b) - 0.25 * k * h * h
    return out


def build_skinned_mesh(body: Body, voxel_m: float = 0.02, blend_m: float = 0.03, falloff_m: float = 0.015,
                       bones: int = 3, smoothing: int = 8, inset_m: float = 0.005) -> SkinnedMesh:
    """The skinned surface around ``body``'s capsules (module docstring).

    Parameters
    ----------
    body : Body
        Offsets and capsule radii (what a ``BodyInfo`` carries).
    voxel_m : float
        Grid spacing of the marching cubes, metres.
    blend_m : float
        Width of the smooth minimum's fillets, metres.
    falloff_m : float
        How fast a capsule's weight falls with the vertex's distance beyond the nearest, metres.
    bones : int
        Capsules per vertex.
    smoothing : int
        Taubin smoothing iterations.
    inset_m : float
        The surface is drawn this far inside the capsules' smooth union: the fillets bulge up to
        ``blend_m / 4`` beyond the capsules the cloth collides with, and must not show through it.

    Returns
    -------
    SkinnedMesh
    """
    if not (voxel_m > 0 and blend_m > 0 and falloff_m > 0 and 1 <= bones <= N_CAPSULES):
        raise ValueError("voxel_m, blend_m and falloff_m must be > 0 and bones in [1, C]")
    joints = fk_global(rest_pose(), body)[0]
    a, b = joints[CAPSULE_JOINTS[:, 0]], joints[CAPSULE_JOINTS[:, 1]]
    radii = np.asarray(body.capsule_radii, np.float64)
    pad = float(radii.max()) + blend_m + 2 * voxel_m
    lo = np.minimum(a, b).min(axis=0) - pad
    hi = np.maximum(a, b).max(axis=0) + pad
    axes = [np.arange(lo[i], hi[i] + voxel_m, voxel_m) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    sdf = np.concatenate([_smooth_min(_capsule_distance(chunk, a, b, radii), blend_m)
                          for chunk in np.array_split(grid, max(1, len(grid) // 65536))])
    verts, faces, _, _ = marching_cubes(sdf.reshape([len(x) for x in axes]), level=-inset_m,
                                        spacing=(voxel_m,) * 3)
    mesh = trimesh.Trimesh(verts + lo, faces, process=True)  # merged vertices
    if mesh.volume < 0:  # outward normals
        mesh.invert()
    if smoothing:
        trimesh.smoothing.filter_taubin(mesh, iterations=smoothing)
    v = np.asarray(mesh.vertices, np.float64)
    d = _capsule_distance(v, a, b, radii)
    near = np.argsort(d, axis=1)[:, :bones]
    dn = np.take_along_axis(d, near, axis=1)
    w = np.exp(-(dn - dn[:, :1]) / falloff_m)
    return SkinnedMesh(v, np.asarray(mesh.faces, np.int64), near.astype(np.int64), w / w.sum(axis=1, keepdims=True),
                       a, b)


def capsule_frames(mesh: SkinnedMesh, body: Body, pose: F64, a: F64 | None = None, b: F64 | None = None
                   ) -> tuple[F64, F64]:
    """Each capsule's rigid transform from the T-pose to ``pose`` (module docstring, step 3).

    Parameters
    ----------
    mesh : SkinnedMesh
    body : Body
    pose : (P,) float64
    a, b : (C, 3) float64, optional
        The capsules the cloth was simulated on; default: the pose's own.

    Returns
    -------
    rot : (C, 3, 3) float64
    shift : (C, 3) float64
        A T-pose point ``x`` on capsule ``c`` goes to ``rot[c] @ (x - rest_a[c]) + shift[c]``.
    """
    joints, glob = fk_global(np.asarray(pose, np.float64), body)
    if a is None or b is None:
        a, b = joints[CAPSULE_JOINTS[:, 0]], joints[CAPSULE_JOINTS[:, 1]]
    rot = glob[CAPSULE_OWNER]
    now = np.einsum("cij,cj->ci", rot, mesh.rest_b - mesh.rest_a)
    target = np.asarray(b, np.float64) - a
    n_now, n_target = np.linalg.norm(now, axis=1), np.linalg.norm(target, axis=1)
    ok = (n_now > 1e-9) & (n_target > 1e-9)
    unit = now / np.maximum(n_now, 1e-9)[:, None]
    tunit = target / np.maximum(n_target, 1e-9)[:, None]
    # the frame's axes (the columns of rot) swung with the capsule's axis
    cols = swing_vectors(unit[:, None, :], tunit[:, None, :], np.swapaxes(rot, 1, 2))
    return np.where(ok[:, None, None], np.swapaxes(cols, 1, 2), rot), np.asarray(a, np.float64)


def pose_vertices(mesh: SkinnedMesh, body: Body, pose: F64, a: F64 | None = None, b: F64 | None = None) -> F64:
    """The surface at ``pose`` by linear blend skinning: ``(V, 3)`` metres (see :func:`capsule_frames`)."""
    rot, shift = capsule_frames(mesh, body, pose, a, b)
    local = mesh.vertices[:, None, :] - mesh.rest_a[mesh.capsules]  # (V, K, 3)
    moved = np.einsum("vkij,vkj->vki", rot[mesh.capsules], local) + shift[mesh.capsules]
    return np.einsum("vk,vki->vi", mesh.weights, moved)
