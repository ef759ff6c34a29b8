"""Numba kernels of the solver's forces and integration: springs, air drag, semi-implicit Euler,
and the strain of a set of springs.

Particle indices read from index arrays are used unsigned (``np.uint64``): a signed index costs a
wrap-around test on each access (a quarter of the springs' and the drag's time), an unsigned one
none, with the same results.

The plain numpy references are in :mod:`cloth_client.solver.reference` (``*_reference``); tests hold
both equal. :func:`~cloth_client.solver.substep_kernels.simulate_substeps` calls these in its loop.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from cloth_client._jit import inline_kernel as _inline
from cloth_client._jit import jit_kernel as _jit

__all__ = ["drag_forces", "integrate", "spring_forces", "spring_strain", "spring_vector"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@_inline
def spring_vector(x: F64, springs: I64, s: int) -> tuple[np.uint64, np.uint64, float, float, float]:  # pragma: no cover
    """Ends ``i, j`` of spring ``s`` (unsigned: no wrap-around test on each access) and the vector
    ``x[j] - x[i]``."""
    i = np.uint64(springs[s, 0])
    j = np.uint64(springs[s, 1])
    return i, j, x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2]


@_jit
def spring_forces(x: F64, v: F64, springs: I64, rest: F64, k: F64, kd: F64, f: F64) -> None:  # pragma: no cover
    """Add Hooke + axial damping forces of every spring to ``f (N, 3)`` (reference:
    :func:`~cloth_client.solver.reference.spring_forces_reference`)."""
    for s in range(springs.shape[0]):
        i, j, dx, dy, dz = spring_vector(x, springs, s)
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        inv = 1.0 / length if length > 1e-12 else 0.0  # branch-free: a zero-length spring exerts nothing
        ux, uy, uz = dx * inv, dy * inv, dz * inv
        dvn = (v[j, 0] - v[i, 0]) * ux + (v[j, 1] - v[i, 1]) * uy + (v[j, 2] - v[i, 2]) * uz
        fs = k[s] * (length - rest[s]) + kd[s] * dvn
        f[i, 0] += fs * ux
        f[i, 1] += fs * uy
        f[i, 2] += fs * uz
        f[j, 0] -= fs * ux
        f[j, 1] -= fs * uy
        f[j, 2] -= fs * uz


@_jit
def drag_forces(x: F64, v: F64, tris: I64, coeff: float, wind: F64, av: F64, f: F64) -> None:  # pragma: no cover
    """Add quadratic normal air drag ``-coeff * A (v_n |v_n|) n`` to ``f``; ``av`` is scratch (N, 3)
    (reference: :func:`~cloth_client.solver.reference.drag_forces_reference`)."""
    av[:] = 0.0
    for t in range(tris.shape[0]):
        i, j, k = np.uint64(tris[t, 0]), np.uint64(tris[t, 1]), np.uint64(tris[t, 2])
        e1x, e1y, e1z = x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2]
        e2x, e2y, e2z = x[k, 0] - x[i, 0], x[k, 1] - x[i, 1], x[k, 2] - x[i, 2]
        cx = (e1y * e2z - e1z * e2y) / 6.0
        cy = (e1z * e2x - e1x * e2z) / 6.0
        cz = (e1x * e2y - e1y * e2x) / 6.0
        for q in (i, j, k):
            av[q, 0] += cx
            av[q, 1] += cy
            av[q, 2] += cz
    for p in range(x.shape[0]):
        area = math.sqrt(av[p, 0] ** 2 + av[p, 1] ** 2 + av[p, 2] ** 2)
        if area < 1e-16:
            continue
        nx, ny, nz = av[p, 0] / area, av[p, 1] / area, av[p, 2] / area
        vn = (v[p, 0] - wind[0]) * nx + (v[p, 1] - wind[1]) * ny + (v[p, 2] - wind[2]) * nz
        mag = coeff * area * vn * abs(vn)
        f[p, 0] -= mag * nx
        f[p, 1] -= mag * ny
        f[p, 2] -= mag * nz


@_jit
def integrate(x: F64, v: F64, f: F64, inv_mass: F64, gravity: F64, damp: float, dt: float,
              xp: F64) -> None:  # pragma: no cover
    """Semi-implicit Euler: ``v += dt (f/m + g)``, ``v *= damp``, ``x += dt v``; saves ``x`` in ``xp``
    (reference: :func:`~cloth_client.solver.reference.integrate_reference`)."""
    for i in range(x.shape[0]):
        for d in range(3):
            xp[i, d] = x[i, d]
        if inv_mass[i] > 0.0:
            for d in range(3):
                v[i, d] = (v[i, d] + dt * (f[i, d] * inv_mass[i] + gravity[d])) * damp
                x[i, d] += dt * v[i, d]


@_jit
def spring_strain(x: F64, springs: I64, rest: F64, out: F64) -> None:  # pragma: no cover
    """``out[s]`` = engineering strain ``(l - L) / L`` of spring ``s`` (reference:
    :func:`cloth_client.solver.reference.spring_strain_reference`)."""
    for s in range(springs.shape[0]):
        _i, _j, d0, d1, d2 = spring_vector(x, springs, s)
        out[s] = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) / rest[s] - 1.0
