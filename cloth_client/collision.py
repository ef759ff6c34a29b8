"""Cloth-vs-body collision: points against tapered capsules ("round cones") and the floor.

A body capsule is the convex hull of two spheres, radius ``ra`` at ``a`` and ``rb`` at ``b``. Its
signed distance and outward normal are exact (not the common "interpolated radius" approximation).
In the (axial ``y``, radial ``rho``) half-plane of a point, the cone's side is the line tangent to
both circles, with unit normal ``(sin phi, cos phi)``, ``sin phi = (ra - rb) / |b - a|``; the point
belongs to sphere ``a``, the side, or sphere ``b`` according to its coordinate ``tau`` along that
tangent line.

Continuity
----------
Body motion within one cloth step is given as a :class:`CapsuleTrack`: capsule endpoints at
``K + 1`` evenly spaced instants (from articulated interpolation of the pose, see
:mod:`cloth_client.avatar`). The solver linearly interpolates between these keys at every substep
and picks enough substeps that no capsule surface moves more than a fraction of its radius per
substep (:func:`max_relative_travel`), so a fast arm swing cannot jump over a cloth particle.

Response
--------
A particle closer than ``margin`` (the cloth's half thickness) to a capsule is projected onto the
offset surface and the normal component of its velocity relative to the capsule surface is removed
if approaching. After all passes, a particle that touched a single surface has its tangential
velocity relative to it reduced by Coulomb friction ``mu * |dv_n|``; cloth squeezed between two
body parts gets no friction (each would drag it its own way and tear it) but takes the velocity of
the stoutest part it touches (a hand pressing a skirt against the hip slides over it, the cloth
stays with the hip). In a crease narrower than twice the margin (two nearest surfaces facing each
other) the clearance shrinks to half the gap (:func:`pinch_margin_np`), so the cloth fits in the
gap instead of being ploughed along by the part that closes it. Capsules
are treated one after another per particle (Gauss-Seidel); a particle that was moved gets another
pass (up to :data:`COLLISION_PASSES`, the floor included in each), which works cloth caught where
two capsules overlap, or a capsule meets the floor, out to the outside of their union. The normals
of up to two surfaces each particle touches are recorded for the contact-aware strain limiting
that follows (cloth pinched in a crease may then only slide along it). The solver ends every
substep with one more collision pass (after the final strain limiting), so the state it hands
on is outside the body wherever the body leaves room.

The numba kernels in :mod:`cloth_client._kernels` implement the same operations; the functions
here are their plain numpy references (tests check that both agree).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "CapsuleTrack",
    "broad_phase_np",
    "capsules_near",
    "collide_np",
    "max_relative_travel",
    "penetration_np",
    "pinch_margin_np",
    "round_cone_np",
]

F64 = NDArray[np.float64]
_TINY = 1e-12


@dataclass(frozen=True)
class CapsuleTrack:
    """Body capsules sampled at ``K + 1`` evenly spaced instants of one cloth step.

    Attributes
    ----------
    a, b : (K + 1, C, 3) float64
        Endpoint positions, metres; key 0 is the start of the step, key K its end.
    radii : (C, 2) float64
        Radius at ``a`` and at ``b`` of every capsule, metres.
    """

    a: F64
    b: F64
    radii: F64

    def __post_init__(self) -> None:
        a = np.ascontiguousarray(self.a, dtype=np.float64)
        b = np.ascontiguousarray(self.b, dtype=np.float64)
        r = np.ascontiguousarray(self.radii, dtype=np.float64)
        if a.ndim != 3 or a.shape[0] < 2 or a.shape[2] != 3 or b.shape != a.shape:
            raise ValueError(f"a and b must both be (K+1 >= 2, C, 3), got {a.shape} and {b.shape}")
        if r.shape != (a.shape[1], 2) or not np.all(r > 0):
            raise ValueError(f"radii must be ({a.shape[1]}, 2) and positive, got {r.shape}")
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "radii", r)

    @classmethod
    def static(cls, a: F64, b: F64, radii: F64) -> CapsuleTrack:
        """A track whose capsules do not move: ``a, b (C, 3)`` repeated at both ends of the step."""
        a2 = np.broadcast_to(np.asarray(a, dtype=np.float64), (2, *np.shape(a)))
        b2 = np.broadcast_to(np.asarray(b, dtype=np.float64), (2, *np.shape(b)))
        return cls(a2, b2, radii)

    @property
    def n_keys(self) -> int:
        """Number of key instants ``K + 1``."""
        return int(self.a.shape[0])

    def at(self, s: float) -> tuple[F64, F64]:
        """Endpoints ``(a, b)``, each ``(C, 3)``, at fraction ``s`` in [0, 1] of the step."""
        return interpolate_keys(self.a, s), interpolate_keys(self.b, s)


def interpolate_keys(keys: F64, s: float) -> F64:
    """Linear interpolation of ``keys (K + 1, ...)`` sampled evenly over [0, 1], at ``s``.

    Parameters
    ----------
    keys : (K + 1, ...) float64
    s : float
        Clipped to [0, 1].

    Returns
    -------
    (...) float64
    """
    k = keys.shape[0] - 1
    u = min(max(float(s), 0.0), 1.0) * k
    i = min(int(u), k - 1)
    w = u - i
    out: F64 = (1.0 - w) * keys[i] + w * keys[i + 1]
    return out


def max_relative_travel(track: CapsuleTrack, near: NDArray[np.bool_] | None = None) -> float:
    """Largest distance any capsule endpoint moves between two keys, in units of that capsule's
    smaller radius, times the number of key intervals (so it is comparable with one whole step).

    Parameters
    ----------
    track : CapsuleTrack
    near : (C,) bool, optional
        Only these capsules count (see :func:`capsules_near`); default all.

    Returns
    -------
    float
        ``n`` substeps keep each capsule's per-substep travel below ``value / n`` radii.
    """
    da = np.linalg.norm(np.diff(track.a, axis=0), axis=-1)  # (K, C)
    db = np.linalg.norm(np.diff(track.b, axis=0), axis=-1)
    rmin = track.radii.min(axis=1)
    rel = np.maximum(da, db) / rmin
    if near is not None:
        rel = rel[:, near]
    return float(rel.max() * (track.n_keys - 1)) if rel.size else 0.0


def capsules_near(track: CapsuleTrack, x: F64, reach: float) -> NDArray[np.bool_]:
    """Capsules that may touch the cloth during the step: their swept bounding box (over all keys,
    grown by the larger radius) meets the bounding box of ``x (N, 3)`` grown by ``reach`` (metres;
    how far the cloth can move within the step plus the clearance).

    Returns
    -------
    (C,) bool
    """
    r = track.radii.max(axis=1)[:, None]
    lo = np.minimum(track.a.min(axis=0), track.b.min(axis=0)) - r  # (C, 3)
    hi = np.maximum(track.a.max(axis=0), track.b.max(axis=0)) + r
    out: NDArray[np.bool_] = np.all((lo <= x.max(axis=0) + reach) & (hi >= x.min(axis=0) - reach), axis=1)
    return out


def round_cone_np(p: F64, a: F64, b: F64, ra: F64, rb: F64) -> tuple[F64, F64, F64]:
    """Signed distance, outward normal and axial parameter of points against round cones.

    Parameters
    ----------
    p : (N, 3) float64
        Points.
    a, b : (C, 3) float64
        Capsule endpoints.
    ra, rb : (C,) float64
        Radii at ``a`` and ``b``.

    Returns
    -------
    dist : (N, C) float64
        Signed distance to the surface (negative inside), metres.
    normal : (N, C, 3) float64
        Unit outward normal of the closest surface point.
    t : (N, C) float64
        Position of the closest point along the axis, 0 at ``a`` and 1 at ``b``.
    """
    ba = b - a
    length = np.linalg.norm(ba, axis=-1)
    # A sphere contains the other (or the segment is degenerate): keep the bigger sphere only.
    engulf = np.abs(ra - rb) >= length - 1e-9
    big_b = engulf & (rb > ra)
    ca = np.where(big_b[:, None], b, a)
    r1 = np.where(engulf, np.maximum(ra, rb), ra)
    safe_len = np.where(engulf, 1.0, length)
    u = ba / safe_len[:, None]
    sin_phi = np.where(engulf, 0.0, (ra - rb) / safe_len)
    cos_phi = np.sqrt(np.maximum(1.0 - sin_phi**2, 0.0))

    pa = p[:, None, :] - ca[None]  # (N, C, 3)
    y = np.einsum("ncj,cj->nc", pa, u)
    w = pa - y[..., None] * u[None]
    rho = np.linalg.norm(w, axis=-1)
    # radial unit vector; on the axis pick any perpendicular of u
    perp = np.cross(u, np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]))
    perp /= np.maximum(np.linalg.norm(perp, axis=-1, keepdims=True), _TINY)
    w_hat = np.where((rho > 1e-12)[..., None], w / np.maximum(rho, _TINY)[..., None], perp[None])

    tau = y * cos_phi - rho * sin_phi
    in_a = engulf[None] | (tau < 0.0)
    in_b = ~in_a & (tau > safe_len * cos_phi)
    pb = p[:, None, :] - b[None]
    da = np.linalg.norm(pa, axis=-1)
    db = np.linalg.norm(pb, axis=-1)
    side_n = sin_phi[None, :, None] * u[None] + cos_phi[None, :, None] * w_hat
    na = np.where((da > 1e-12)[..., None], pa / np.maximum(da, _TINY)[..., None], side_n)
    nb = np.where((db > 1e-12)[..., None], pb / np.maximum(db, _TINY)[..., None], side_n)
    dist = np.where(in_a, da - r1, np.where(in_b, db - rb, y * sin_phi + rho * cos_phi - ra))
    normal = np.where(in_a[..., None], na, np.where(in_b[..., None], nb, side_n))
    t = np.where(engulf[None], np.where(big_b, 1.0, 0.0)[None], np.clip(y / safe_len, 0.0, 1.0))
    t = np.where(in_a & ~engulf[None], 0.0, np.where(in_b, 1.0, t))
    return dist, normal, t


#: Most projection passes over the capsules per particle (only particles moved in a pass get another).
COLLISION_PASSES = 4
#: Two contact normals with a cosine below this face each other: the cloth is in a crease.
PINCH_COS = -0.3
#: A particle closer than the clearance by less than this (metres) is on the surface, not in contact.
HIT_TOLERANCE = 1e-9


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


def collide_np(
    x: F64, v: F64, free: NDArray[np.bool_], a0: F64, b0: F64, a1: F64, b1: F64, radii: F64,
    margin: float, friction: float, dt: float, floor: float | None, contact: F64, xprev: F64 | None = None,
) -> None:
    """Resolve contacts of particles with capsules (end-of-substep endpoints) and the floor, in place.

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
    pinched = _resolve_np(x, v, free, a0, b0, a1, b1, radii, np.full(len(x), margin), margin, friction, dt, floor,
                          contact, xp)
    m = np.full(len(x), margin)
    m[pinched] = pinch_margin_np(x0[pinched], a1, b1, radii, margin)
    again = pinched & (m < margin)  # a crease: start again with the clearance the gap leaves
    if again.any():
        x[again], v[again] = x0[again], v0[again]
        sub = np.zeros((int(again.sum()), 6))
        xs, vs = x[again], v[again]
        _resolve_np(xs, vs, np.ones(len(xs), bool), a0, b0, a1, b1, radii, m[again], margin, friction, dt, floor, sub,
                    xp[again])
        x[again], v[again], contact[again] = xs, vs, sub


