"""Numba kernels for cloth-vs-body contact: round-cone geometry, collision response, penetration.

The plain numpy references are in :mod:`cloth_client.contact.collision` and :mod:`cloth_client.contact.response`
(same rules, vectorised); tests check that both agree. :mod:`cloth_client.solver._kernels` runs
:func:`collide` inside its substep loop.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

__all__ = ["ALL_CAPSULES", "BROAD_SLACK", "CARRY_JUMP", "COLLISION_PASSES", "CREASE_COS", "HIT_TOLERANCE",
           "PINCH_COS", "PINCH_DEPTH", "RELAX_RATE", "RELAX_STEPS", "SEAM_LENGTH_ROUNDS", "SEAM_LENGTH_SLACK",
           "SEAM_MIN_COS", "SEAM_RING_STRIDE", "SEAM_SHARED_PASSES", "STRADDLE_DEPTH", "STRADDLE_SAMPLES",
           "broad_phase", "capsule_geometry", "clear_limbs", "collide", "covered", "inline_kernel", "jit_kernel",
           "keep_seam_length", "limb_overlap", "penetration", "pinch_margin", "push_out", "release_straddles",
           "round_cone", "round_cone_geo", "slide_seam"]

F64 = NDArray[np.float64]
#: numpy error model (no zero-division checks: every division is guarded by hand) and fast-math
#: flags that keep NaN/inf semantics, so a blow-up still shows as NaN instead of being optimised away.
jit_kernel = njit(cache=True, error_model="numpy", fastmath={"nsz", "arcp", "contract", "afn", "reassoc"})
_jit = jit_kernel
#: The same compiled inline into its callers (small helpers called per particle: no call overhead).
inline_kernel = njit(cache=True, inline="always", error_model="numpy",
                     fastmath={"nsz", "arcp", "contract", "afn", "reassoc"})
_inline = inline_kernel

#: Most projection passes over the capsules per particle (only particles moved in a pass get another).
COLLISION_PASSES = 4
#: Two contact normals with a cosine below this face each other: the cloth is in a crease.
PINCH_COS = -0.3
#: Two contact normals with a cosine below this (more than 90 degrees apart) but not below
#: :data:`PINCH_COS` are the sides of a V (next to where a forearm lies on the hip): the clearance
#: is half the gap there too, but never negative (the cloth may reach the surfaces, not go into them).
CREASE_COS = 0.0
#: Deepest (metres) cloth pinched between two overlapping body parts may sit inside both: it is put
#: half-way through their overlap (as if both soft surfaces gave way equally) instead of being
#: squeezed out to one side. Half the 2 cm sunk-limb depth (``DriverConfig.ghost_depth``) less 1 mm,
#: so cloth in any overlap the driver does not ghost stays within the 1 cm penetration target.
PINCH_DEPTH = 0.009
#: Columns of the per-capsule geometry table built by :func:`capsule_geometry`.
_GEO_COLS = 13
#: Further columns of :func:`collide`'s table: the capsule's centre (3), the motion of its ends over
#: the substep (``a1 - a0``, ``b1 - b0``) and ``max(ra, rb)``.
_CENTRE, _DA, _DB, _RMAX = 13, 16, 19, 22
_COLLIDE_COLS = 23
#: A particle closer than the clearance by less than this (metres) counts as on the surface, not in
#: contact (a projected particle re-measured at the clearance must not trigger another pass).
HIT_TOLERANCE = 1e-9
#: Candidate mask meaning "test every capsule" (all bits set).
ALL_CAPSULES = -1
#: Distance (metres) a particle may move from where its candidate capsules were gathered
#: (:func:`broad_phase`) before :func:`collide` tests every capsule again for it.
BROAD_SLACK = 0.02
#: A limb correction (:func:`clear_limbs`) that moves a joint further than this (metres) from the
#: previous key's correction is taken for a flip of the nearest trunk surface (it can also be a
#: fast motion seen through keys closer than ~3.5 ms): the previous correction is carried over.
CARRY_JUMP = 0.02
#: Largest fraction of a carried-over correction given back to the recording per key, and the
#: bisection steps that find how much of it keeps the limb clear.
RELAX_RATE = 0.25
RELAX_STEPS = 6


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
    """Signed distance, outward normal and axial parameter of one point to one round cone."""
    geo = np.empty((1, _GEO_COLS))
    radii = np.empty((1, 2))
    radii[0, 0], radii[0, 1] = ra, rb
    capsule_geometry(a.reshape(1, 3), b.reshape(1, 3), radii, 0.0, geo)
    return round_cone_geo(px, py, pz, geo, 0)


@_jit
def broad_phase(x: F64, active: F64, a: F64, b: F64, radii: F64, reach: float, cand: NDArray[np.int64],
                xb: F64) -> None:  # pragma: no cover
    """Candidate capsules of every particle: bit ``c`` of ``cand[i]`` is set when particle ``i``
    lies within ``reach`` of the capsule ``c`` of radius ``max(ra, rb)`` round the axis ``a[c] b[c]``
    (which contains the round cone). ``xb`` receives the positions the mask was gathered at.

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
    n = x.shape[0]
    for i in range(n):
        cand[i] = 0 if a.shape[0] <= 62 else ALL_CAPSULES
        xb[i, 0], xb[i, 1], xb[i, 2] = x[i, 0], x[i, 1], x[i, 2]
    if a.shape[0] > 62:
        return
    for c in range(a.shape[0]):
        ax, ay, az = a[c, 0], a[c, 1], a[c, 2]
        ux, uy, uz = b[c, 0] - ax, b[c, 1] - ay, b[c, 2] - az
        inv = 1.0 / max(ux * ux + uy * uy + uz * uz, 1e-300)
        r = max(radii[c, 0], radii[c, 1]) + reach
        r2 = r * r
        bit = np.int64(1) << np.int64(c)
        # the capsule's bounding box grown by r: a particle outside it is farther than r from the axis
        lo0, hi0 = min(ax, b[c, 0]) - r, max(ax, b[c, 0]) + r
        lo1, hi1 = min(ay, b[c, 1]) - r, max(ay, b[c, 1]) + r
        lo2, hi2 = min(az, b[c, 2]) - r, max(az, b[c, 2]) + r
        for i in range(n):
            if (x[i, 0] < lo0 or x[i, 0] > hi0 or x[i, 1] < lo1 or x[i, 1] > hi1
                    or x[i, 2] < lo2 or x[i, 2] > hi2):
                continue
            px, py, pz = x[i, 0] - ax, x[i, 1] - ay, x[i, 2] - az
            t = min(max((px * ux + py * uy + pz * uz) * inv, 0.0), 1.0)
            qx, qy, qz = px - t * ux, py - t * uy, pz - t * uz
            if qx * qx + qy * qy + qz * qz < r2 and active[i] > 0.0:
                cand[i] |= bit


