"""Numba kernel of the whole substep loop: :func:`simulate_substeps` runs all substeps of one cloth
step without returning to Python.

It chains the force kernels (:mod:`~cloth_client.solver.force_kernels`), the strain-limiting kernels
(:mod:`~cloth_client.solver.strain_kernels`) and the contact kernels
(:mod:`cloth_client.contact.response_kernels`). Its plain numpy reference is
:func:`cloth_client.solver.reference.simulate_substeps_reference`; a test holds both equal.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from cloth_client._jit import inline_kernel as _inline
from cloth_client._jit import jit_kernel as _jit
from cloth_client.contact.response_kernels import BROAD_SLACK, broad_phase, collide, release_straddles
from cloth_client.solver.force_kernels import drag_forces, integrate, spring_forces
from cloth_client.solver.strain_kernels import line_limit, long_range_attach, ring_limit, strain_limit, worst_stretch2

__all__ = ["simulate_substeps"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@_inline
def _lerp_keys(keys: F64, s: float, out: F64) -> None:  # pragma: no cover
    k = keys.shape[0] - 1
    u = min(max(s, 0.0), 1.0) * k
    i0 = min(int(u), k - 1)
    w = u - i0
    out[:] = (1.0 - w) * keys[i0] + w * keys[i0 + 1]


@_jit
def simulate_substeps(
    x: F64, v: F64, inv_mass: F64, springs: I64, rest: F64, k: F64, kd: F64, tris: I64,
    drag_coeff: float, wind: F64, gravity: F64, mass_damping: float,
    lim_springs: I64, lim_lo: F64, lim_hi: F64, lim_iterations: int,
    lim_sweeps: int, final_sweeps: int, final_rounds: int, extra_rounds: int, extra_trigger2: float, straddles: bool,
    opposed: float,
    anchor: I64, reach: F64, lines_a: I64, rest_a: F64, lines_b: I64, rest_b: F64, lines_c: I64, rest_c: F64,
    max_stretch: float, max_compression: float,
    pin_idx: I64, pin_keys: F64, cap_a: F64, cap_b: F64, radii: F64,
    margin: float, friction: float, floor: float, use_floor: bool, max_speed: float,
    n_sub: int, dt_total: float,
) -> None:  # pragma: no cover
    """Advance ``x, v`` by ``dt_total`` in ``n_sub`` substeps (same sequence as
    :func:`cloth_client.solver.reference.simulate_substeps_reference`).

    ``pin_keys (K+1, P, 3)`` and ``cap_a, cap_b (K+1, C, 3)`` are sampled evenly over the step. After
    the ``final_rounds``, up to ``extra_rounds`` more run while the largest ``(l / lim_hi)**2`` of the
    structural springs exceeds ``extra_trigger2`` (the caller passes ``extra_rounds = 0`` when
    ``final_rounds`` is 0), each first lifting straddled springs off the limb between their
    particles when ``straddles`` (:func:`release_straddles`).
    """
    n = x.shape[0]
    dt = dt_total / n_sub
    damp = 1.0 / (1.0 + mass_damping * dt)
    f = np.empty((n, 3))
    xp = np.empty((n, 3))
    av = np.empty((n, 3))
    targets = np.empty(pin_keys.shape[1:])
    a0 = np.empty(cap_a.shape[1:])
    b0 = np.empty(cap_a.shape[1:])
    a1 = np.empty(cap_a.shape[1:])
    b1 = np.empty(cap_a.shape[1:])
    contact = np.zeros((n, 6))
    touch = np.zeros(n, dtype=np.bool_)  # contact's rows that are nonzero (strain_kernels.touching)
    cand = np.empty(n, dtype=np.int64)
    xb = np.empty((n, 3))
    for step in range(n_sub):
        s0 = step / n_sub
        s1 = (step + 1) / n_sub
        f[:] = 0.0
        spring_forces(x, v, springs, rest, k, kd, f)
        if drag_coeff > 0.0:
            drag_forces(x, v, tris, drag_coeff, wind, av, f)
        integrate(x, v, f, inv_mass, gravity, damp, dt, xp)
        _lerp_keys(pin_keys, s1, targets)
        for p in range(pin_idx.shape[0]):
            i = pin_idx[p]
            for d in range(3):
                x[i, d] = targets[p, d]
                v[i, d] = (targets[p, d] - xp[i, d]) / dt
        _lerp_keys(cap_a, s0, a0)
        _lerp_keys(cap_b, s0, b0)
        _lerp_keys(cap_a, s1, a1)
        _lerp_keys(cap_b, s1, b1)
        contact[:] = 0.0
        touch[:] = False
        broad_phase(x, inv_mass, a1, b1, radii, margin + BROAD_SLACK, cand, xb)
        for _ in range(lim_iterations):  # strain limiting and contacts, interleaved
            long_range_attach(x, inv_mass, anchor, reach)
            for _sweep in range(lim_sweeps):
                line_limit(x, inv_mass, lines_a, rest_a, max_stretch, max_compression, contact, touch)
                line_limit(x, inv_mass, lines_b, rest_b, max_stretch, max_compression, contact, touch)
                ring_limit(x, inv_mass, lines_c, rest_c, max_stretch, max_compression, contact, touch)
            strain_limit(x, inv_mass, lim_springs, lim_lo, lim_hi, 1, contact, touch)
            for i in range(n):
                if inv_mass[i] > 0.0:
                    for d in range(3):
                        v[i, d] = (x[i, d] - xp[i, d]) / dt
            collide(x, v, inv_mass, a0, b0, a1, b1, radii, margin, friction, dt, floor, use_floor, contact,
                    cand, xb, BROAD_SLACK, xp, touch)
        # final rounds: contact-aware strain limiting (contacts slide along the surfaces of the last
        # collision instead of into them), then collision (with final_rounds == 0: no collision after it)
        # then up to extra_rounds more while a structural spring is stretched beyond the trigger
        rounds = max(final_rounds, 1)
        for _r in range(rounds + extra_rounds):
            if _r >= rounds and worst_stretch2(x, lim_springs, lim_hi, inv_mass) <= extra_trigger2:
                break
            for i in range(n):
                for d in range(3):
                    f[i, d] = x[i, d]
            if straddles and _r >= rounds:  # a limb between two particles of a stretched spring: lift it off
                release_straddles(x, inv_mass, lim_springs, lim_hi, extra_trigger2, a1, b1, radii, margin, opposed)
            for _sweep in range(final_sweeps):
                line_limit(x, inv_mass, lines_a, rest_a, max_stretch, max_compression, contact, touch)
                line_limit(x, inv_mass, lines_b, rest_b, max_stretch, max_compression, contact, touch)
                ring_limit(x, inv_mass, lines_c, rest_c, max_stretch, max_compression, contact, touch)
            strain_limit(x, inv_mass, lim_springs, lim_lo, lim_hi, 1 if final_sweeps > 0 else 0, contact, touch)
            for i in range(n):
                for d in range(3):
                    v[i, d] += (x[i, d] - f[i, d]) / dt
            if final_rounds > 0:  # friction was applied in the interleaved passes already
                collide(x, v, inv_mass, a0, b0, a1, b1, radii, margin, 0.0, dt, floor, use_floor, contact,
                        cand, xb, BROAD_SLACK, xp, touch)
        for i in range(n):
            sp = math.sqrt(v[i, 0] ** 2 + v[i, 1] ** 2 + v[i, 2] ** 2)
            if sp > max_speed and inv_mass[i] > 0.0:
                for d in range(3):
                    v[i, d] *= max_speed / sp