def _resolve_np(x: F64, v: F64, free: NDArray[np.bool_], a0: F64, b0: F64, a1: F64, b1: F64, radii: F64, m: F64,
                margin: float, friction: float, dt: float, floor: float | None, contact: F64,
                xprev: F64) -> NDArray[np.bool_]:
    """Projection passes with clearance ``m (N,)`` from the capsules and ``margin`` from the floor,
    then friction or the held velocity; returns which particles were pinched (reference of ``K._resolve``)."""
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
            d, nc, t = round_cone_np(x, a1[c:c + 1], b1[c:c + 1], radii[c:c + 1, 0], radii[c:c + 1, 1])
            hit = todo & (d[:, 0] < m - HIT_TOLERANCE)
            if not hit.any():
                continue
            # back to the side it came from if it went through the axis (reference of ``K._side``)
            carried = xprev + (1.0 - t) * (a1[c] - a0[c]) + t * (b1[c] - b0[c])
            dq, nq, tq = round_cone_np(carried, a1[c:c + 1], b1[c:c + 1], radii[c:c + 1, 0], radii[c:c + 1, 1])
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


def broad_phase_np(x: F64, free: NDArray[np.bool_], a: F64, b: F64, radii: F64, reach: float) -> NDArray[np.int64]:
    """Candidate capsules of every particle as bit masks (reference of ``K.broad_phase``).

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
        Bit ``c`` set where the particle is within ``reach`` of the capsule of radius
        ``max(ra, rb)`` round the segment ``a[c] b[c]`` (a superset of the round cone).
    """
    u = b - a
    t = np.clip(np.einsum("ncj,cj->nc", x[:, None] - a[None], u) / np.maximum(np.einsum("cj,cj->c", u, u), 1e-300),
                0.0, 1.0)
    q = x[:, None] - a[None] - t[..., None] * u[None]
    near = (np.einsum("ncj,ncj->nc", q, q) < (radii.max(axis=1) + reach) ** 2) & free[:, None]
    out: NDArray[np.int64] = (near.astype(np.int64) << np.arange(len(a), dtype=np.int64)).sum(axis=1)
    return out