@_inline
def _push(x: F64, v: F64, i: int, push: float, nx: float, ny: float, nz: float,
          vsx: float, vsy: float, vsz: float) -> float:  # pragma: no cover
    """Move particle ``i`` by ``push`` along ``n`` and cancel its approach to the surface moving at
    ``vs``; returns the normal velocity change (>= 0) for friction."""
    x[i, 0] += push * nx
    x[i, 1] += push * ny
    x[i, 2] += push * nz
    vn = (v[i, 0] - vsx) * nx + (v[i, 1] - vsy) * ny + (v[i, 2] - vsz) * nz
    if vn >= 0.0:
        return 0.0
    v[i, 0] -= vn * nx
    v[i, 1] -= vn * ny
    v[i, 2] -= vn * nz
    return -vn


@_inline
def _friction(v: F64, i: int, nx: float, ny: float, nz: float, vsx: float, vsy: float, vsz: float, dvn: float,
              friction: float) -> None:  # pragma: no cover
    """Coulomb friction: reduce the tangential velocity relative to the surface (normal ``n``, moving
    at ``vs``) by ``friction * dvn``."""
    rx, ry, rz = v[i, 0] - vsx, v[i, 1] - vsy, v[i, 2] - vsz
    vn = rx * nx + ry * ny + rz * nz
    tx, ty, tz = rx - vn * nx, ry - vn * ny, rz - vn * nz
    vt = math.sqrt(tx * tx + ty * ty + tz * tz)
    if vt <= 1e-12:
        return
    scale = max(0.0, 1.0 - friction * dvn / vt) - 1.0
    v[i, 0] += scale * tx
    v[i, 1] += scale * ty
    v[i, 2] += scale * tz


@_jit
def pinch_margin(px: float, py: float, pz: float, geo: F64, centre: F64, margin: float) -> float:  # pragma: no cover
    """Clearance a particle at ``p`` can keep from the body: ``margin``, or less in a crease.

    If the two nearest capsules within ``margin`` face each other (normals more than
    :data:`PINCH_COS` apart), the cloth lies in the gap between two body parts: it keeps half the
    gap from each instead of ``margin``, so it fits in the gap rather than being ploughed along by
    the part that closes it. Where the two overlap (a forearm pressed on the hip) the "half gap" is
    negative: the cloth sits half-way through the overlap, at most :data:`PINCH_DEPTH` inside each,
    instead of being squeezed out to one side of the limb (which stretched the cloth across it).
    In a wider V (normals between 90 degrees, :data:`CREASE_COS`, and :data:`PINCH_COS` apart: the
    sides of such an overlap) it keeps half the gap too, but at least 0, so the cloth next to the
    part held in the overlap is not pushed out of the V to the full margin."""
    d1 = d2 = margin
    n1x = n1y = n1z = n2x = n2y = n2z = 0.0
    for c in range(geo.shape[0]):
        ex, ey, ez = px - centre[c, 0], py - centre[c, 1], pz - centre[c, 2]
        if ex * ex + ey * ey + ez * ez > geo[c, 11] * geo[c, 11]:
            continue
        d, nx, ny, nz, _t = round_cone_geo(px, py, pz, geo, c)
        if d < d1:
            d2, n2x, n2y, n2z = d1, n1x, n1y, n1z
            d1, n1x, n1y, n1z = d, nx, ny, nz
        elif d < d2:
            d2, n2x, n2y, n2z = d, nx, ny, nz
    cos = n1x * n2x + n1y * n2y + n1z * n2z
    if d2 < margin and cos < CREASE_COS:
        return min(margin, max(-PINCH_DEPTH if cos < PINCH_COS else 0.0, 0.5 * (d1 + d2)))
    return margin


@_inline
def _side(x: F64, i: int, d: float, nx: float, ny: float, nz: float, t: float, geo: F64, c: int, qx: float,
          qy: float, qz: float) -> tuple[float, float, float, float, float]:  # pragma: no cover
    """Keep particle ``i`` on the side of capsule ``c`` it came from.

    ``q`` (the particle at the start of the substep) is carried along with the capsule's motion
    (columns :data:`_DA`, :data:`_DB` of :func:`collide`'s table ``geo``); if that point is outside
    the capsule and its normal faces away from ``n`` (the normal of the nearest surface to the
    particle, inside the capsule), the particle went through the axis within the substep (a limb
    pressed into cloth the strain limit holds back): it is put back at the carried point and the
    distance, normal and axial parameter there are returned instead."""
    qx = qx + (1.0 - t) * geo[c, _DA] + t * geo[c, _DB]
    qy = qy + (1.0 - t) * geo[c, _DA + 1] + t * geo[c, _DB + 1]
    qz = qz + (1.0 - t) * geo[c, _DA + 2] + t * geo[c, _DB + 2]
    dq, mx, my, mz, tq = round_cone_geo(qx, qy, qz, geo, c)
    if dq > 0.0 and mx * nx + my * ny + mz * nz < 0.0:
        x[i, 0], x[i, 1], x[i, 2] = qx, qy, qz
        return dq, mx, my, mz, tq
    return d, nx, ny, nz, t


