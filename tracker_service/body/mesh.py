"""Triangle meshes of the capsule bodies (the 30 models and any :class:`~protocol.skeleton.Body`).

Each entry of :data:`~protocol.skeleton.CAPSULES` is a *tapered capsule*: the convex hull of a
sphere of radius ``r_a`` at joint ``a`` and one of radius ``r_b`` at joint ``b`` (two spherical caps
joined by a tangent cone). The mesh of a posed body is generated directly from the joint positions
(one fixed topology, vertices computed in a few vectorised numpy operations), so it is the exact
surface the fast silhouette renderer approximates; it serves the pyrender agreement tests, the
benchmarks and anyone who wants to look at a model (``trimesh`` export).

Capsule ``c`` owns vertices ``[c * V_c, (c + 1) * V_c)`` where ``V_c = 2 + 2 * rings * segments``:
the pole at ``a``, ``rings`` latitude rings on sphere ``a`` (south pole side up to the tangent
latitude), ``rings`` rings on sphere ``b`` (from the tangent latitude), the pole at ``b``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from protocol.kinematics import fk
from protocol.skeleton import CAPSULE_JOINTS, CAPSULE_PART, N_CAPSULES, N_JOINTS, Body

__all__ = ["BodyMesh", "capsule_endpoints", "capsule_mesh_topology", "tapered_capsules"]


def capsule_endpoints(joints: ArrayLike) -> NDArray[np.float64]:
    """Capsule end points from joint positions.

    Parameters
    ----------
    joints : (..., J, 3) float

    Returns
    -------
    (..., C, 2, 3) float64
        ``[..., c, 0]`` is joint ``a`` and ``[..., c, 1]`` joint ``b`` of capsule ``c``.
    """
    j = np.asarray(joints, dtype=np.float64)
    if j.shape[-2:] != (N_JOINTS, 3):
        raise ValueError(f"joints must be (..., {N_JOINTS}, 3), got {j.shape}")
    return j[..., CAPSULE_JOINTS, :]


def capsule_mesh_topology(segments: int, rings: int) -> NDArray[np.int64]:
    """Faces of one tapered capsule (vertex layout in the module docstring).

    Parameters
    ----------
    segments : int
        Vertices per latitude ring (>= 3).
    rings : int
        Latitude rings per end cap (>= 1).

    Returns
    -------
    (F, 3) int64
        Counter-clockwise seen from outside, ``F = 2 * segments * (2 * rings)``.
    """
    if segments < 3 or rings < 1:
        raise ValueError("need segments >= 3 and rings >= 1")
    n_rings = 2 * rings
    faces: list[list[int]] = []
    s = segments
    ring0 = 1
    for k in range(s):  # fan around the pole at a (pointing away from b)
        faces.append([0, ring0 + (k + 1) % s, ring0 + k])
    for r in range(n_rings - 1):
        base0, base1 = ring0 + r * s, ring0 + (r + 1) * s
        for k in range(s):
            k1 = (k + 1) % s
            faces.append([base0 + k, base0 + k1, base1 + k1])
            faces.append([base0 + k, base1 + k1, base1 + k])
    last = ring0 + (n_rings - 1) * s
    top = ring0 + n_rings * s
    for k in range(s):
        faces.append([top, last + k, last + (k + 1) % s])
    return np.asarray(faces, dtype=np.int64)


def _frames(axis: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Two unit vectors perpendicular to each unit ``axis (..., 3)``, right-handed with it."""
    ref = np.where(np.abs(axis[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))
    e1 = np.cross(axis, ref)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(axis, e1)
    return e1, e2


def tapered_capsules(endpoints: ArrayLike, radii: ArrayLike, segments: int = 24,
                     rings: int = 6) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Vertices and unit normals of tapered capsules.

    Parameters
    ----------
    endpoints : (..., C, 2, 3) float
        End points ``a`` and ``b`` of each capsule, metres.
    radii : (C, 2) or (..., C, 2) float
        Radius at ``a`` and at ``b``.
    segments, rings : int
        Tessellation (see :func:`capsule_mesh_topology`).

    Returns
    -------
    vertices, normals : (..., C, V_c, 3) float64
        ``V_c = 2 + 2 * rings * segments``.
    """
    e = np.asarray(endpoints, dtype=np.float64)
    r = np.broadcast_to(np.asarray(radii, dtype=np.float64), (*e.shape[:-2], 2))
    a, b = e[..., 0, :], e[..., 1, :]
    ra, rb = r[..., 0], r[..., 1]
    d = b - a
    length = np.linalg.norm(d, axis=-1)
    axis = np.where(length[..., None] > 1e-9, d / np.maximum(length, 1e-9)[..., None], np.array([0.0, 1.0, 0.0]))
    e1, e2 = _frames(axis)
    sin_phi = np.clip((ra - rb) / np.maximum(length, 1e-9), -1.0, 1.0)
    phi = np.arcsin(sin_phi)  # tangent latitude (towards b)
    k = np.arange(1, rings + 1) / rings
    lat_a = -np.pi / 2 + (phi[..., None] + np.pi / 2) * k  # (..., C, rings), ends at phi
    lat_b = phi[..., None] + (np.pi / 2 - phi[..., None]) * (np.arange(rings) / rings)
    lat = np.concatenate([lat_a, lat_b], axis=-1)  # (..., C, 2 rings)
    rad = np.concatenate([np.repeat(ra[..., None], rings, -1), np.repeat(rb[..., None], rings, -1)], -1)
    ctr = np.concatenate([np.repeat(a[..., None, :], rings, -2), np.repeat(b[..., None, :], rings, -2)], -2)
    th = 2 * np.pi * np.arange(segments) / segments
    ring_dir = (np.cos(th)[:, None] * e1[..., None, :] + np.sin(th)[:, None] * e2[..., None, :])  # (..., C, S, 3)
    n = (np.cos(lat)[..., :, None, None] * ring_dir[..., None, :, :]
         + np.sin(lat)[..., :, None, None] * axis[..., None, None, :])  # (..., C, 2R, S, 3)
    v = ctr[..., :, None, :] + rad[..., :, None, None] * n
    shape = (*v.shape[:-4], v.shape[-4], 2 * rings * segments, 3)
    v = v.reshape(shape)
    n = n.reshape(shape)
    pole_a = a - ra[..., None] * axis
    pole_b = b + rb[..., None] * axis
    verts = np.concatenate([pole_a[..., None, :], v, pole_b[..., None, :]], axis=-2)
    norms = np.concatenate([-axis[..., None, :], n, axis[..., None, :]], axis=-2)
    return verts, norms


@dataclass(frozen=True)
class BodyMesh:
    """Mesh generator for one body: fixed topology, vertices from a pose.

    Parameters
    ----------
    body : Body
        Skeleton offsets and capsule radii.
    segments, rings : int
        Tessellation of every capsule (defaults give ~10k triangles for the whole body).
    """

    body: Body
    segments: int = 24
    rings: int = 6

    @property
    def verts_per_capsule(self) -> int:
        return 2 + 2 * self.rings * self.segments

    @property
    def faces(self) -> NDArray[np.int64]:
        """(F, 3) int64 faces of the whole body (capsule ``c``'s faces are contiguous)."""
        one = capsule_mesh_topology(self.segments, self.rings)
        off = (np.arange(N_CAPSULES) * self.verts_per_capsule)[:, None, None]
        return (one[None] + off).reshape(-1, 3)

    @property
    def face_part(self) -> NDArray[np.int64]:
        """(F,) int64 body part (index into :data:`~protocol.skeleton.PARTS`) of every face."""
        per = 2 * self.segments * 2 * self.rings
        return np.repeat(CAPSULE_PART, per)

    @property
    def vertex_part(self) -> NDArray[np.int64]:
        """(V,) int64 body part of every vertex."""
        return np.repeat(CAPSULE_PART, self.verts_per_capsule)

    def vertices(self, joints: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Posed vertices and normals.

        Parameters
        ----------
        joints : (..., J, 3) float
            Joint positions (from :func:`protocol.kinematics.fk`).

        Returns
        -------
        vertices, normals : (..., V, 3) float64
        """
        v, n = tapered_capsules(capsule_endpoints(joints), self.body.capsule_radii, self.segments, self.rings)
        shape = (*v.shape[:-3], -1, 3)
        return v.reshape(shape), n.reshape(shape)

    def trimesh_at(self, pose: ArrayLike) -> trimesh.Trimesh:
        """The body in ``pose (P,)`` as a ``trimesh.Trimesh`` (not watertight-merged: one shell per capsule)."""
        v, n = self.vertices(fk(np.asarray(pose, dtype=np.float64), self.body))
        return trimesh.Trimesh(vertices=v, faces=self.faces, vertex_normals=n, process=False)
