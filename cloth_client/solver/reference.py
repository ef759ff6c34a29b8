"""Plain numpy references of the solver kernels: forces and integration
(:mod:`cloth_client.solver.force_kernels`), strain limiting (:mod:`cloth_client.solver.strain_kernels`)
and the whole substep loop (:mod:`cloth_client.solver.substep_kernels`, which
:func:`cloth_client.solver.cloth.step_reference` runs through :func:`simulate_substeps_reference`).
Each is named after its kernel, ``<kernel>_reference``. Tests compare them with the kernels; they
are far too slow for real time.

Strain limiting
---------------
Soft springs alone (stiff ones would need tiny explicit substeps) let a hanging cape sag by tens of
percent, so after every integration the positions are projected back (Provot 1995), in three
complementary passes:

* **long-range attachments** (Kim, Chentanez & Mueller 2012): no particle may be farther from its
  nearest pin than ``(1 + max_stretch)`` times its rest distance along the cloth - this stops the
  low-frequency sag of a long column that local passes converge on slowly;
* **line solves**: along every grid column and row, the springs outside
  ``[(1 - max_compression) L, (1 + max_stretch) L]`` form a tridiagonal system ``J W J^T lambda =
  -C`` solved exactly (Thomas algorithm), so a pull travels the whole line in one pass;
* **Gauss-Seidel sweeps** over all structural springs, ordered from the pins outwards and split
  into batches that share no particle (a vectorised batch update then equals the sequential
  sweep), alternating direction; they also cover the wrap seam of a tube.

Every pass can be *contact-aware*: ``contact (N, 6)`` holds the unit normals of up to two surfaces a
particle rests on, and moves into them are dropped, so the final projection slides cloth along the
body instead of pushing it in. The numba kernels (:mod:`cloth_client.solver.strain_kernels`) implement
the same passes; the functions here are their numpy references.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import NDArray

from cloth_client.contact.collision import CapsuleTrack, interpolate_keys
from cloth_client.contact.response import collide_reference, release_straddles_reference
from cloth_client.solver.model import ClothModel
from cloth_client.solver.strain_kernels import SLIDE_FLOOR

__all__ = ["drag_forces_reference", "integrate_reference", "line_limit_reference", "long_range_attach_reference",
           "ring_limit_reference", "simulate_substeps_reference", "slide_reference", "spring_forces_reference",
           "spring_strain_reference", "strain_limit_reference", "tangent_dot_reference", "tangent_reference",
           "touching_reference", "worst_stretch2_reference"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


def long_range_attach_reference(x: F64, inv_mass: F64, anchor: I64, reach: F64) -> None:
    """Long-range attachments, in place (reference of :func:`~cloth_client.solver.strain_kernels.long_range_attach`)."""
    d = x - x[anchor]
    dist = np.linalg.norm(d, axis=1)
    over = (inv_mass > 0) & (dist > reach)
    x[over] = x[anchor[over]] + d[over] * (reach[over] / dist[over])[:, None]


def touching_reference(contact: F64) -> NDArray[np.bool_]:
    """``(N,) bool``: whether each particle rests on any surface, a nonzero normal in ``contact (N, 6)``
    (reference of :func:`~cloth_client.solver.strain_kernels.touching`)."""
    out: NDArray[np.bool_] = (contact != 0.0).any(axis=1)
    return out


def slide_reference(x: F64, idx: I64, delta: F64, contact: F64) -> None:
    """``x[idx] += delta`` less any component into the particles' (up to two) contact surfaces
    (reference of ``strain_kernels._slide``, and of the callers adding its move to ``x``)."""
    n1, n2 = contact[idx, 0:3], contact[idx, 3:6]
    d = delta.copy()
    for _ in range(3):
        active = np.zeros(len(idx), dtype=bool)
        for n in (n1, n2):
            into = np.einsum("ij,ij->i", d, n)
            hit = into < -1e-15
            d[hit] -= into[hit, None] * n[hit]
            active |= hit
        if not active.any():
            break
    x[idx] += d


def tangent_dot_reference(c: F64, a: F64, b: F64) -> F64:
    """``a . P b`` (last axis), ``P`` the orthogonal projector onto the tangent space of the (up to
    two) contact normals ``c (..., 6)`` (reference of ``strain_kernels._tangent_dot``)."""
    out: F64 = np.einsum("...j,...j->...", a, tangent_reference(c, b))
    return out


def tangent_reference(c: F64, m: F64) -> F64:
    """``P m`` (last axis) for the projector of :func:`tangent_dot_reference` (reference of
    ``strain_kernels._tangent``)."""
    n1, n2 = c[..., 0:3], c[..., 3:6]
    has1 = np.einsum("...j,...j->...", n1, n1) > 0.5
    m = np.where(has1[..., None], m - np.einsum("...j,...j->...", m, n1)[..., None] * n1, m)
    k = np.einsum("...j,...j->...", n2, n1)
    n2 = np.where(has1[..., None], n2 - k[..., None] * n1, n2)
    l2 = np.einsum("...j,...j->...", n2, n2)
    ok = l2 > 1e-12
    n2 = n2 / np.sqrt(np.where(ok, l2, 1.0))[..., None]
    out: F64 = np.where(ok[..., None], m - np.einsum("...j,...j->...", m, n2)[..., None] * n2, m)
    return out


def strain_limit_reference(x: F64, inv_mass: F64, springs: I64, lo: F64, hi: F64, batches: I64, iterations: int,
                           contact: F64) -> None:
    """Batch-vectorised symmetric Gauss-Seidel strain limiting, in place (reference of
    :func:`~cloth_client.solver.strain_kernels.strain_limit`).

    ``batches`` are offsets into ``springs``; springs inside one batch share no particle, so updating
    a whole batch at once gives exactly the sequential result. Odd iterations run backwards.
    """
    spans = list(itertools.pairwise(batches))
    for it in range(iterations):
        for b0, b1 in spans if it % 2 == 0 else spans[::-1]:
            s = springs[b0:b1]
            i, j = s[:, 0], s[:, 1]
            d = x[j] - x[i]
            length = np.linalg.norm(d, axis=1)
            target = np.clip(length, lo[b0:b1], hi[b0:b1])
            wi = inv_mass[i]
            wj = inv_mass[j]
            act = (wi + wj > 0) & (length >= 1e-12) & (target != length)
            c = np.where(act, (length - target) / np.where(act, length * (wi + wj), 1.0), 0.0)[:, None] * d
            slide_reference(x, i, wi[:, None] * c, contact)
            slide_reference(x, j, -wj[:, None] * c, contact)


def line_limit_reference(x: F64, inv_mass: F64, lines: I64, rest: F64, max_stretch: float, max_compression: float,
                         contact: F64) -> None:
    """Strain limiting solved along whole grid lines, in place (reference of
    :func:`~cloth_client.solver.strain_kernels.line_limit`): the
    tridiagonal systems ``J W P J^T lambda = -C`` (``P``: each particle's moves kept in the tangent
    space of the surfaces it touches) of all lines are eliminated together (a loop over the position
    along the line, vectorised over lines)."""
    if lines.shape[0] == 0:
        return
    d = x[lines[:, 1:]] - x[lines[:, :-1]]  # (L, m-1, 3)
    length = np.linalg.norm(d, axis=-1)
    hi, lo = rest * (1.0 + max_stretch), rest * (1.0 - max_compression)
    w = inv_mass[lines]
    act = ((length > hi) | (length < lo)) & (length > 1e-12) & (w[:, :-1] + w[:, 1:] > 0.0)
    n = np.where(act[..., None], d / np.where(act, length, 1.0)[..., None], 0.0)
    c = contact[lines]  # (L, m, 6): J W P J^T, each end moving in the tangent space of what it touches
    diag = w[:, :-1] * tangent_dot_reference(c[:, :-1], n, n) + w[:, 1:] * tangent_dot_reference(c[:, 1:], n, n)
    b = np.where(act, np.maximum(diag, SLIDE_FLOOR * (w[:, :-1] + w[:, 1:])), 1.0)
    rhs = np.where(act, -(length - np.where(length > hi, hi, lo)), 0.0)
    both = act[:, :-1] & act[:, 1:]
    off = np.where(both, -w[:, 1:-1] * tangent_dot_reference(c[:, 1:-1], n[:, :-1], n[:, 1:]), 0.0)  # (L, m-2)
    cp, dp = np.zeros_like(b), np.zeros_like(b)
    for k in range(b.shape[1]):
        denom = b[:, k] - (off[:, k - 1] * cp[:, k - 1] if k > 0 else 0.0)
        dk = rhs[:, k] - (off[:, k - 1] * dp[:, k - 1] if k > 0 else 0.0)
        cp[:, k] = (off[:, k] if k < off.shape[1] else 0.0) / denom
        dp[:, k] = dk / denom
    lam = np.zeros_like(b)
    lam[:, -1] = dp[:, -1]
    for k in range(b.shape[1] - 2, -1, -1):
        lam[:, k] = dp[:, k] - cp[:, k] * lam[:, k + 1]
    lam = np.where(act, lam, 0.0)
    move = np.zeros((*lines.shape, 3))
    move[:, 1:] += lam[..., None] * n
    move[:, :-1] -= lam[..., None] * n
    move = tangent_reference(c, move)  # the move the system was solved for
    slide_reference(x, lines.ravel(), (w[..., None] * move).reshape(-1, 3), contact)


def ring_limit_reference(x: F64, inv_mass: F64, rings: I64, rest: F64, max_stretch: float, max_compression: float,
                         contact: F64) -> None:
    """Strain limiting round closed rings, in place (reference of
    :func:`~cloth_client.solver.strain_kernels.ring_limit`): each ring ``rings[r] (m,)`` (rest lengths
    ``rest[r, k]`` from particle ``k`` to ``k + 1`` mod ``m``) is solved by :func:`line_limit_reference`
    as the open chain that starts after its slackest spring."""
    if rings.shape[0] == 0:
        return
    m = rings.shape[1]
    d = x[np.roll(rings, -1, axis=1)] - x[rings]
    ratio = np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]) / rest
    order = (np.argmin(ratio, axis=1)[:, None] + 1 + np.arange(m)) % m
    line_limit_reference(x, inv_mass, np.take_along_axis(rings, order, axis=1),
                         np.take_along_axis(rest, order[:, :-1], axis=1), max_stretch, max_compression, contact)


def spring_forces_reference(x: F64, v: F64, springs: I64, rest: F64, k: F64, kd: F64) -> F64:
    """Hooke + axial damping forces ``(N, 3)`` of ``springs (S, 2)`` (reference of
    :func:`~cloth_client.solver.force_kernels.spring_forces`)."""
    d = x[springs[:, 1]] - x[springs[:, 0]]
    length = np.linalg.norm(d, axis=1)
    ok = length > 1e-12
    u = np.where(ok[:, None], d / np.where(ok, length, 1.0)[:, None], 0.0)
    dvn = np.einsum("ij,ij->i", v[springs[:, 1]] - v[springs[:, 0]], u)
    fs = np.where(ok, k * (length - rest) + kd * dvn, 0.0)[:, None] * u
    f = np.zeros_like(x)
    for c in range(3):
        f[:, c] = np.bincount(springs[:, 0], fs[:, c], len(x)) - np.bincount(springs[:, 1], fs[:, c], len(x))
    return f


def drag_forces_reference(x: F64, v: F64, tris: I64, coeff: float, wind: F64) -> F64:
    """Quadratic normal air drag ``(N, 3)`` (reference of :func:`~cloth_client.solver.force_kernels.drag_forces`)."""
    c = np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]]) / 6.0
    av = np.stack([np.bincount(tris.ravel(), np.repeat(c[:, d], 3), len(x)) for d in range(3)], axis=1)
    area = np.linalg.norm(av, axis=1)
    n = av / np.maximum(area, 1e-300)[:, None]
    vn = np.einsum("ij,ij->i", v - wind, n)
    out: F64 = np.where((area >= 1e-16)[:, None], -(coeff * area * vn * np.abs(vn))[:, None] * n, 0.0)
    return out


def _line_pass(x: F64, model: ClothModel, inv_mass: F64, contact: F64, sweeps: int) -> None:
    p = model.params
    for _ in range(sweeps):
        for lines, rest in ((model.lines_v, model.rest_v), (model.lines_h, model.rest_h)):
            line_limit_reference(x, inv_mass, lines, rest, p.max_stretch, p.max_compression, contact)
        ring_limit_reference(x, inv_mass, model.lines_s, model.rest_s, p.max_stretch, p.max_compression, contact)


def worst_stretch2_reference(x: F64, springs: I64, hi: F64, inv_mass: F64) -> float:
    """Largest ``(l / hi)**2`` over the ``springs (L, 2)`` with a free end (``inv_mass (N,)``), ``hi (L,)``
    their upper length bounds (reference of :func:`~cloth_client.solver.strain_kernels.worst_stretch2`)."""
    free = inv_mass[springs[:, 0]] + inv_mass[springs[:, 1]] > 0.0
    d = x[springs[free, 1]] - x[springs[free, 0]]
    return float((np.einsum("ij,ij->i", d, d) / (hi[free] * hi[free])).max(initial=0.0))


def integrate_reference(x: F64, v: F64, f: F64, inv_mass: F64, gravity: F64, mass_damping: float,
                        dt: float) -> F64:
    """Semi-implicit Euler of the free particles, in place: ``v = (v + dt (f/m + g)) / (1 + c dt)``,
    ``x += dt v``; returns the positions before the move (reference of
    :func:`~cloth_client.solver.force_kernels.integrate`, which multiplies by its ``damp = 1 / (1 + c dt)``)."""
    free = inv_mass > 0
    xp = x.copy()
    v[free] = (v[free] + dt * (f[free] * inv_mass[free, None] + gravity)) / (1.0 + mass_damping * dt)
    x[free] += dt * v[free]
    return xp


def spring_strain_reference(x: F64, springs: I64, rest: F64) -> F64:
    """Engineering strain ``(l - L) / L`` of every spring ``(S,)`` (reference of
    :func:`~cloth_client.solver.force_kernels.spring_strain`)."""
    out: F64 = np.linalg.norm(x[springs[:, 1]] - x[springs[:, 0]], axis=1) / rest - 1.0
    return out


def simulate_substeps_reference(x: F64, v: F64, model: ClothModel, inv_mass: F64, pin_idx: I64, track: CapsuleTrack,
                                pins: F64, n: int, dt_total: float, mass_damping: float, anchor: I64 | None = None,
                                reach: F64 | None = None) -> None:
    """Advance ``x, v`` in place by ``dt_total`` in ``n`` substeps of ``model`` (reference of
    :func:`~cloth_client.solver.substep_kernels.simulate_substeps`, same sequence; run by
    :func:`cloth_client.solver.cloth.step_reference`)."""
    p, g = model.params, model.garment
    anchor = g.anchor if anchor is None else anchor
    reach = model.reach if reach is None else reach
    dt = dt_total / n
    free = inv_mass > 0
    grav, wind = np.asarray(p.gravity), np.asarray(p.wind)
    trigger2 = ((1.0 + p.extra_above) / (1.0 + p.max_stretch)) ** 2
    extra = p.extra_rounds if p.final_rounds > 0 else 0
    for step_i in range(n):
        s0, s1 = step_i / n, (step_i + 1) / n
        f = spring_forces_reference(x, v, model.springs, model.rest, model.k, model.kd)
        if p.air_density * p.drag_coefficient > 0:
            f += drag_forces_reference(x, v, g.triangles, 0.5 * p.air_density * p.drag_coefficient, wind)
        xp = integrate_reference(x, v, f, inv_mass, grav, mass_damping, dt)
        target = interpolate_keys(pins, s1)
        x[pin_idx] = target
        v[pin_idx] = (target - xp[pin_idx]) / dt
        a0, b0 = track.at(s0)
        a1, b1 = track.at(s1)
        contact = np.zeros((len(x), 6))
        for _ in range(p.limit_iterations):
            long_range_attach_reference(x, inv_mass, anchor, reach)
            _line_pass(x, model, inv_mass, contact, p.limit_sweeps)
            strain_limit_reference(x, inv_mass, model.lim_springs, model.lim_lo, model.lim_hi, g.limit_batches, 1,
                                   contact)
            v[free] = (x[free] - xp[free]) / dt
            collide_reference(x, v, free, a0, b0, a1, b1, track.radii, p.margin, p.friction, dt, p.floor, contact, xp)
        rounds = max(p.final_rounds, 1)
        for r in range(rounds + extra):  # extra rounds while a structural spring is over extra_above
            if r >= rounds and worst_stretch2_reference(x, model.lim_springs, model.lim_hi, inv_mass) <= trigger2:
                break
            before = x.copy()  # contact-aware: cloth on the body slides over it, not into it
            if p.release_straddles and r >= rounds:  # a limb between two particles of a stretched spring
                release_straddles_reference(x, inv_mass, model.lim_springs, model.lim_hi, trigger2, a1, b1,
                                            track.radii, p.margin, p.straddle_opposed)
            _line_pass(x, model, inv_mass, contact, p.final_sweeps)
            strain_limit_reference(x, inv_mass, model.lim_springs, model.lim_lo, model.lim_hi, g.limit_batches,
                                   1 if p.final_sweeps > 0 else 0, contact)
            v += (x - before) / dt
            if p.final_rounds > 0:  # friction was applied in the interleaved passes already
                collide_reference(x, v, free, a0, b0, a1, b1, track.radii, p.margin, 0.0, dt, p.floor, contact, xp)
        speed = np.linalg.norm(v, axis=1)
        fast = free & (speed > p.max_speed)
        v[fast] *= (p.max_speed / speed[fast])[:, None]
