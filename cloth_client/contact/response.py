"""Cloth-vs-body contact response (numpy references of :mod:`cloth_client.contact.response_kernels`).

A particle closer than ``margin`` (the cloth's half thickness) to a capsule is projected onto the
offset surface and the normal component of its velocity relative to the capsule surface is removed
if approaching. After all passes, a particle that touched a single surface has its tangential
velocity relative to it reduced by Coulomb friction ``mu * |dv_n|``; cloth squeezed between two
body parts gets no friction (each would drag it its own way and tear it) but takes the velocity of
the stoutest part it touches (a hand pressing a skirt against the hip slides over it, the cloth
stays with the hip). In a crease narrower than twice the margin (two nearest surfaces facing each
other) the clearance shrinks to half the gap (:func:`pinch_margin_reference`), so the cloth fits in the
gap instead of being ploughed along by the part that closes it; where the two overlap (no gap:
a forearm pressed on the hip) it sits half-way through the overlap, at most :data:`PINCH_DEPTH`
inside each, instead of being squeezed out to one side of the limb. Capsules
are treated one after another per particle (Gauss-Seidel); a particle that was moved gets another
pass (up to :data:`COLLISION_PASSES`, the floor included in each), which works cloth caught where
two capsules overlap, or a capsule meets the floor, out to the outside of their union. The normals
of up to two surfaces each particle touches are recorded for the contact-aware strain limiting
that follows, the final rounds included (cloth pinched in a crease may then only slide along it,
and cloth resting on the body slides over it instead of being pulled into it and pushed back out
with the stretch left in). The solver ends every substep with one more collision pass (after the
final strain limiting), so the state it hands on is outside the body wherever the body leaves room.

A particle found inside a capsule past its axis from where it was at the start of the substep
(carried along with the capsule) is put back on that side instead of being projected to the
nearest surface, so a limb pressed into cloth that the strain limit holds back cannot pull it
through itself. :func:`broad_phase_reference` gathers each particle's candidate capsules once per substep.

The numba kernels (:mod:`cloth_client.contact.response_kernels`) implement the same operations;
the functions here are their plain numpy references, ``<kernel>_reference`` (tests check that both
agree). The constants are the kernels' own: one rule, two implementations.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cloth_client.contact.collision import round_cone_reference
from cloth_client.contact.response_kernels import (
    COLLISION_PASSES,
    CREASE_COS,
    HIT_TOLERANCE,
    PINCH_COS,
    PINCH_DEPTH,
    STRADDLE_DEPTH,
    STRADDLE_SAMPLES,
)

__all__ = [
    "COLLISION_PASSES",
    "CREASE_COS",
    "HIT_TOLERANCE",
    "PINCH_COS",
    "PINCH_DEPTH",
    "STRADDLE_DEPTH",
    "STRADDLE_SAMPLES",
    "broad_phase_reference",
    "collide_reference",
    "pinch_margin_reference",
    "release_straddles_reference",
]

F64 = NDArray[np.float64]
_TINY = 1e-12


def _push(x: F64, v: F64, hit: NDArray[np.bool_], push: F64, n: F64, vs: F64) -> F64:
    """Move ``x[hit]`` by ``push * n`` and cancel the approach to the surface moving at ``vs``;
    returns the normal velocity change ``(N,)`` (0 where not hit)."""
    x[hit] += push[hit, None] * n[hit]
    vn = np.einsum("ij,ij->i", v - vs, n)
    cancel = hit & (vn < 0.0)
    v[cancel] -= vn[cancel, None] * n[cancel]
    out: F64 = np.where(cancel, -vn, 0.0)
    return out


def _friction(v: F64, sel: NDArray[np.bool_], n: F64, vs: F64, dvn: F64, friction: float) -> None:
    """Coulomb friction on ``v[sel]``: tangential speed relative to the surface reduced by ``friction * dvn``."""
    r = v[sel] - vs[sel]
    vn = np.einsum("ij,ij->i", r, n[sel])
    t = r - vn[:, None] * n[sel]
    vt = np.linalg.norm(t, axis=1)
    scale = np.where(vt > 1e-12, np.maximum(0.0, 1.0 - friction * dvn[sel] / np.maximum(vt, _TINY)) - 1.0, 0.0)
    v[sel] += scale[:, None] * t


def _record(contact: F64, first: NDArray[np.int64], hit: NDArray[np.bool_], surface: int, n: F64) -> None:
    """Note contacts: the first surface's normal in ``contact[:, 0:3]``, another's in ``[:, 3:6]``."""
    single = hit & ((first < 0) | (first == surface))
    contact[single, 0:3] = n[single]
    contact[hit & ~single, 3:6] = n[hit & ~single]


def collide_reference(
    x: F64, v: F64, free: NDArray[np.bool_], a0: F64, b0: F64, a1: F64, b1: F64, radii: F64,
    margin: float, friction: float, dt: float, floor: float | None, contact: F64, xprev: F64 | None = None,
) -> None:
    """Resolve contacts of particles with capsules (end-of-substep endpoints) and the floor, in place
    (reference of :func:`cloth_client.contact.response_kernels.collide`).

    Parameters
    ----------
    x, v : (N, 3) float64
        Positions and velocities at the end of the substep (modified in place).
    free : (N,) bool
        Particles that may be moved (pinned ones are skipped).
    a0, b0 : (C, 3) float64
        Capsule endpoints at the start of the substep (for the surface velocity).
    a1, b1 : (C, 3) float64
        Capsule endpoints at the end of the substep (the geometry collided against).
    radii : (C, 2) float64
    margin : float
        Distance kept from the surfaces (cloth half thickness), metres.
    friction : float
        Coulomb coefficient (applied to particles touching a single surface).
    dt : float
        Substep length, seconds.
    floor : float or None
        Height of the floor plane (Y up), or None for no floor.
    contact : (N, 6) float64
        Output: unit normals of the first and of another surface each particle was pushed off
        (zero where none).
    xprev : (N, 3) float64, optional
        Positions at the start of the substep (default ``x``): a particle found inside a capsule
        past its axis from where it was (carried along with the capsule) is put back on that side.
    """
    x0, v0 = x.copy(), v.copy()
    xp = x0 if xprev is None else xprev
    pinched = _resolve_reference(x, v, free, a0, b0, a1, b1, radii, np.full(len(x), margin), margin, friction, dt,
                                 floor, contact, xp)
    m = np.full(len(x), margin)
    m[pinched] = pinch_margin_reference(x0[pinched], a1, b1, radii, margin)
    again = pinched & (m < margin)  # a crease: start again with the clearance the gap leaves
    if again.any():
        held = v[again]  # the stoutest touched part's velocity (set by the first resolve)
        x[again], v[again] = x0[again], v0[again]
        sub = np.zeros((int(again.sum()), 6))
        xs, vs = x[again], v[again]
        _resolve_reference(xs, vs, np.ones(len(xs), bool), a0, b0, a1, b1, radii, m[again], margin, friction, dt,
                           floor, sub, xp[again])
        x[again], v[again], contact[again] = xs, held, sub


def _resolve_reference(x: F64, v: F64, free: NDArray[np.bool_], a0: F64, b0: F64, a1: F64, b1: F64, radii: F64,
                       m: F64, margin: float, friction: float, dt: float, floor: float | None, contact: F64,
                xprev: F64) -> NDArray[np.bool_]:
    """Projection passes with clearance ``m (N,)`` from the capsules and ``margin`` from the floor,
    then friction or the held velocity; returns which particles were pinched (reference of
    ``response_kernels._resolve``)."""
    contact[:] = 0.0
    n = len(x)
    first = np.full(n, -1, dtype=np.int64)
    pinched = np.zeros(n, dtype=bool)
    dvn = np.zeros(n)
    nrm, vel, hold = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    big = np.full(n, -1.0)
    stout = radii.max(axis=1)
    va, vb = (a1 - a0) / dt, (b1 - b0) / dt

    def hit_surface(hit: NDArray[np.bool_], surface: int, push: F64, nn: F64, vs: F64) -> None:
        dv = _push(x, v, hit, push, nn, vs)
        _record(contact, first, hit, surface, nn)
        own = hit & ((first < 0) | (first == surface))
        first[own] = surface
        dvn[own] += dv[own]
        nrm[own], vel[own] = nn[own], vs[own]
        pinched[hit & ~own] = True

    up = np.broadcast_to(np.array([0.0, 1.0, 0.0]), x.shape)
    todo = free.copy()
    for _ in range(COLLISION_PASSES):
        moved = np.zeros_like(todo)
        for c in range(a1.shape[0]):
            d, nc, t = round_cone_reference(x, a1[c:c + 1], b1[c:c + 1], radii[c:c + 1, 0], radii[c:c + 1, 1])
            hit = todo & (d[:, 0] < m - HIT_TOLERANCE)
            if not hit.any():
                continue
            # back to the side it came from if it went through the axis (``response_kernels._side``)
            carried = xprev + (1.0 - t) * (a1[c] - a0[c]) + t * (b1[c] - b0[c])
            dq, nq, tq = round_cone_reference(carried, a1[c:c + 1], b1[c:c + 1], radii[c:c + 1, 0], radii[c:c + 1, 1])
            back = hit & (dq[:, 0] > 0.0) & (np.einsum("ij,ij->i", nq[:, 0], nc[:, 0]) < 0.0)
            x[back] = carried[back]
            d[back], nc[back], t[back] = dq[back], nq[back], tq[back]
            vs = (1.0 - t[:, :1]) * va[c] + t[:, :1] * vb[c]
            hit_surface(hit, c, m - d[:, 0], nc[:, 0], vs)
            upd = hit & (stout[c] > big)
            hold[upd], big[upd] = vs[upd], stout[c]
            moved |= hit
        if floor is not None:
            hit = todo & (x[:, 1] < floor + margin - HIT_TOLERANCE)
            hit_surface(hit, a1.shape[0], floor + margin - x[:, 1], up, np.zeros_like(x))
            moved |= hit
        todo = moved
        if not todo.any():
            break
    _friction(v, (first >= 0) & ~pinched, nrm, vel, dvn, friction)
    held = pinched & (big > 0.0)
    v[held] = hold[held]
    return pinched


def broad_phase_reference(x: F64, free: NDArray[np.bool_], a: F64, b: F64, radii: F64,
                          reach: float) -> NDArray[np.int64]:
    """Candidate capsules of every particle as bit masks (reference of
    :func:`cloth_client.contact.cone_kernels.broad_phase`).

    Parameters
    ----------
    x : (N, 3) float64
    free : (N,) bool
        Other particles get an empty mask.
    a, b : (C, 3) float64
        Capsule endpoints (C <= 62).
    radii : (C, 2) float64
    reach : float
        Clearance plus slack, metres.

    Returns
    -------
    (N,) int64
        Bit ``c`` set where the particle's signed distance to the round cone ``c`` is below ``reach``.
    """
    d, _, _ = round_cone_reference(x, a, b, radii[:, 0], radii[:, 1])
    near = (d < reach) & free[:, None]
    out: NDArray[np.int64] = (near.astype(np.int64) << np.arange(len(a), dtype=np.int64)).sum(axis=1)
    return out


def pinch_margin_reference(x: F64, a: F64, b: F64, radii: F64, margin: float) -> F64:
    """Clearance ``(N,)`` each particle can keep from the body (reference of
    :func:`cloth_client.contact.response_kernels.pinch_margin`).

    ``margin``, except in a crease: when the two nearest capsules within ``margin`` have normals
    facing each other (cosine below ``PINCH_COS``), half the gap between them; where they overlap
    that is negative (half-way through the overlap), down to ``-PINCH_DEPTH``; in a wider V (cosine
    below ``CREASE_COS`` but not ``PINCH_COS``) half the gap too, but not below 0.
    """
    if len(a) < 2:
        return np.full(len(x), margin)
    d, nrm, _ = round_cone_reference(x, a, b, radii[:, 0], radii[:, 1])
    order = np.argsort(d, axis=1, kind="stable")[:, :2]
    rows = np.arange(len(x))
    d1, d2 = d[rows, order[:, 0]], d[rows, order[:, 1]]
    cos = np.einsum("ij,ij->i", nrm[rows, order[:, 0]], nrm[rows, order[:, 1]])
    crease = (d2 < margin) & (cos < CREASE_COS)
    floor = np.where(cos < PINCH_COS, -PINCH_DEPTH, 0.0)
    out: F64 = np.where(crease, np.minimum(np.maximum(0.5 * (d1 + d2), floor), margin), margin)
    return out


def release_straddles_reference(x: F64, inv_mass: F64, springs: NDArray[np.int64], hi: F64, trigger2: float,
                                a: F64, b: F64, radii: F64, margin: float, opposed: float) -> int:
    """Lift stretched springs that straddle a body part off it, in place (reference of
    :func:`cloth_client.contact.response_kernels.release_straddles`, which documents the rule).

    Parameters
    ----------
    x : (N, 3) float64
        Positions, moved in place.
    inv_mass : (N,) float64
    springs : (L, 2) int64
        Springs to test, visited in order.
    hi : (L,) float64
        Their upper length bounds; a spring is tested when ``(l / hi)**2 > trigger2``.
    trigger2 : float
    a, b : (C, 3) float64
        Capsule ends.
    radii : (C, 2) float64
    margin : float
        Clearance the chord is lifted to (the cloth's half thickness).

    Returns
    -------
    int
        Springs released.
    """
    ts = np.arange(1, STRADDLE_SAMPLES + 1) / (STRADDLE_SAMPLES + 1)
    released = 0
    if not len(a):
        return 0
    for s in range(len(springs)):
        i, j = int(springs[s, 0]), int(springs[s, 1])
        d = x[j] - x[i]
        if not float(d @ d) > trigger2 * hi[s] * hi[s]:
            continue
        wi, wj = float(inv_mass[i]), float(inv_mass[j])
        if wi + wj <= 0.0:
            continue
        dist, normal, _ = round_cone_reference(x[i] + ts[:, None] * d, a, b, radii[:, 0], radii[:, 1])  # (S, C)
        flat = dist.T.ravel()  # capsule-major, as the kernel scans: the first deepest sample wins
        m = int(np.argmin(flat))
        if not flat[m] < -STRADDLE_DEPTH:
            continue
        c, k = divmod(m, STRADDLE_SAMPLES)
        ends, en, _ = round_cone_reference(x[[i, j]], a[c:c + 1], b[c:c + 1], radii[c:c + 1, 0], radii[c:c + 1, 1])
        if (ends < 0.0).any():
            continue  # an end inside: collision moves that particle out
        if not float(en[0, 0] @ en[1, 0]) < opposed:
            continue  # both ends on the same side of the limb
        t = ts[k]
        push = (margin - flat[m]) / (wi * (1.0 - t) ** 2 + wj * t * t)
        x[i] += wi * (1.0 - t) * push * normal[k, c]
        x[j] += wj * t * push * normal[k, c]
        released += 1
    return released
