"""Numba kernels of the collision response: projection, friction, creases, straddles.

The plain numpy references are in :mod:`cloth_client.contact.response` (same rules, vectorised; its
docstring describes them); tests hold both equal. The solver's substep kernel runs
:func:`~cloth_client.contact.cone_kernels.broad_phase` (re-exported here), :func:`collide` and
:func:`release_straddles` in its loop.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import cast

import numpy as np
from numba.cpython.unsafe.numbers import trailing_zeros
from numpy.typing import NDArray

from cloth_client._jit import inline_kernel as _inline
from cloth_client._jit import jit_kernel as _jit
from cloth_client.contact.cone_kernels import (
    ALL_CAPSULES,
    BROAD_SLACK,
    GEO_COLS,
    broad_phase,
    capsule_geometry,
    round_cone_geo,
)

__all__ = ["ALL_CAPSULES", "BROAD_SLACK", "COLLISION_PASSES", "CREASE_COS", "HIT_TOLERANCE", "PINCH_COS",
           "PINCH_DEPTH", "STRADDLE_DEPTH", "STRADDLE_SAMPLES", "broad_phase", "collide", "pinch_margin",
           "release_straddles"]

F64 = NDArray[np.float64]

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
#: Columns of :func:`collide`'s table after :func:`~cloth_client.contact.cone_kernels.capsule_geometry`'s:
#: the capsule's centre (3), the motion of its ends over the substep (``a1 - a0``, ``b1 - b0``), ``max(ra, rb)``.
_CENTRE, _DA, _DB, _RMAX = 13, 16, 19, 22
_COLLIDE_COLS = 23
#: Index of the lowest set bit of a capsule mask (numba's count of trailing zeros; typed for mypy).
_lowest_bit = cast(Callable[[int], int], trailing_zeros)
#: A particle closer than the clearance by less than this (metres) counts as on the surface, not in
#: contact (a projected particle re-measured at the clearance must not trigger another pass).
HIT_TOLERANCE = 1e-9


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
    part held in the overlap is not pushed out of the V to the full margin (reference:
    :func:`~cloth_client.contact.response.pinch_margin_reference`)."""
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
    (where the mask was gathered; every capsule otherwise, from the capsule that pushed it past the
    slack on: the others cannot be within reach, so the result is that of testing every capsule).
    A particle found past the capsule's axis from ``q`` (where it was at the start of the substep)
    carried along with the capsule goes back to that side (:func:`_side`).

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
        left = mask  # candidates not visited yet
        c = -1
        while True:  # the capsules in ``mask`` in increasing order
            if mask == ALL_CAPSULES:
                c += 1
                if c >= n_caps:
                    break
            else:  # the set bits only, lowest first (most masks hold one or two of the capsules)
                if left == 0:
                    break
                c = _lowest_bit(left)
                left &= left - 1
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
                ox, oy, oz = x[i, 0] - bx, x[i, 1] - by, x[i, 2] - bz
                if ox * ox + oy * oy + oz * oz > slack * slack:
                    mask = ALL_CAPSULES  # pushed past the slack: the rest of the pass tests every capsule
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
            contact: F64, cand: NDArray[np.int64], xb: F64, slack: float, xprev: F64,
            touch: NDArray[np.bool_] | None = None) -> None:  # pragma: no cover
    """Project particles (those with ``active > 0``) out of the capsules ``(a1, b1)`` and the floor;
    same rules as :func:`cloth_client.contact.response.collide_reference`. ``xprev (N, 3)``: positions
    at the start of the substep (a particle that went through a capsule's axis since is put back on
    its side).

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
    second may touch only one of the two surfaces, whose friction would drag it along).

    ``touch (N,) bool``, optional output: whether each particle's ``contact`` row is nonzero (the
    flags :func:`~cloth_client.solver.strain_kernels.touching` computes, written here at the cost
    of the particles resolved only)."""
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
            if touch is not None:
                touch[i] = False
            continue
        px, py, pz = x[i, 0], x[i, 1], x[i, 2]
        ux, uy, uz = v[i, 0], v[i, 1], v[i, 2]
        mask, bx, by, bz = cand[i], xb[i, 0], xb[i, 1], xb[i, 2]
        qx, qy, qz = xprev[i, 0], xprev[i, 1], xprev[i, 2]
        if _resolve(x, v, i, margin, geo, margin, friction, dt, floor, use_floor, contact, mask, bx, by, bz, slack,
                    qx, qy, qz):
            m = pinch_margin(px, py, pz, geo, centre, margin)
            if m < margin:  # a crease: start again with the clearance the gap leaves
                hx, hy, hz = v[i, 0], v[i, 1], v[i, 2]  # the stoutest touched part's velocity
                x[i, 0], x[i, 1], x[i, 2] = px, py, pz
                v[i, 0], v[i, 1], v[i, 2] = ux, uy, uz
                _resolve(x, v, i, m, geo, margin, friction, dt, floor, use_floor, contact, mask, bx, by, bz, slack, qx,
                         qy, qz)
                v[i, 0], v[i, 1], v[i, 2] = hx, hy, hz  # it is still in the crease, held by the stoutest part
        if touch is not None:
            touch[i] = (contact[i, 0] != 0.0 or contact[i, 1] != 0.0 or contact[i, 2] != 0.0 or contact[i, 3] != 0.0
                        or contact[i, 4] != 0.0 or contact[i, 5] != 0.0)


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
    """Lift springs that straddle a body part off it (reference:
    :func:`cloth_client.contact.response.release_straddles_reference`).

    A spring ``s`` stretched beyond ``(l / hi[s])**2 > trigger2`` whose chord passes more than
    :data:`STRADDLE_DEPTH` inside a capsule, with both its ends outside that capsule and the
    capsule's outward normals at the two ends pointing apart (``n_i . n_j < opposed``), has a limb
    between its two particles: particle-vs-capsule collision pushes each end out to its own side
    and the strain limit cannot pull them together through the limb (the limb slipped between two
    particles: a shin between two rows of a skirt's hem, an arm up through a cape). Cloth draped
    round a limb also has its chord inside it, but with both ends on the same side; lifting that
    pumps a skirt off a forearm, hence the side test (``n_i . n_j < opposed``). The chord is
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
    geo = np.empty((a.shape[0], GEO_COLS))
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
