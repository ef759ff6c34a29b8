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
:mod:`cloth_client.avatar.capsules`). The solver linearly interpolates between these keys at every substep
and picks enough substeps that no capsule surface moves more than a fraction of its radius per
substep (:func:`max_relative_travel`), so a fast arm swing cannot jump over a cloth particle.

Response
--------
:mod:`cloth_client.contact.response`.

The numba kernels in :mod:`cloth_client.contact.cone_kernels` implement the same geometry;
:func:`round_cone_reference` and :func:`penetration_reference` are their plain numpy references
(tests check that both agree).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "CapsuleTrack",
    "capsules_near",
    "interpolate_keys",
    "max_relative_travel",
    "penetration_reference",
    "round_cone_reference",
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


def round_cone_reference(p: F64, a: F64, b: F64, ra: F64, rb: F64) -> tuple[F64, F64, F64]:
    """Signed distance, outward normal and axial parameter of points against round cones (reference
    of :func:`cloth_client.contact.cone_kernels.round_cone`, vectorised over points and capsules).

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


def penetration_reference(x: F64, a: F64, b: F64, radii: F64, free: NDArray[np.bool_]) -> F64:
    """Depth (>= 0, metres) by which each particle lies inside the body, 0 for pinned particles
    (reference of :func:`cloth_client.contact.cone_kernels.penetration`).

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
    d, _, _ = round_cone_reference(x, a, b, radii[:, 0], radii[:, 1])
    depth: F64 = np.maximum(-d.min(axis=1), 0.0)
    return np.where(free, depth, 0.0)
