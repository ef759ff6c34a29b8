"""Textured surface primitives for the synthetic scene: ring grids (lofts, tubes, ellipsoids) with
seam-aware smooth normals, and boxes with per-face texture coordinates.

A ring grid is ``(K, S, 3)`` points: ``K`` cross-section rings of ``S`` points each. The mesh gets
``S + 1`` columns (the last repeats the first, so the texture ``u`` can run from 0 to 1 without a
wrap-around triangle); normals are averaged across that seam and over collapsed pole rings, so
shading is smooth everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Surface", "box_surface", "ellipsoid_rings", "merge_surfaces", "ring_surface", "tube_rings"]


@dataclass(frozen=True)
class Surface:
    """A triangle surface with texture coordinates.

    Attributes
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64
        Counter-clockwise seen from outside.
    normals : (V, 3) float64
        Unit vertex normals.
    uv : (V, 2) float64
        Texture coordinates (glTF: ``v`` along image rows from the top; repeat wrapping).
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    normals: NDArray[np.float64]
    uv: NDArray[np.float64]


def _smooth_normals(v: NDArray[np.float64], f: NDArray[np.int64], canon: NDArray[np.int64]) -> NDArray[np.float64]:
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # area-weighted face normals
    acc = np.zeros((int(canon.max()) + 1, 3))
    for k in range(3):
        np.add.at(acc, canon[f[:, k]], fn)
    n = acc[canon]
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(norm > 1e-15, n / np.maximum(norm, 1e-15), np.array([0.0, 1.0, 0.0]))


def ring_surface(rings: ArrayLike, u_repeat: float = 1.0, v_scale: float | None = None,
                 v_values: ArrayLike | None = None) -> Surface:
    """Mesh of a ring grid.

    Parameters
    ----------
    rings : (K, S, 3) float
        Cross-section rings (a ring whose points coincide is a pole).
    u_repeat : float
        Texture repeats around the ring.
    v_scale : float, optional
        Metres per texture repeat along the rings (``v`` = arc length of ring centres / ``v_scale``).
    v_values : (K,) float, optional
        Explicit ``v`` of each ring (overrides ``v_scale``); default ``k / (K - 1)``.

    Returns
    -------
    Surface
        Faces oriented outwards (away from each ring's centre).
    """
    r = np.asarray(rings, dtype=np.float64)
    k_n, s_n = r.shape[:2]
    grid = np.concatenate([r, r[:, :1]], axis=1)  # (K, S + 1, 3)
    verts = grid.reshape(-1, 3)
    kk, cc = np.meshgrid(np.arange(k_n), np.arange(s_n + 1), indexing="ij")
    canon = kk * (s_n + 1) + (cc % s_n)
    spread = np.ptp(r, axis=1).max(axis=1)
    canon[spread < 1e-12] = (kk * (s_n + 1))[spread < 1e-12]  # collapsed rings are single points
    canon = canon.reshape(-1)
    a = (kk[:-1, :-1] * (s_n + 1) + cc[:-1, :-1]).reshape(-1)
    b, c, d = a + 1, a + s_n + 2, a + s_n + 1
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    ctr = r.mean(axis=1)
    if v_values is not None:
        vv = np.asarray(v_values, dtype=np.float64)
    elif v_scale is not None:
        vv = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ctr, axis=0), axis=1))]) / v_scale
    else:
        vv = np.arange(k_n) / max(k_n - 1, 1)
    uv = np.stack([cc.reshape(-1) / s_n * u_repeat, np.repeat(vv, s_n + 1)], axis=1)
    normals = _smooth_normals(verts, faces, canon)
    mid = k_n // 2
    probe = grid[mid, : s_n] - ctr[mid]
    if np.sum(normals.reshape(k_n, s_n + 1, 3)[mid, :s_n] * probe) < 0:
        faces = faces[:, ::-1].copy()
        normals = -normals
    return Surface(verts, faces, normals, uv)