def pinch_margin_np(x: F64, a: F64, b: F64, radii: F64, margin: float) -> F64:
    """Clearance ``(N,)`` each particle can keep from the body (reference of ``K.pinch_margin``).

    ``margin``, except in a crease: when the two nearest capsules within ``margin`` have normals
    facing each other (cosine below ``PINCH_COS``), half the gap between them (0 where they overlap).
    """
    if len(a) < 2:
        return np.full(len(x), margin)
    d, nrm, _ = round_cone_np(x, a, b, radii[:, 0], radii[:, 1])
    order = np.argsort(d, axis=1, kind="stable")[:, :2]
    rows = np.arange(len(x))
    d1, d2 = d[rows, order[:, 0]], d[rows, order[:, 1]]
    cos = np.einsum("ij,ij->i", nrm[rows, order[:, 0]], nrm[rows, order[:, 1]])
    crease = (d2 < margin) & (cos < PINCH_COS)
    out: F64 = np.where(crease, np.clip(0.5 * (d1 + d2), 0.0, margin), margin)
    return out


def penetration_np(x: F64, a: F64, b: F64, radii: F64, free: NDArray[np.bool_]) -> F64:
    """Depth (>= 0, metres) by which each particle lies inside the body, 0 for pinned particles.

    Parameters
    ----------
    x : (N, 3) float64
    a, b : (C, 3) float64
    radii : (C, 2) float64
    free : (N,) bool

    Returns
    -------
    (N,) float64
        ``max(0, -min_c dist_c)``.
    """
    d, _, _ = round_cone_np(x, a, b, radii[:, 0], radii[:, 1])
    depth: F64 = np.maximum(-d.min(axis=1), 0.0)
    return np.where(free, depth, 0.0)