@_inline
def _resolve(x: F64, v: F64, i: int, m: float, geo: F64, margin: float, friction: float, dt: float, floor: float,
             use_floor: bool, contact: F64, mask0: int, bx: float, by: float, bz: float, slack: float, qx: float,
             qy: float, qz: float) -> bool:  # pragma: no cover
    """Projection passes of particle ``i`` with clearance ``m`` from the capsules (``margin`` from the
    floor), then friction or, if pinched, the stoutest touched part's velocity; True if pinched.
    ``geo``: :func:`collide`'s per-capsule table. Only the capsules in ``mask0`` (the
    particle's :func:`broad_phase` mask) are tested while the particle is within ``slack`` of ``b``
    (where the mask was gathered; every capsule otherwise). A particle found past the capsule's axis
    from ``q`` (where it was at the start of the substep) carried along with the capsule goes back
    to that side (:func:`_side`).

    Each array handed to an inlined helper with loops costs a reference-count increment and
    decrement per call: the broad-phase data and the start position come in as numbers, the
    capsules in one table. (The position and velocity stay in ``x``, ``v``: carried as numbers,
    some dot products of them were summed in another order.)"""
    n_caps = geo.shape[0]
    for o in range(6):
        contact[i, o] = 0.0
    first = -1
    pinched = False
    dvn = 0.0
    big = -1.0
    fnx = fny = fnz = fvx = fvy = fvz = hvx = hvy = hvz = 0.0  # first normal, its surface's velocity, held
    for _ in range(COLLISION_PASSES):
        moved = False
        ox, oy, oz = x[i, 0] - bx, x[i, 1] - by, x[i, 2] - bz
        mask = mask0 if ox * ox + oy * oy + oz * oz <= slack * slack else ALL_CAPSULES
        for c in range(n_caps):
            if c < 63 and (mask >> c) & 1 == 0:
                continue
            ex, ey, ez = x[i, 0] - geo[c, _CENTRE], x[i, 1] - geo[c, _CENTRE + 1], x[i, 2] - geo[c, _CENTRE + 2]
            if ex * ex + ey * ey + ez * ez > geo[c, 11] * geo[c, 11]:
                continue
            d, nx, ny, nz, t = round_cone_geo(x[i, 0], x[i, 1], x[i, 2], geo, c)
            if d < m - HIT_TOLERANCE:
                d, nx, ny, nz, t = _side(x, i, d, nx, ny, nz, t, geo, c, qx, qy, qz)
                vsx = ((1.0 - t) * geo[c, _DA] + t * geo[c, _DB]) / dt
                vsy = ((1.0 - t) * geo[c, _DA + 1] + t * geo[c, _DB + 1]) / dt
                vsz = ((1.0 - t) * geo[c, _DA + 2] + t * geo[c, _DB + 2]) / dt
                dv = _push(x, v, i, m - d, nx, ny, nz, vsx, vsy, vsz)
                _record(contact, i, c, first, nx, ny, nz)
                if geo[c, _RMAX] > big:  # the stoutest body part touched holds pinched cloth
                    big = geo[c, _RMAX]
                    hvx, hvy, hvz = vsx, vsy, vsz
                if first < 0 or first == c:
                    first = c
                    dvn += dv
                    fnx, fny, fnz = nx, ny, nz
                    fvx, fvy, fvz = vsx, vsy, vsz
                else:
                    pinched = True
                moved = True
        if use_floor and x[i, 1] < floor + margin - HIT_TOLERANCE:
            dv = _push(x, v, i, floor + margin - x[i, 1], 0.0, 1.0, 0.0, 0.0, 0.0, 0.0)
            _record(contact, i, n_caps, first, 0.0, 1.0, 0.0)
            if first < 0 or first == n_caps:
                first = n_caps
                dvn += dv
                fnx, fny, fnz = 0.0, 1.0, 0.0
                fvx, fvy, fvz = 0.0, 0.0, 0.0
            else:
                pinched = True
            moved = True
        if not moved:
            break
    if first >= 0 and not pinched:
        _friction(v, i, fnx, fny, fnz, fvx, fvy, fvz, dvn, friction)
    elif pinched and big > 0.0:
        v[i, 0], v[i, 1], v[i, 2] = hvx, hvy, hvz
    return pinched


@_jit
def collide(x: F64, v: F64, active: F64, a0: F64, b0: F64, a1: F64, b1: F64, radii: F64,
            margin: float, friction: float, dt: float, floor: float, use_floor: bool,
            contact: F64, cand: NDArray[np.int64], xb: F64, slack: float, xprev: F64) -> None:  # pragma: no cover
    """Project particles (those with ``active > 0``) out of the capsules ``(a1, b1)`` and the floor;
    same rules as ``collide_np``. ``xprev (N, 3)``: positions at the start of the substep (a
    particle that went through a capsule's axis since is put back on its side).

    ``cand (N,)``, ``xb (N, 3)`` are a :func:`broad_phase` of ``(a1, b1)`` with reach
    ``margin + slack``: a particle within ``slack`` of ``xb[i]`` tests only its candidate
    capsules, any other every capsule (same result as without the broad phase; pass
    :data:`ALL_CAPSULES` masks to test every capsule always).

    ``contact (N, 6)`` receives the normals of the first and of another surface each particle was
    pushed off (zero where none). Friction acts on particles that touch a single surface only; a
    particle pinched between body parts takes the velocity of the stoutest one it touches (cloth
    pressed against the hip by a hand stays with the hip instead of being torn along by the hand).
    A pinched particle in a crease narrower than twice the margin is resolved again from where it
    was with the clearance of :func:`pinch_margin` (half the gap, negative where the two overlap),
    so it fits in the gap; it keeps the velocity of the stoutest part of the first resolve (the
    second may touch only one of the two surfaces, whose friction would drag it along)."""
    geo = np.empty((a1.shape[0], _COLLIDE_COLS))  # capsule_geometry's columns, then the ones of _resolve
    capsule_geometry(a1, b1, radii, margin, geo)
    centre = 0.5 * (a1 + b1)
    for c in range(a1.shape[0]):
        for d in range(3):
            geo[c, _CENTRE + d] = centre[c, d]
            geo[c, _DA + d] = a1[c, d] - a0[c, d]
            geo[c, _DB + d] = b1[c, d] - b0[c, d]
        geo[c, _RMAX] = max(radii[c, 0], radii[c, 1])
    for i in range(x.shape[0]):
        ox, oy, oz = x[i, 0] - xb[i, 0], x[i, 1] - xb[i, 1], x[i, 2] - xb[i, 2]
        if active[i] <= 0.0 or (cand[i] == 0 and ox * ox + oy * oy + oz * oz <= slack * slack
                                and not (use_floor and x[i, 1] < floor + margin - HIT_TOLERANCE)):
            for o in range(6):  # nothing within reach (the common case): no call, no contact
                contact[i, o] = 0.0
            continue
        px, py, pz = x[i, 0], x[i, 1], x[i, 2]
        ux, uy, uz = v[i, 0], v[i, 1], v[i, 2]
        mask, bx, by, bz = cand[i], xb[i, 0], xb[i, 1], xb[i, 2]
        qx, qy, qz = xprev[i, 0], xprev[i, 1], xprev[i, 2]
        if not _resolve(x, v, i, margin, geo, margin, friction, dt, floor, use_floor, contact, mask, bx, by, bz, slack,
                        qx, qy, qz):
            continue
        m = pinch_margin(px, py, pz, geo, centre, margin)
        if m < margin:  # a crease: start again with the clearance the gap leaves
            hx, hy, hz = v[i, 0], v[i, 1], v[i, 2]  # the stoutest touched part's velocity
            x[i, 0], x[i, 1], x[i, 2] = px, py, pz
            v[i, 0], v[i, 1], v[i, 2] = ux, uy, uz
            _resolve(x, v, i, m, geo, margin, friction, dt, floor, use_floor, contact, mask, bx, by, bz, slack, qx, qy,
                     qz)
            v[i, 0], v[i, 1], v[i, 2] = hx, hy, hz  # it is still in the crease, held by the stoutest part


