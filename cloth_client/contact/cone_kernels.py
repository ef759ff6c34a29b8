"""Numba kernels of the round-cone geometry: per-capsule tables, signed distance, penetration depth.

The plain numpy references are in :mod:`cloth_client.contact.collision` (:func:`round_cone_reference`,
:func:`penetration_reference`: the same rules, vectorised); tests hold both equal. The other contact
kernels (:mod:`~cloth_client.contact.response_kernels`, :mod:`~cloth_client.contact.seam_kernels`)
and the avatar's limb kernels measure against :func:`capsule_geometry`'s table with
:func:`round_cone_geo`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from cloth_client._jit import inline_kernel as _inline
from cloth_client._jit import jit_kernel as _jit

__all__ = ["GEO_COLS", "capsule_geometry", "penetration", "round_cone", "round_cone_geo"]

F64 = NDArray[np.float64]

#: Columns of the per-capsule geometry table built by :func:`capsule_geometry`.
GEO_COLS = 13


@_jit
def capsule_geometry(a: F64, b: F64, radii: F64, margin: float, geo: F64) -> None:  # pragma: no cover
    """Per-capsule constants ``geo (C, 13)``: a (3), u (3), length, sin phi, cos phi, ra, rb,
    bounding-sphere radius + margin, and 1.0 if one end sphere swallows the other (then the
    sphere's centre replaces ``a`` and its radius ``ra``)."""
    for c in range(a.shape[0]):
        bx, by, bz = b[c, 0] - a[c, 0], b[c, 1] - a[c, 1], b[c, 2] - a[c, 2]
        length = math.sqrt(bx * bx + by * by + bz * bz)
        ra, rb = radii[c, 0], radii[c, 1]
        geo[c, 11] = 0.5 * length + max(ra, rb) + margin
        if abs(ra - rb) >= length - 1e-9:
            big_b = rb > ra
            for d in range(3):
                geo[c, d] = b[c, d] if big_b else a[c, d]
                geo[c, 3 + d] = 0.0
            geo[c, 6], geo[c, 7], geo[c, 8] = 0.0, 0.0, 1.0
            geo[c, 9], geo[c, 10], geo[c, 12] = max(ra, rb), 1.0 if big_b else 0.0, 1.0
            continue
        for d in range(3):
            geo[c, d] = a[c, d]
        geo[c, 3], geo[c, 4], geo[c, 5] = bx / length, by / length, bz / length
        geo[c, 6] = length
        geo[c, 7] = (ra - rb) / length
        geo[c, 8] = math.sqrt(max(1.0 - geo[c, 7] ** 2, 0.0))
        geo[c, 9], geo[c, 10], geo[c, 12] = ra, rb, 0.0


@_inline
def round_cone_geo(px: float, py: float, pz: float, geo: F64,
                   c: int) -> tuple[float, float, float, float, float]:  # pragma: no cover
    """Signed distance, outward normal (nx, ny, nz) and axial parameter t of a point to the round
    cone described by row ``c`` of :func:`capsule_geometry`'s table ``geo``."""
    pax, pay, paz = px - geo[c, 0], py - geo[c, 1], pz - geo[c, 2]
    if geo[c, 12] > 0.5:  # a single sphere; geo[c, 10] holds t
        dq = math.sqrt(pax * pax + pay * pay + paz * paz)
        if dq < 1e-12:
            return -geo[c, 9], 0.0, 1.0, 0.0, geo[c, 10]
        return dq - geo[c, 9], pax / dq, pay / dq, paz / dq, geo[c, 10]
    ux, uy, uz, length, sin_phi, cos_phi = geo[c, 3], geo[c, 4], geo[c, 5], geo[c, 6], geo[c, 7], geo[c, 8]
    y = pax * ux + pay * uy + paz * uz
    wx, wy, wz = pax - y * ux, pay - y * uy, paz - y * uz
    rho = math.sqrt(wx * wx + wy * wy + wz * wz)
    tau = y * cos_phi - rho * sin_phi
    if tau < 0.0 or tau > length * cos_phi:
        if tau < 0.0:
            qx, qy, qz, r, t = pax, pay, paz, geo[c, 9], 0.0
        else:
            qx, qy, qz, r, t = pax - length * ux, pay - length * uy, paz - length * uz, geo[c, 10], 1.0
        dq = math.sqrt(qx * qx + qy * qy + qz * qz)
        if dq > 1e-12:
            return dq - r, qx / dq, qy / dq, qz / dq, t
        rho = 0.0  # at the sphere centre: fall through to the side normal
    if rho > 1e-12:
        wx, wy, wz = wx / rho, wy / rho, wz / rho
    else:  # on the axis: any perpendicular of u
        ex, ey, ez = (1.0, 0.0, 0.0) if abs(ux) < 0.9 else (0.0, 1.0, 0.0)
        wx, wy, wz = uy * ez - uz * ey, uz * ex - ux * ez, ux * ey - uy * ex
        wn = math.sqrt(wx * wx + wy * wy + wz * wz)
        wx, wy, wz = wx / wn, wy / wn, wz / wn
    nx, ny, nz = sin_phi * ux + cos_phi * wx, sin_phi * uy + cos_phi * wy, sin_phi * uz + cos_phi * wz
    if tau < 0.0:
        return -geo[c, 9], nx, ny, nz, 0.0
    if tau > length * cos_phi:
        return -geo[c, 10], nx, ny, nz, 1.0
    return y * sin_phi + rho * cos_phi - geo[c, 9], nx, ny, nz, min(max(y / length, 0.0), 1.0)


@_jit
def round_cone(px: float, py: float, pz: float, a: F64, b: F64, ra: float,
               rb: float) -> tuple[float, float, float, float, float]:  # pragma: no cover
    """Signed distance, outward normal and axial parameter of one point to one round cone
    (reference: :func:`cloth_client.contact.collision.round_cone_reference`, vectorised)."""
    geo = np.empty((1, GEO_COLS))
    radii = np.empty((1, 2))
    radii[0, 0], radii[0, 1] = ra, rb
    capsule_geometry(a.reshape(1, 3), b.reshape(1, 3), radii, 0.0, geo)
    return round_cone_geo(px, py, pz, geo, 0)


@_jit
def penetration(x: F64, a: F64, b: F64, radii: F64, inv_mass: F64, out: F64) -> None:  # pragma: no cover
    """``out[i]`` = depth (>= 0) of free particle ``i`` inside the union of capsules, else 0
    (reference: :func:`cloth_client.contact.collision.penetration_reference`)."""
    geo = np.empty((a.shape[0], GEO_COLS))
    capsule_geometry(a, b, radii, 0.0, geo)
    centre = 0.5 * (a + b)
    for i in range(x.shape[0]):
        deepest = 0.0
        if inv_mass[i] > 0.0:
            for c in range(a.shape[0]):
                ex, ey, ez = x[i, 0] - centre[c, 0], x[i, 1] - centre[c, 1], x[i, 2] - centre[c, 2]
                if ex * ex + ey * ey + ez * ez < geo[c, 11] * geo[c, 11]:
                    deepest = max(deepest, -round_cone_geo(x[i, 0], x[i, 1], x[i, 2], geo, c)[0])
        out[i] = deepest
