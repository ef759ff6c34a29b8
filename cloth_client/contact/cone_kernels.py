"""Numba kernels of the round-cone geometry: per-capsule tables, signed distance, penetration depth,
and the broad phase of the collision (each particle's candidate capsules).

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

__all__ = ["ALL_CAPSULES", "BROAD_BLOCK", "BROAD_SLACK", "GEO_COLS", "broad_phase", "capsule_geometry", "penetration",
           "round_cone", "round_cone_geo"]

F64 = NDArray[np.float64]

#: Columns of the per-capsule geometry table built by :func:`capsule_geometry`.
GEO_COLS = 13
#: Candidate mask meaning "test every capsule" (all bits set).
ALL_CAPSULES = -1
#: Distance (metres) a particle may move from where its candidate capsules were gathered
#: (:func:`broad_phase`) before :func:`~cloth_client.contact.response_kernels.collide` tests every
#: capsule again for it. A particle moves about 2 mm in a 5,000-particle garment's substep
#: (strain-limiting corrections included); a wider slack only adds candidates that miss.
BROAD_SLACK = 0.005
#: Consecutive particles (neighbours along a grid row) whose bounding sphere :func:`broad_phase`
#: tests against a capsule before testing them one by one.
BROAD_BLOCK = 16


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


@_jit
def broad_phase(x: F64, active: F64, a: F64, b: F64, radii: F64, reach: float, cand: NDArray[np.int64],
                xb: F64) -> None:  # pragma: no cover
    """Candidate capsules of every particle: bit ``c`` of ``cand[i]`` is set when particle ``i``
    lies within ``reach`` of the round cone ``c`` (signed distance below ``reach``). ``xb`` receives
    the positions the mask was gathered at. Reference:
    :func:`~cloth_client.contact.response.broad_phase_reference`.

    The signed distance to a round cone (a convex body) changes by at most as much as the point
    moves, so a particle within ``reach - margin`` (the slack) of ``xb[i]`` cannot touch a capsule
    missing from its mask. Blocks of :data:`BROAD_BLOCK` consecutive particles are skipped whole
    when their bounding sphere is farther than the capsule's largest radius plus ``reach`` from its
    axis; the others are tested one by one (bounding box, distance to the axis, then the distance to
    the cone).

    Parameters
    ----------
    x : (N, 3) float64
    active : (N,) float64
        Particles with ``active <= 0`` get an empty mask.
    a, b : (C, 3) float64
    radii : (C, 2) float64
    reach : float
        Clearance plus slack, metres.
    cand : (N,) int64
        Output bit masks (:data:`ALL_CAPSULES` for every particle when ``C > 62``).
    xb : (N, 3) float64
        Output copy of ``x``.
    """
    n, n_caps = x.shape[0], a.shape[0]
    for i in range(n):
        cand[i] = 0 if n_caps <= 62 else ALL_CAPSULES
        xb[i, 0], xb[i, 1], xb[i, 2] = x[i, 0], x[i, 1], x[i, 2]
    if n_caps > 62 or n == 0:
        return
    geo = np.empty((n_caps, GEO_COLS))
    capsule_geometry(a, b, radii, 0.0, geo)
    n_blocks = (n + BROAD_BLOCK - 1) // BROAD_BLOCK
    sphere = np.empty((n_blocks, 4))  # centre and radius of each block's bounding box
    for q in range(n_blocks):
        lo0 = hi0 = x[q * BROAD_BLOCK, 0]
        lo1 = hi1 = x[q * BROAD_BLOCK, 1]
        lo2 = hi2 = x[q * BROAD_BLOCK, 2]
        for i in range(q * BROAD_BLOCK + 1, min(n, (q + 1) * BROAD_BLOCK)):
            lo0, hi0 = min(lo0, x[i, 0]), max(hi0, x[i, 0])
            lo1, hi1 = min(lo1, x[i, 1]), max(hi1, x[i, 1])
            lo2, hi2 = min(lo2, x[i, 2]), max(hi2, x[i, 2])
        sphere[q, 0], sphere[q, 1], sphere[q, 2] = 0.5 * (lo0 + hi0), 0.5 * (lo1 + hi1), 0.5 * (lo2 + hi2)
        sphere[q, 3] = 0.5 * math.sqrt((hi0 - lo0) ** 2 + (hi1 - lo1) ** 2 + (hi2 - lo2) ** 2)
    for c in range(n_caps):
        ax, ay, az = a[c, 0], a[c, 1], a[c, 2]
        ux, uy, uz = b[c, 0] - ax, b[c, 1] - ay, b[c, 2] - az
        inv = 1.0 / max(ux * ux + uy * uy + uz * uz, 1e-300)
        r = max(radii[c, 0], radii[c, 1]) + reach
        bit = np.int64(1) << np.int64(c)
        # the capsule's bounding box grown by r: a particle outside it is farther than r from the axis
        lo0, hi0 = min(ax, b[c, 0]) - r, max(ax, b[c, 0]) + r
        lo1, hi1 = min(ay, b[c, 1]) - r, max(ay, b[c, 1]) + r
        lo2, hi2 = min(az, b[c, 2]) - r, max(az, b[c, 2]) + r
        for q in range(n_blocks):
            px, py, pz = sphere[q, 0] - ax, sphere[q, 1] - ay, sphere[q, 2] - az
            t = min(max((px * ux + py * uy + pz * uz) * inv, 0.0), 1.0)
            px, py, pz = px - t * ux, py - t * uy, pz - t * uz
            if px * px + py * py + pz * pz > (r + sphere[q, 3]) ** 2:
                continue  # the whole block is farther than r from the axis
            for i in range(q * BROAD_BLOCK, min(n, (q + 1) * BROAD_BLOCK)):
                if (x[i, 0] < lo0 or x[i, 0] > hi0 or x[i, 1] < lo1 or x[i, 1] > hi1
                        or x[i, 2] < lo2 or x[i, 2] > hi2 or active[i] <= 0.0):
                    continue
                px, py, pz = x[i, 0] - ax, x[i, 1] - ay, x[i, 2] - az
                t = min(max((px * ux + py * uy + pz * uz) * inv, 0.0), 1.0)
                px, py, pz = px - t * ux, py - t * uy, pz - t * uz
                if px * px + py * py + pz * pz >= r * r:
                    continue  # farther than r from the axis: outside the capsule round the cone
                if round_cone_geo(x[i, 0], x[i, 1], x[i, 2], geo, c)[0] < reach:
                    cand[i] |= bit