@_inline
def _record(contact: F64, i: int, surface: int, first: int, nx: float, ny: float,
            nz: float) -> None:  # pragma: no cover
    """Note a contact of particle ``i``: the first surface's normal in ``[0:3]``, a second surface's
    in ``[3:6]``."""
    o = 0 if first < 0 or first == surface else 3
    contact[i, o], contact[i, o + 1], contact[i, o + 2] = nx, ny, nz


#: A stretched spring whose chord passes more than this (metres, half a millimetre) inside a capsule, both ends
#: outside it, straddles a body part (:func:`release_straddles`).
STRADDLE_DEPTH = 0.0005
#: Interior samples of a spring's chord tested against the capsules (at ``k / (n + 1)``).
STRADDLE_SAMPLES = 9


@_jit
def release_straddles(x: F64, inv_mass: F64, springs: NDArray[np.int64], hi: F64, trigger2: float, a: F64, b: F64,
                      radii: F64, margin: float, opposed: float) -> int:  # pragma: no cover
    """Lift springs that straddle a body part off it (reference: ``contact.release_straddles_np``).

    A spring ``s`` stretched beyond ``(l / hi[s])**2 > trigger2`` whose chord passes more than
    :data:`STRADDLE_DEPTH` inside a capsule, with both its ends outside that capsule and the
    capsule's outward normals at the two ends pointing apart (``n_i . n_j < opposed``), has a limb
    between its two particles: particle-vs-capsule collision pushes each end out to its own side
    and the strain limit cannot pull them together through the limb (the limb slipped between two
    particles: a shin between two rows of a skirt's hem, an arm up through a cape). Cloth draped
    round a limb also has its chord inside it, but with both ends on the same side; lifting that
    pumped a skirt off a forearm (session 17), hence the side test (session 18). The chord is
    moved out of the capsule along the outward normal ``n`` at its deepest sample ``t`` to the
    cloth margin: push ``p = margin - d(t)`` split between the ends by the least-norm rule
    ``w_i (1 - t) p n / D`` and ``w_j t p n / D``, ``D = w_i (1 - t)**2 + w_j t**2`` (``w`` the
    inverse masses, so a pin does not move). The limb then lies on one side of the cloth and the
    strain limit can shorten the spring around it. The ends keep their contact normals, so the
    line solves that follow still slide them along the surfaces they touch (clearing them let a
    particle between the legs be pulled into the other leg: on the 252 recordings' failing walks,
    `walk_feminine_001` 38 % with clearing, 7.9 % without). Springs are visited in order, each
    from the current positions; ``contact`` is read by the callers' passes, not here. Returns the
    number of springs released.
    """
    geo = np.empty((a.shape[0], _GEO_COLS))
    capsule_geometry(a, b, radii, 0.0, geo)
    released = 0
    for s in range(springs.shape[0]):
        i, j = springs[s, 0], springs[s, 1]
        dx, dy, dz = x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2]
        if not (dx * dx + dy * dy + dz * dz) > trigger2 * hi[s] * hi[s]:
            continue
        wi, wj = inv_mass[i], inv_mass[j]
        if wi + wj <= 0.0:
            continue
        deep, cap, bt, bnx, bny, bnz = -STRADDLE_DEPTH, -1, 0.0, 0.0, 0.0, 0.0
        for c in range(a.shape[0]):
            for k in range(1, STRADDLE_SAMPLES + 1):
                t = k / (STRADDLE_SAMPLES + 1)
                d, nx, ny, nz, _ = round_cone_geo(x[i, 0] + t * dx, x[i, 1] + t * dy, x[i, 2] + t * dz, geo, c)
                if d < deep:
                    deep, cap, bt, bnx, bny, bnz = d, c, t, nx, ny, nz
        if cap < 0:
            continue
        di, inx, iny, inz, _ = round_cone_geo(x[i, 0], x[i, 1], x[i, 2], geo, cap)
        dj, jnx, jny, jnz, _ = round_cone_geo(x[j, 0], x[j, 1], x[j, 2], geo, cap)
        if di < 0.0 or dj < 0.0:
            continue  # an end inside: collision moves that particle out
        if not inx * jnx + iny * jny + inz * jnz < opposed:
            continue  # both ends on the same side of the limb: cloth draped round it, not a limb between them
        den = wi * (1.0 - bt) ** 2 + wj * bt * bt
        push = (margin - deep) / den
        fi, fj = wi * (1.0 - bt) * push, wj * bt * push
        x[i, 0] += fi * bnx
        x[i, 1] += fi * bny
        x[i, 2] += fi * bnz
        x[j, 0] += fj * bnx
        x[j, 1] += fj * bny
        x[j, 2] += fj * bnz
        released += 1
    return released