def tube_rings(start: ArrayLike, axis: ArrayLike, e1: ArrayLike, profile: ArrayLike, segments: int,
               offset: ArrayLike | None = None) -> NDArray[np.float64]:
    """Rings of an elliptical tube along a straight axis.

    Parameters
    ----------
    start : (3,) float
        Point where ``s = 0``.
    axis : (3,) float
        Unit direction of increasing ``s``.
    e1 : (3,) float
        Unit direction of the first ellipse axis (perpendicular to ``axis``); the second is
        ``axis x e1``.
    profile : (K, 3) float
        ``(s, a, b)`` per ring: position along the axis and semi-axes along ``e1`` and ``e2``.
    segments : int
    offset : (K, 2) float, optional
        Shift of each ring's centre along ``e1`` and ``e2``.

    Returns
    -------
    (K, segments, 3) float64
    """
    ax = np.asarray(axis, dtype=np.float64)
    u = np.asarray(e1, dtype=np.float64)
    w = np.cross(ax, u)
    p = np.asarray(profile, dtype=np.float64)
    th = 2 * np.pi * np.arange(segments) / segments
    ctr = np.asarray(start, dtype=np.float64) + p[:, :1] * ax
    if offset is not None:
        off = np.asarray(offset, dtype=np.float64)
        ctr = ctr + off[:, :1] * u + off[:, 1:2] * w
    ring = (p[:, 1:2, None] * np.cos(th)[None, :, None] * u + p[:, 2:3, None] * np.sin(th)[None, :, None] * w)
    return ctr[:, None, :] + ring


def ellipsoid_rings(centre: ArrayLike, semi: ArrayLike, rings: int, segments: int,
                    front_u: float = 0.5) -> NDArray[np.float64]:
    """Latitude rings of an ellipsoid from the top pole (+Y) to the bottom pole.

    Column ``c`` lies at longitude ``2 pi (c / segments - front_u)`` measured from +Z towards +X, so
    texture ``u = front_u`` faces +Z.

    Returns
    -------
    (rings, segments, 3) float64
    """
    c = np.asarray(centre, dtype=np.float64)
    a, b, d = np.asarray(semi, dtype=np.float64)
    lat = np.linspace(np.pi / 2, -np.pi / 2, rings)
    lon = 2 * np.pi * (np.arange(segments) / segments - front_u)
    x = a * np.cos(lat)[:, None] * np.sin(lon)[None, :]
    y = b * np.sin(lat)[:, None] * np.ones(segments)[None, :]
    z = d * np.cos(lat)[:, None] * np.cos(lon)[None, :]
    return c + np.stack([x, y, z], axis=-1)


def box_surface(lo: ArrayLike, hi: ArrayLike, metres_per_repeat: float | None = None) -> Surface:
    """An axis-aligned box with flat shading and per-face texture coordinates.

    Parameters
    ----------
    lo, hi : (3,) float
        Opposite corners.
    metres_per_repeat : float, optional
        Texture scale; default: each face maps the whole texture once.
    """
    lo_a, hi_a = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    verts: list[NDArray[np.float64]] = []
    normals: list[NDArray[np.float64]] = []
    uvs: list[NDArray[np.float64]] = []
    faces: list[list[int]] = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            i, j = [k for k in range(3) if k != axis]
            if sign < 0:
                i, j = j, i
            corner = np.where(n > 0, hi_a, lo_a)
            quad = []
            for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                p = corner.copy()
                p[i] = lo_a[i] if du == 0 else hi_a[i]
                p[j] = lo_a[j] if dv == 0 else hi_a[j]
                quad.append(p)
            q = np.array(quad)
            if np.dot(np.cross(q[1] - q[0], q[2] - q[0]), n) < 0:
                q = q[::-1]
            size_u, size_v = np.linalg.norm(q[1] - q[0]), np.linalg.norm(q[3] - q[0])
            su = size_u / metres_per_repeat if metres_per_repeat else 1.0
            sv = size_v / metres_per_repeat if metres_per_repeat else 1.0
            base = len(verts) * 4
            verts.append(q)
            normals.append(np.repeat(n[None], 4, 0))
            uvs.append(np.array([[0, sv], [su, sv], [su, 0], [0, 0]], np.float64))
            faces.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]])
    return Surface(np.concatenate(verts), np.asarray(faces, np.int64), np.concatenate(normals), np.concatenate(uvs))


def merge_surfaces(parts: list[Surface]) -> Surface:
    """Concatenate surfaces into one (faces re-indexed)."""
    offs = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    return Surface(np.concatenate([p.vertices for p in parts]),
                   np.concatenate([p.faces + o for p, o in zip(parts, offs, strict=True)]),
                   np.concatenate([p.normals for p in parts]), np.concatenate([p.uv for p in parts]))