@_jit
def penetration(x: F64, a: F64, b: F64, radii: F64, inv_mass: F64, out: F64) -> None:  # pragma: no cover
    """``out[i]`` = depth (>= 0) of free particle ``i`` inside the union of capsules, else 0."""
    geo = np.empty((a.shape[0], _GEO_COLS))
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
def covered(points: F64, a: F64, b: F64, radii: F64, reach: F64, out: NDArray[np.bool_]) -> None:  # pragma: no cover
    """``out[p]``: point ``p`` is within ``reach[c]`` metres of some capsule ``c`` (endpoints per
    key in ``a, b``) at some key (reference: ``AvatarKeys.covered(..., backend="numpy")``).

    Parameters
    ----------
    points : (K + 1, P, 3) float64
    a, b : (K + 1, C, 3) float64
    radii : (C, 2) float64
    reach : (C,) float64
    out : (P,) bool
    """
    geo = np.empty((a.shape[1], _GEO_COLS))
    out[:] = False
    for k in range(points.shape[0]):
        capsule_geometry(a[k], b[k], radii, 0.0, geo)
        for p in range(points.shape[1]):
            for c in range(a.shape[1]):
                if out[p]:
                    break
                d = round_cone_geo(points[k, p, 0], points[k, p, 1], points[k, p, 2], geo, c)[0]
                out[p] = d < reach[c]


@_jit
def limb_overlap(a: F64, b: F64, radii: F64, limbs: NDArray[np.int64], trunk: NDArray[np.int64], s: F64,
                 out: F64) -> None:  # pragma: no cover
    """``out[l]``: largest ``r_limb(s) - min_t d_t(s)`` over the axis samples ``s`` of limb capsule
    ``limbs[l]`` and the trunk capsules ``trunk`` (reference:
    ``limb_clearance.limb_overlap(..., backend="numpy")``).

    Parameters
    ----------
    a, b : (C, 3) float64
    radii : (C, 2) float64
    limbs : (L,) int64
    trunk : (T,) int64
    s : (S,) float64
        Axis fractions.
    out : (L,) float64
    """
    for ix in (limbs, trunk):  # indices are checked here, where it costs nothing (no bounds checks below)
        for i in range(ix.shape[0]):
            if ix[i] < 0 or ix[i] >= a.shape[0]:
                raise ValueError("limb_overlap: a capsule index is out of range")
    geo = np.empty((a.shape[0], _GEO_COLS))
    capsule_geometry(a, b, radii, 0.0, geo)
    for li in range(limbs.shape[0]):
        c = limbs[li]
        worst = -np.inf
        for k in range(s.shape[0]):
            u = s[k]
            px = a[c, 0] + u * (b[c, 0] - a[c, 0])
            py = a[c, 1] + u * (b[c, 1] - a[c, 1])
            pz = a[c, 2] + u * (b[c, 2] - a[c, 2])
            d_min = np.inf
            for ti in range(trunk.shape[0]):
                d = round_cone_geo(px, py, pz, geo, trunk[ti])[0]
                if d != d or d < d_min:  # a NaN propagates, as in the numpy reference
                    d_min = d
            depth = (1.0 - u) * radii[c, 0] + u * radii[c, 1] - d_min
            if depth != depth or depth > worst:
                worst = depth
        out[li] = worst


@_inline
def _push_point(points: F64, k: int, p: int, geo: F64, n_caps: int, clearance: float) -> None:  # pragma: no cover
    """One projection of ``points[k, p]`` to ``clearance`` outside the nearest capsule of ``geo``
    (least signed distance, the first on a tie; a NaN distance wins, as numpy's argmin: not moved)."""
    px, py, pz = points[k, p, 0], points[k, p, 1], points[k, p, 2]
    best, bx, by, bz = np.inf, 0.0, 0.0, 0.0
    for c in range(n_caps):
        d, nx, ny, nz, _t = round_cone_geo(px, py, pz, geo, c)
        if d != d:
            best = d
            break
        if d < best:
            best, bx, by, bz = d, nx, ny, nz
    depth = clearance - best
    if depth > 0.0:
        points[k, p, 0] = px + depth * bx
        points[k, p, 1] = py + depth * by
        points[k, p, 2] = pz + depth * bz


@_jit
def push_out(points: F64, a: F64, b: F64, radii: F64, clearance: float, passes: int) -> None:  # pragma: no cover
    """Move ``points`` in place to at least ``clearance`` metres outside the body at their key:
    ``passes`` projections along the normal of the nearest capsule (the one of least signed
    distance; the first on a tie). Reference: ``AvatarKeys.push_out(..., backend="numpy")``.

    Parameters
    ----------
    points : (K + 1, P, 3) float64
        Modified in place.
    a, b : (K + 1, C, 3) float64
    radii : (C, 2) float64
    clearance : float
    passes : int
    """
    geo = np.empty((a.shape[1], _GEO_COLS))
    for k in range(points.shape[0]):
        capsule_geometry(a[k], b[k], radii, 0.0, geo)
        for p in range(points.shape[1]):
            for _ in range(passes):
                _push_point(points, k, p, geo, a.shape[1], clearance)


#: Passes of the shared push of a slid seam's covered pins (:func:`slide_seam`).
SEAM_SHARED_PASSES = 3
#: Floor of the cosine between a pin's own normal and its capsule's shared push direction: a pin on
#: the side of the body part moves at most twice its depth along that direction.
SEAM_MIN_COS = 0.5
#: Rounds of the slid seam's length pass (:func:`keep_seam_length`), and the stretch over rest it
#: leaves a seam segment (the cloth's own strain limit lets a spring reach 3 %).
SEAM_LENGTH_ROUNDS = 32
SEAM_LENGTH_SLACK = 0.02
#: Segments a ring's sweep start moves on each round, modulo the ring (:func:`keep_seam_length`): a
#: sweep round a closed ring ends where it started and leaves there what the body does not let it
#: shorten. A prime larger than any seam, so the start moves on every round on rings of any size.
SEAM_RING_STRIDE = 1009


@_jit
def slide_seam(points: F64, a: F64, b: F64, radii: F64, clearance: float, spread: int,
               wrap: bool, rest: F64) -> None:  # pragma: no cover
    """Slide a seam's pins (a cape's collar) out of the body parts covering them, in place, keeping
    the seam's length: reference ``AvatarKeys.slide_seam(..., backend="numpy")``.

    Pushing each covered pin along its own normal spreads the pins under a body part round its
    surface, and the pinned springs between them stretch (the cape's collar under a head thrown
    back: 62 % on `dance-short`, every frame over 10 % a collar spring next to the skull). Per key:

    1. each pin's nearest capsule (least signed distance, the first on a tie) and its depth
       ``clearance - d``; the pins with a positive depth are covered;
    2. the covered pins of each capsule move together along one direction ``u`` (the depth-weighted
       sum of their normals, normalised), :data:`SEAM_SHARED_PASSES` times by
       ``max(clearance - d, 0) / max(n . u, SEAM_MIN_COS)``: the covered stretch is carried, not
       spread round the body part; then two radial projections (:func:`push_out`);
    3. the move ``delta`` of every pin is spread along the seam with a linear fall-off over
       ``spread`` pins, ``w(k) = max(0, 1 - k / (spread + 1))`` at ``k`` pins away (round the seam
       when ``wrap``): pin ``i`` moves by ``w(|i - j|) delta_j`` for the ``j`` of largest
       ``w(|i - j|) |delta_j|`` (the first on a tie), so the step between held and carried pins is
       shared by their neighbours;
    4. two radial projections again leave every pin at least ``clearance`` outside;
    5. when ``rest`` is given, :func:`keep_seam_length` shortens what the moves still stretched (the
       boundary between two body parts' groups, a stretch carried round a thigh in a crouch:
       `dance-short`'s waistband slid with a pin-to-pin spring at 10.3 %).

    Parameters
    ----------
    points : (K + 1, P, 3) float64
        Pin targets in seam order, modified in place.
    a, b : (K + 1, C, 3) float64
    radii : (C, 2) float64
    clearance : float
    spread : int
        Fall-off length in pins (0: no spreading).
    wrap : bool
        The seam is closed (a waistband).
    rest : (S,) float64
        Rest length of each seam segment ``i -> i + 1`` (``S = P`` when ``wrap``, the last closing
        the ring, else ``P - 1``); empty: no length pass.
    """
    n_keys, n_pins, n_caps = points.shape[0], points.shape[1], a.shape[1]
    geo = np.empty((n_caps, _GEO_COLS))
    near = np.empty(n_pins, dtype=np.int64)
    depth = np.empty(n_pins)
    start = points.copy()
    for k in range(n_keys):
        capsule_geometry(a[k], b[k], radii, 0.0, geo)
        for p in range(n_pins):
            best, cb = np.inf, 0
            for c in range(n_caps):
                d = round_cone_geo(start[k, p, 0], start[k, p, 1], start[k, p, 2], geo, c)[0]
                if d < best:
                    best, cb = d, c
            near[p], depth[p] = cb, clearance - best
        for c in range(n_caps):
            ux, uy, uz, any_in = 0.0, 0.0, 0.0, False
            for p in range(n_pins):
                if near[p] == c and depth[p] > 0.0:
                    _d, nx, ny, nz, _t = round_cone_geo(start[k, p, 0], start[k, p, 1], start[k, p, 2], geo, c)
                    ux += depth[p] * nx
                    uy += depth[p] * ny
                    uz += depth[p] * nz
                    any_in = True
            norm = math.sqrt(ux * ux + uy * uy + uz * uz)
            if not any_in or not norm > 0.0:
                continue
            ux, uy, uz = ux / norm, uy / norm, uz / norm
            for _ in range(SEAM_SHARED_PASSES):
                for p in range(n_pins):
                    if near[p] == c and depth[p] > 0.0:
                        d, nx, ny, nz, _t = round_cone_geo(points[k, p, 0], points[k, p, 1], points[k, p, 2], geo, c)
                        need = clearance - d
                        if need > 0.0:
                            step = need / max(nx * ux + ny * uy + nz * uz, SEAM_MIN_COS)
                            points[k, p, 0] += step * ux
                            points[k, p, 1] += step * uy
                            points[k, p, 2] += step * uz
    push_out(points, a, b, radii, clearance, 2)
    if spread > 0:
        _spread_moves(points, start, spread, wrap)
        push_out(points, a, b, radii, clearance, 2)
    if rest.shape[0] > 0:
        keep_seam_length(points, a, b, radii, clearance, rest, SEAM_LENGTH_ROUNDS, SEAM_LENGTH_SLACK)


@_jit
def _spread_moves(points: F64, start: F64, spread: int, wrap: bool) -> None:  # pragma: no cover
    """Step 3 of :func:`slide_seam`: each pin moved by the largest fall-off-weighted move near it."""
    n_keys, n_pins = points.shape[0], points.shape[1]
    delta = points - start
    mag = np.empty(n_pins)
    for k in range(n_keys):
        for p in range(n_pins):
            mag[p] = math.sqrt(delta[k, p, 0] ** 2 + delta[k, p, 1] ** 2 + delta[k, p, 2] ** 2)
        for i in range(n_pins):
            top, jb, wb = -1.0, 0, 0.0
            for j in range(n_pins):
                gap = abs(i - j)
                if wrap:
                    gap = min(gap, n_pins - gap)
                w = max(0.0, 1.0 - gap / (spread + 1.0))
                if w * mag[j] > top:
                    top, jb, wb = w * mag[j], j, w
            for e in range(3):
                points[k, i, e] = start[k, i, e] + wb * delta[k, jb, e]


@_jit
def keep_seam_length(points: F64, a: F64, b: F64, radii: F64, clearance: float, rest: F64, rounds: int,
                     slack: float) -> None:  # pragma: no cover
    """Shorten a slid seam's stretched segments, in place, keeping the pins outside the body:
    reference ``AvatarKeys.keep_seam_length(..., backend="numpy")``.

    Per key, up to ``rounds`` rounds, each a Gauss-Seidel sweep over the segments (forwards, then
    backwards on the next round; round a closed ring each round starts :data:`SEAM_RING_STRIDE`
    segments further on) that moves both ends of a segment longer than
    ``(1 + slack) rest`` half-way each towards the other, then one projection
    (:func:`push_out`'s rule) of every pin it moved. It stops after a round that moved nothing, so
    the body has the last word; a seam the body cannot leave room for keeps its stretch, spread
    over the segments instead of in one. A seam whose pins were not slid is at its rest lengths and
    is not touched.

    Parameters
    ----------
    points : (K + 1, P, 3) float64
        Pins in seam order, modified in place.
    a, b : (K + 1, C, 3) float64
    radii : (C, 2) float64
    clearance : float
    rest : (S,) float64
        Segment rest lengths, segment ``i`` from pin ``i`` to ``i + 1``; ``S = P`` closes the ring
        (the last segment joins the last pin to the first), else ``S = P - 1``.
    rounds : int
    slack : float
    """
    n_keys, n_pins, n_caps = points.shape[0], points.shape[1], a.shape[1]
    n_seg = rest.shape[0]
    geo = np.empty((n_caps, _GEO_COLS))
    moved = np.zeros(n_pins, dtype=np.bool_)
    for k in range(n_keys):
        geo_ready = False
        for r in range(rounds):
            any_move = False
            start = (r * SEAM_RING_STRIDE) % n_seg if n_seg == n_pins else 0
            for q in range(n_seg):
                i = start + q if r % 2 == 0 else start + n_seg - 1 - q
                if i >= n_seg:
                    i -= n_seg
                j = i + 1
                if j == n_pins:
                    j = 0
                dx = points[k, j, 0] - points[k, i, 0]
                dy = points[k, j, 1] - points[k, i, 1]
                dz = points[k, j, 2] - points[k, i, 2]
                length = math.sqrt(dx * dx + dy * dy + dz * dz)
                limit = (1.0 + slack) * rest[i]
                if length > limit:
                    h = 0.5 * (length - limit) / length
                    points[k, i, 0] += h * dx
                    points[k, i, 1] += h * dy
                    points[k, i, 2] += h * dz
                    points[k, j, 0] -= h * dx
                    points[k, j, 1] -= h * dy
                    points[k, j, 2] -= h * dz
                    moved[i] = True
                    moved[j] = True
                    any_move = True
            if not any_move:
                break
            if not geo_ready:
                capsule_geometry(a[k], b[k], radii, 0.0, geo)
                geo_ready = True
            for p in range(n_pins):
                if moved[p]:
                    _push_point(points, k, p, geo, n_caps, clearance)
                    moved[p] = False


#: Smallest axis fraction a push of the upper arm is levered at (:func:`clear_limbs`): the shoulder
#: end cannot move, so a push near it turns the elbow by push / fraction; this caps that gain at 4.
UPPER_ARM_MIN_LEVER = 0.25


@_inline
def _deepest(a: F64, b: F64, radii: F64, cap: int, trunk: NDArray[np.int64], geo: F64, s: F64,
             clearance: float) -> tuple[float, float, float, float, float]:  # pragma: no cover
    """Deepest axis sample of capsule ``cap`` against the trunk rows of ``geo``: (push, n, s) with
    push = ``r(s) + clearance - min_t d_t(s)`` and n the nearest trunk surface's outward normal."""
    best, bx, by, bz, bs = -1e300, 0.0, 0.0, 1.0, 0.0
    for j in range(s.shape[0]):
        sj = s[j]
        px = a[cap, 0] + sj * (b[cap, 0] - a[cap, 0])
        py = a[cap, 1] + sj * (b[cap, 1] - a[cap, 1])
        pz = a[cap, 2] + sj * (b[cap, 2] - a[cap, 2])
        dmin, nx, ny, nz = 1e300, 0.0, 0.0, 1.0
        for t in range(trunk.shape[0]):
            d, mx, my, mz, _ = round_cone_geo(px, py, pz, geo, trunk[t])
            if d < dmin:
                dmin, nx, ny, nz = d, mx, my, mz
        push = (1.0 - sj) * radii[cap, 0] + sj * radii[cap, 1] + clearance - dmin
        if push > best:
            best, bx, by, bz, bs = push, nx, ny, nz, sj
    return best, bx, by, bz, bs


@_inline
def _place(pivot: F64, end: F64, target: F64, length: float) -> None:  # pragma: no cover
    """``end`` (3,) set in place to ``pivot + length * unit(target - pivot)`` (kept if degenerate)."""
    dx, dy, dz = target[0] - pivot[0], target[1] - pivot[1], target[2] - pivot[2]
    n = math.sqrt(dx * dx + dy * dy + dz * dz)
    if n > 1e-12:
        end[0], end[1], end[2] = pivot[0] + dx * length / n, pivot[1] + dy * length / n, pivot[2] + dz * length / n


@_inline
def _norm3(v: F64) -> float:  # pragma: no cover
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


@_inline
def _sunk(a: F64, b: F64, radii: F64, chain: NDArray[np.int64], trunk: NDArray[np.int64], geo: F64, s: F64,
          clearance: float) -> bool:  # pragma: no cover
    """Whether the upper arm, the forearm or the hand of ``chain`` is nearer the trunk than ``clearance``."""
    for i in range(3):
        if _deepest(a, b, radii, chain[i], trunk, geo, s, clearance)[0] > 1e-6:
            return True
    return False


@_inline
def _rebuild(a: F64, b: F64, chain: NDArray[np.int64], raw: F64, offset: F64, lam: float, lengths: F64,
             tgt: F64) -> None:  # pragma: no cover
    """Arm ``chain`` of one key set, in place, to its recorded joints ``raw`` (3, 3: elbow, wrist,
    hand tip) moved by ``lam * offset`` (3, 3), each joint turned about its (moved) parent with
    the bone ``lengths`` (3,) kept."""
    up, fore, hand = chain[0], chain[1], chain[2]
    tgt[:] = raw[0] + lam * offset[0]
    _place(a[up], b[up], tgt, lengths[0])
    a[fore] = b[up]
    tgt[:] = raw[1] + lam * offset[1]
    _place(a[fore], b[fore], tgt, lengths[1])
    a[hand] = b[fore]
    tgt[:] = raw[2] + lam * offset[2]
    _place(a[hand], b[hand], tgt, lengths[2])


@_jit
def _arm_out(a: F64, b: F64, radii: F64, chain: NDArray[np.int64], trunk: NDArray[np.int64], geo: F64, s: F64,
             clearance: float, max_push: float, iterations: int, n: F64, tgt: F64) -> None:  # pragma: no cover
    """Rounds of pushes of the upper arm, the forearm, then the hand, of arm ``chain`` of one key out
    of the trunk along the nearest surface's normal, in place (``n``, ``tgt``: (3,) scratch)."""
    for _ in range(iterations):
        moved = False
        for i in (0, 1, 2):  # upper arm, forearm, then hand
            cap = chain[i]
            push, n[0], n[1], n[2], sj = _deepest(a, b, radii, cap, trunk, geo, s, clearance)
            if push <= 1e-6 or push > max_push:
                continue
            far = b[cap].copy()
            if i == 0:  # the shoulder stays: the elbow turns about it (a lever, the push at sj)
                lever = push / max(sj, UPPER_ARM_MIN_LEVER)
                if lever > max_push:
                    continue
                tgt[:] = far + lever * n
                _place(a[cap], b[cap], tgt, _norm3(far - a[cap]))
            else:
                parent = chain[i - 1]
                den = (1.0 - sj) ** 2 + sj * sj
                ca, cb = push * (1.0 - sj) / den, push * sj / den
                near = a[cap].copy()
                l_near, l_far = _norm3(b[parent] - a[parent]), _norm3(far - near)
                tgt[:] = near + ca * n  # the near end turns about the parent's pivot
                _place(a[parent], b[parent], tgt, l_near)
                a[cap] = b[parent]
                tgt[:] = far + (a[cap] - near) + cb * n  # the far end goes with it, then turns
                _place(a[cap], b[cap], tgt, l_far)
            moved = True
            for j in range(i + 1, 3):  # the rest of the arm rides the moved end (elbow or wrist)
                b[chain[j]] += b[cap] - far
                a[chain[j]] = b[chain[j - 1]]
        if not moved:
            break


@_jit
def clear_limbs(a: F64, b: F64, radii: F64, arms: NDArray[np.int64], trunk: NDArray[np.int64], s: F64,
                clearance: float, max_push: float, iterations: int, memory: F64,
                first_given: bool) -> None:  # pragma: no cover
    """Sunk upper arms, forearms and hands turned out of the trunk, in place (the rule, and its numpy
    reference: :func:`cloth_client.avatar.limb_clearance.clear_limbs_track` with ``backend="numpy"``).

    Parameters
    ----------
    a, b : (K, C, 3) float64
        Keys in time order.
    radii : (C, 2) float64
    arms : (2, 3) int64
        Upper arm, forearm and hand capsule of each side (chained: ``b[upper] = a[forearm]``...).
    trunk : (T,) int64
    s : (S,) float64
    clearance, max_push : float
    iterations : int
    memory : (2, 3, 3) float64
        Per side, how far the elbow, wrist and hand tip were moved from the recorded ones at the
        previous key (zeros: not moved); updated in place key after key.
    first_given : bool
        ``memory`` is the correction of key 0 itself (the previous call's last key, same pose):
        applied as it is.
    """
    geo = np.empty((a.shape[1], _GEO_COLS))
    tgt = np.empty(3)
    n = np.empty(3)
    raw = np.empty((3, 3))
    raw_a = np.empty((3, 3))
    lengths = np.empty(3)
    for k in range(a.shape[0]):
        capsule_geometry(a[k], b[k], radii, 0.0, geo)
        for side in range(arms.shape[0]):
            chain = arms[side]
            if _deepest(a[k], b[k], radii, chain[1], trunk, geo, s, clearance)[0] > max_push:
                memory[side] = 0.0
                continue  # a forearm that cannot be cleared: the side stays as recorded (ghosted)
            warm = False
            for j in range(3):
                raw_a[j], raw[j] = a[k, chain[j]], b[k, chain[j]]
                lengths[j] = _norm3(b[k, chain[j]] - a[k, chain[j]])
                warm = warm or _norm3(memory[side, j]) > 1e-12
            if k == 0 and first_given:
                if warm:
                    _rebuild(a[k], b[k], chain, raw, memory[side], 1.0, lengths, tgt)
                continue
            _arm_out(a[k], b[k], radii, chain, trunk, geo, s, clearance, max_push, iterations, n, tgt)
            jump, fresh_size = 0.0, 0.0
            for j in range(3):
                jump = max(jump, _norm3(b[k, chain[j]] - raw[j] - memory[side, j]))
                fresh_size = max(fresh_size, _norm3(b[k, chain[j]] - raw[j]))
            if warm and jump > CARRY_JUMP:
                # the fresh correction jumped (the nearest surface flipped): carry the previous key's
                # correction instead, pushed out if it sinks, else relaxed towards the recording as far
                # as it stays clear (at most RELAX_RATE of it: never back into the trunk)
                for j in range(3):
                    a[k, chain[j]] = raw_a[j]
                    b[k, chain[j]] = raw[j]
                _rebuild(a[k], b[k], chain, raw, memory[side], 1.0, lengths, tgt)
                if _sunk(a[k], b[k], radii, chain, trunk, geo, s, clearance):
                    _arm_out(a[k], b[k], radii, chain, trunk, geo, s, clearance, max_push, iterations, n, tgt)
                else:
                    lo, hi = 1.0 - RELAX_RATE, 1.0
                    _rebuild(a[k], b[k], chain, raw, memory[side], lo, lengths, tgt)
                    if _sunk(a[k], b[k], radii, chain, trunk, geo, s, clearance):
                        for _ in range(RELAX_STEPS):
                            mid = 0.5 * (lo + hi)
                            _rebuild(a[k], b[k], chain, raw, memory[side], mid, lengths, tgt)
                            if _sunk(a[k], b[k], radii, chain, trunk, geo, s, clearance):
                                lo = mid
                            else:
                                hi = mid
                        _rebuild(a[k], b[k], chain, raw, memory[side], hi, lengths, tgt)
                        if hi == 1.0 and fresh_size == 0.0:
                            # the recorded limb is clear and the way back to it is through the trunk:
                            # a carried correction must not hold the arm away forever; back to the recording
                            for j in range(3):
                                a[k, chain[j]] = raw_a[j]
                                b[k, chain[j]] = raw[j]
            for j in range(3):
                memory[side, j] = b[k, chain[j]] - raw[j]
