"""Numba kernels for the cloth solver's hot loops.

Each kernel has a plain numpy reference (:mod:`cloth_client.solver.reference`: spring, drag, integration,
long-range attachments, line solves, Gauss-Seidel strain limiting and the whole substep;
:mod:`cloth_client.contact.collision` and :mod:`cloth_client.contact.response`: round-cone distance, broad phase,
collision response, penetration - the contact kernels themselves live in
:mod:`cloth_client.contact._kernels`) and a test checks that both give the same numbers. The
kernels work in place on ``float64`` arrays and never allocate per particle; :func:`simulate_substeps`
runs all substeps of one cloth step without returning to Python. Small helpers called per particle
or per spring are compiled inline into their callers (a call with array arguments costs more than
the work they do); in hot loops they take numbers rather than arrays where they can (an array
handed to an inlined helper with branches or loops costs an atomic reference-count increment and
decrement per call, as much as the arithmetic of a particle).

Speed-ups are kept bit-identical (re-running the quality sweep is expensive), which takes more than
the same formulas: with the ``contract`` and ``reassoc`` fast-math flags of :data:`jit_kernel`,
a product and the sum using it become one FMA only when both are in one basic block, and the order
in which a sum of products is added may follow the order in which its operands were defined (loads
in a loop body, loop-carried values). Hence the shapes kept below: moves multiplied before the
branch that adds them, contact normals read inside :func:`_slide`'s loop. Compare any change bitwise
with the previous kernels, on particles with two contact normals too.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from cloth_client.contact._kernels import (
    ALL_CAPSULES,
    BROAD_SLACK,
    COLLISION_PASSES,
    CREASE_COS,
    PINCH_COS,
    PINCH_DEPTH,
    broad_phase,
    capsule_geometry,
    collide,
    inline_kernel,
    jit_kernel,
    penetration,
    pinch_margin,
    release_straddles,
    round_cone,
    round_cone_geo,
)

__all__ = [
    "ALL_CAPSULES",
    "BROAD_SLACK",
    "COLLISION_PASSES",
    "CREASE_COS",
    "PINCH_COS",
    "PINCH_DEPTH",
    "SLIDE_FLOOR",
    "broad_phase",
    "capsule_geometry",
    "collide",
    "drag_forces",
    "integrate",
    "interpolate_poses",
    "line_limit",
    "long_range_attach",
    "penetration",
    "pinch_margin",
    "ring_limit",
    "round_cone",
    "round_cone_geo",
    "simulate_substeps",
    "spring_forces",
    "spring_strain",
    "strain_limit",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
_jit = jit_kernel
_inline = inline_kernel

#: Least share of a constraint's unconstrained mobility the sliding line solve credits it with: a
#: spring's diagonal entry is ``sum w (u . P u)`` (``P``: onto the tangent space of the surfaces a
#: particle touches) instead of ``sum w``, floored at this share of ``sum w`` so a spring whose both
#: ends are held against the body (nearly along both normals) is not corrected by an unbounded slide
#: (a move of at most about ``1 / sqrt(SLIDE_FLOOR)`` = 2 times the unconstrained one; 0.1 gave the same
#: 26-take sample but one frame at 1,060 % on ``cmu/01_01``, 313 % with 0.25).
SLIDE_FLOOR = 0.25


@_inline
def _spring_vector(x: F64, springs: I64, s: int) -> tuple[int, int, float, float, float]:  # pragma: no cover
    """Ends ``i, j`` of spring ``s`` and the vector ``x[j] - x[i]``."""
    i = springs[s, 0]
    j = springs[s, 1]
    return i, j, x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2]


@_jit
def spring_forces(x: F64, v: F64, springs: I64, rest: F64, k: F64, kd: F64, f: F64) -> None:  # pragma: no cover
    """Add Hooke + axial damping forces of every spring to ``f (N, 3)``."""
    for s in range(springs.shape[0]):
        i, j, dx, dy, dz = _spring_vector(x, springs, s)
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
    """Add quadratic normal air drag ``-coeff * A (v_n |v_n|) n`` to ``f``; ``av`` is scratch (N, 3)."""
    av[:] = 0.0
    for t in range(tris.shape[0]):
        i, j, k = tris[t, 0], tris[t, 1], tris[t, 2]
        e1x, e1y, e1z = x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2]
        e2x, e2y, e2z = x[k, 0] - x[i, 0], x[k, 1] - x[i, 1], x[k, 2] - x[i, 2]
        cx = (e1y * e2z - e1z * e2y) / 6.0
        cy = (e1z * e2x - e1x * e2z) / 6.0
        cz = (e1x * e2y - e1y * e2x) / 6.0
        for q in (i, j, k):
            av[q, 0] += cx
            av[q, 1] += cy
            av[q, 2] += cz
    for i in range(x.shape[0]):
        area = math.sqrt(av[i, 0] ** 2 + av[i, 1] ** 2 + av[i, 2] ** 2)
        if area < 1e-16:
            continue
        nx, ny, nz = av[i, 0] / area, av[i, 1] / area, av[i, 2] / area
        vn = (v[i, 0] - wind[0]) * nx + (v[i, 1] - wind[1]) * ny + (v[i, 2] - wind[2]) * nz
        mag = coeff * area * vn * abs(vn)
        f[i, 0] -= mag * nx
        f[i, 1] -= mag * ny
        f[i, 2] -= mag * nz


@_jit
def integrate(x: F64, v: F64, f: F64, inv_mass: F64, gravity: F64, damp: float, dt: float,
              xp: F64) -> None:  # pragma: no cover
    """Semi-implicit Euler: ``v += dt (f/m + g)``, ``v *= damp``, ``x += dt v``; saves ``x`` in ``xp``."""
    for i in range(x.shape[0]):
        for d in range(3):
            xp[i, d] = x[i, d]
        if inv_mass[i] > 0.0:
            for d in range(3):
                v[i, d] = (v[i, d] + dt * (f[i, d] * inv_mass[i] + gravity[d])) * damp
                x[i, d] += dt * v[i, d]


@_jit
def long_range_attach(x: F64, inv_mass: F64, anchor: I64, reach: F64) -> None:  # pragma: no cover
    """Pull every free particle ``i`` back within ``reach[i]`` of particle ``anchor[i]`` (its pin)."""
    for i in range(x.shape[0]):
        if inv_mass[i] <= 0.0:
            continue
        a = anchor[i]
        dx, dy, dz = x[i, 0] - x[a, 0], x[i, 1] - x[a, 1], x[i, 2] - x[a, 2]
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        if dist > reach[i]:
            s = reach[i] / dist
            x[i, 0] = x[a, 0] + s * dx
            x[i, 1] = x[a, 1] + s * dy
            x[i, 2] = x[a, 2] + s * dz


#: The two contact normals of one particle, ``contact[i, 0:3]`` and ``contact[i, 3:6]``.
Normals = tuple[float, float, float, float, float, float]


@_inline
def _normals(contact: F64, i: np.uint64) -> Normals:  # pragma: no cover
    """Row ``i`` of ``contact (N, 6)``: the (up to two) unit normals particle ``i`` touches.

    :func:`_touching` and :func:`_tangent` take these six numbers instead of the array: an array
    handed to an inlined helper with branches costs a reference-count increment and decrement per
    call (more than the arithmetic of an untouched particle)."""
    return contact[i, 0], contact[i, 1], contact[i, 2], contact[i, 3], contact[i, 4], contact[i, 5]


@_inline
def _touching(n: Normals) -> bool:  # pragma: no cover
    """Whether a particle rests on any surface (a nonzero normal); when not, :func:`_tangent` and
    :func:`_slide` are the identity."""
    return n[0] != 0.0 or n[1] != 0.0 or n[2] != 0.0 or n[3] != 0.0 or n[4] != 0.0 or n[5] != 0.0


@_inline
def _slide(contact: F64, i: np.uint64, w: float, dx: float, dy: float,
           dz: float) -> tuple[float, float, float]:  # pragma: no cover
    """The move ``w * d`` of particle ``i`` less any component of it into the surfaces it touches.

    ``contact[i]`` holds up to two unit normals (``[0:3]`` and ``[3:6]``, zero when unused); with
    two (a crease between body parts) the move is projected alternately until it points into
    neither surface, so pinched cloth slides along the crease. Callers use it for touching
    particles only (see :func:`_touching`; the move of the others is ``w * d``), then add the move
    to ``x[i]``. (The loop reads the normals from the array, as the single helper it replaces did:
    taken as numbers, its dot products were summed in another order.)"""
    mx, my, mz = w * dx, w * dy, w * dz
    for _ in range(3):
        done = True
        for o in (0, 3):
            into = mx * contact[i, o] + my * contact[i, o + 1] + mz * contact[i, o + 2]
            if into < -1e-15:
                mx -= into * contact[i, o]
                my -= into * contact[i, o + 1]
                mz -= into * contact[i, o + 2]
                done = False
        if done:
            break
    return mx, my, mz


@_inline
def _tangent(n: Normals, mx: float, my: float, mz: float) -> tuple[float, float, float]:  # pragma: no cover
    """``P m``: ``m`` less its components along the (up to two) contact normals ``n`` (the
    projector of :func:`_tangent_dot`)."""
    n2x, n2y, n2z = n[3], n[4], n[5]
    n1x, n1y, n1z = n[0], n[1], n[2]
    if n1x * n1x + n1y * n1y + n1z * n1z > 0.5:
        q = mx * n1x + my * n1y + mz * n1z
        mx, my, mz = mx - q * n1x, my - q * n1y, mz - q * n1z
        k = n2x * n1x + n2y * n1y + n2z * n1z
        n2x, n2y, n2z = n2x - k * n1x, n2y - k * n1y, n2z - k * n1z
    l2 = n2x * n2x + n2y * n2y + n2z * n2z
    if l2 > 1e-12:
        inv = 1.0 / math.sqrt(l2)
        n2x, n2y, n2z = n2x * inv, n2y * inv, n2z * inv
        q = mx * n2x + my * n2y + mz * n2z
        mx, my, mz = mx - q * n2x, my - q * n2y, mz - q * n2z
    return mx, my, mz


@_inline
def _tangent_dot(n: Normals, ax: float, ay: float, az: float, bx: float, by: float,
                 bz: float) -> float:  # pragma: no cover
    """``a . P b`` with ``P`` the orthogonal projector onto the tangent space of the (up to two)
    surfaces of normals ``n`` (``a . b`` when there are none)."""
    px, py, pz = _tangent(n, bx, by, bz)
    return ax * px + ay * py + az * pz


@_jit
def strain_limit(x: F64, inv_mass: F64, springs: I64, lo: F64, hi: F64, iterations: int,
                 contact: F64) -> None:  # pragma: no cover
    """Provot-style strain limiting: project each spring's length into ``[lo, hi]`` (Gauss-Seidel).

    Odd iterations sweep backwards (symmetric Gauss-Seidel). ``contact (N, 6)`` holds the unit
    normals of up to two surfaces each particle rests on (zero if none): moves into them are dropped.
    """
    n_springs = springs.shape[0]
    for it in range(iterations):
        for k in range(n_springs):
            s = k if it % 2 == 0 else n_springs - 1 - k  # symmetric Gauss-Seidel: alternate sweeps
            i = np.uint64(springs[s, 0])  # unsigned: no wrap-around test on each access
            j = np.uint64(springs[s, 1])
            dx = x[j, 0] - x[i, 0]
            dy = x[j, 1] - x[i, 1]
            dz = x[j, 2] - x[i, 2]
            length = math.sqrt(dx * dx + dy * dy + dz * dz)
            if length > hi[s]:
                target = hi[s]
            elif length < lo[s]:
                target = lo[s]
            else:
                continue
            wi = inv_mass[i]
            wj = inv_mass[j]
            wsum = wi + wj
            if wsum <= 0.0 or length < 1e-12:
                continue
            c = (length - target) / (length * wsum)
            # the two ends written out: folded into a loop over (i, j), the compiled sums change
            # bits (fast-math contraction; measured in session 9), which would void the sweep
            w = wi * c
            if _touching(_normals(contact, i)):
                mx, my, mz = _slide(contact, i, w, dx, dy, dz)
            else:
                mx, my, mz = w * dx, w * dy, w * dz
            x[i, 0] += mx
            x[i, 1] += my
            x[i, 2] += mz
            w = -wj * c
            if _touching(_normals(contact, j)):
                mx, my, mz = _slide(contact, j, w, dx, dy, dz)
            else:
                mx, my, mz = w * dx, w * dy, w * dz
            x[j, 0] += mx
            x[j, 1] += my
            x[j, 2] += mz


@_jit
def line_limit(x: F64, inv_mass: F64, lines: I64, rest: F64, max_stretch: float, max_compression: float,
               contact: F64) -> None:  # pragma: no cover
    """Strain limiting solved exactly along whole grid lines (one linearised projection per line).

    ``lines (L, m)`` lists the particles of each row (or column) in order and ``rest (L, m - 1)`` the
    rest lengths between neighbours. On each line the springs outside
    ``[(1 - max_compression) L, (1 + max_stretch) L]`` form a tridiagonal system
    ``J W P J^T lambda = -C`` solved by the Thomas algorithm, so a pull is carried along the whole
    line at once. Lines must not share particles. ``P`` (per particle) projects onto the tangent
    space of the surfaces it touches (``contact``): cloth on the body slides along it, and a spring
    nearly along a contact normal is solved in one pass by the slide (its diagonal entry is
    ``w (1 - (u . n)^2)``, floored at :data:`SLIDE_FLOOR` of ``w``) instead of only its tangential
    share of it; the moves are ``W P J^T lambda`` (and never into a touched surface).

    Particle indices are used unsigned (``np.uint64``: no wrap-around test on each access); a line
    without an active spring is skipped, an inactive spring's row of the system is the identity
    (``cp = dp = 0``, as ``0 / 1`` gives), the off-diagonal entry shared by rows ``k`` and ``k + 1``
    is computed once, a particle that touches nothing skips the projections (the identity then) and
    one next to no active spring the move (zero): the same numbers as the plain form.
    """
    m = lines.shape[1]
    nx = np.empty((m, 3))
    cons = np.empty(m)
    act = np.zeros(m, dtype=np.bool_)
    cp = np.empty(m)
    dp = np.empty(m)
    lam = np.zeros(m)
    for ln in range(lines.shape[0]):
        row = lines[ln]
        any_active = False
        for k in range(m - 1):
            i, j = np.uint64(row[k]), np.uint64(row[k + 1])
            dx, dy, dz = x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2]
            length = math.sqrt(dx * dx + dy * dy + dz * dz)
            hi = rest[ln, k] * (1.0 + max_stretch)
            lo = rest[ln, k] * (1.0 - max_compression)
            w = inv_mass[i] + inv_mass[j]
            active = (length > hi or length < lo) and length > 1e-12 and w > 0.0
            act[k] = active
            if active:
                any_active = True
                nx[k, 0], nx[k, 1], nx[k, 2] = dx / length, dy / length, dz / length
                cons[k] = length - (hi if length > hi else lo)
        if not any_active:
            continue
        c = 0.0  # row k - 1's upper off-diagonal entry: row k's lower one (the same expression)
        for k in range(m - 1):  # forward elimination
            if not act[k]:
                cp[k] = 0.0
                dp[k] = 0.0
                continue
            i, j = np.uint64(row[k]), np.uint64(row[k + 1])
            wi, wj = inv_mass[i], inv_mass[j]
            ni, nj = _normals(contact, i), _normals(contact, j)
            # J W P J^T: each end only moves in the tangent space of the surfaces it touches
            b = (wi * _tangent_dot(ni, nx[k, 0], nx[k, 1], nx[k, 2], nx[k, 0], nx[k, 1], nx[k, 2])
                 + wj * _tangent_dot(nj, nx[k, 0], nx[k, 1], nx[k, 2], nx[k, 0], nx[k, 1], nx[k, 2]))
            b = max(b, SLIDE_FLOOR * (wi + wj))
            d = -cons[k]
            if k > 0 and act[k - 1]:
                a = c
                denom = b - a * cp[k - 1]
                d -= a * dp[k - 1]
            else:
                denom = b
            if k + 1 < m - 1 and act[k + 1]:
                dot = _tangent_dot(nj, nx[k, 0], nx[k, 1], nx[k, 2], nx[k + 1, 0], nx[k + 1, 1], nx[k + 1, 2])
                c = -inv_mass[j] * dot
            else:
                c = 0.0
            cp[k] = c / denom
            dp[k] = d / denom
        lam[m - 2] = dp[m - 2]
        for k in range(m - 3, -1, -1):  # back substitution
            lam[k] = dp[k] - cp[k] * lam[k + 1]
        for k in range(m):
            left = k > 0 and act[k - 1]
            right = k < m - 1 and act[k]
            if not (left or right):
                continue  # no active spring at this particle: no move
            mx = my = mz = 0.0
            if left:
                mx += lam[k - 1] * nx[k - 1, 0]
                my += lam[k - 1] * nx[k - 1, 1]
                mz += lam[k - 1] * nx[k - 1, 2]
            if right:
                mx -= lam[k] * nx[k, 0]
                my -= lam[k] * nx[k, 1]
                mz -= lam[k] * nx[k, 2]
            i = np.uint64(row[k])
            w = inv_mass[i]
            n = _normals(contact, i)
            if _touching(n):
                mx, my, mz = _tangent(n, mx, my, mz)  # the move the system was solved for
                mx, my, mz = _slide(contact, i, w, mx, my, mz)
            else:
                mx, my, mz = w * mx, w * my, w * mz
            x[i, 0] += mx
            x[i, 1] += my
            x[i, 2] += mz


@_jit
def ring_limit(x: F64, inv_mass: F64, rings: I64, rest: F64, max_stretch: float, max_compression: float,
               contact: F64) -> None:  # pragma: no cover
    """:func:`line_limit` round closed rings, each solved as the open chain that starts after its
    slackest spring.

    ``rings (R, m)`` lists the particles round each ring and ``rest (R, m)`` the rest length from
    particle ``k`` to particle ``k + 1`` (mod ``m``). A closed ring pressed round a body has no
    well-posed linearised solve (shortening it by sliding along the body is singular), so each ring
    is cut once; an open chain's contraction pulls its two end particles apart, and the spring
    between them takes that stretch. Cut after the spring with the smallest length over rest length,
    it goes where the ring has slack to give (a fixed cut made the spring there hold the residual of
    every frame whose ring is too short for the body: the back centre of a skirt over a pelvis
    tilted by a bow). Ties go to the first such spring (the numpy reference computes the same
    ratios, but rounding may break a near-tie differently). Rings must not share particles; the
    rotated rings ``(R, m)`` are gathered into work arrays (two small allocations per call; indices
    wrap by a compare, not a modulo).
    """
    n_rings, m = rings.shape
    if n_rings == 0:
        return
    rows = np.empty((n_rings, m), dtype=np.int64)
    rows_rest = np.empty((n_rings, m - 1))
    for ln in range(n_rings):
        cut = 0
        slack = np.inf
        i = np.uint64(rings[ln, 0])
        for k in range(m):
            j = np.uint64(rings[ln, k + 1 if k + 1 < m else 0])
            dx, dy, dz = x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2]
            ratio = math.sqrt(dx * dx + dy * dy + dz * dz) / rest[ln, k]
            if ratio < slack:
                slack = ratio
                cut = k
            i = j
        src = cut + 1 if cut + 1 < m else 0
        for k in range(m):
            rows[ln, k] = rings[ln, src]
            if k < m - 1:
                rows_rest[ln, k] = rest[ln, src]
            src = src + 1 if src + 1 < m else 0
    line_limit(x, inv_mass, rows, rows_rest, max_stretch, max_compression, contact)


@_inline
def _lerp_keys(keys: F64, s: float, out: F64) -> None:  # pragma: no cover
    k = keys.shape[0] - 1
    u = min(max(s, 0.0), 1.0) * k
    i0 = min(int(u), k - 1)
    w = u - i0
    out[:] = (1.0 - w) * keys[i0] + w * keys[i0 + 1]


@_jit
def _worst_stretch2(x: F64, springs: I64, hi: F64, inv_mass: F64) -> float:  # pragma: no cover
    """Largest ``(l / hi)**2`` over the ``springs`` with a free end (no round can shorten a spring
    between two pins: a collar spread round the skull would run every extra round in vain)."""
    worst = 0.0
    for s in range(springs.shape[0]):
        i, j, d0, d1, d2 = _spring_vector(x, springs, s)
        if inv_mass[i] + inv_mass[j] <= 0.0:
            continue
        r = (d0 * d0 + d1 * d1 + d2 * d2) / (hi[s] * hi[s])
        if not r <= worst:  # a NaN propagates, as in the numpy reference
            worst = r
    return worst


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
    ``reference.substeps_np``).

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
        broad_phase(x, inv_mass, a1, b1, radii, margin + BROAD_SLACK, cand, xb)
        for _ in range(lim_iterations):  # strain limiting and contacts, interleaved
            long_range_attach(x, inv_mass, anchor, reach)
            for _sweep in range(lim_sweeps):
                line_limit(x, inv_mass, lines_a, rest_a, max_stretch, max_compression, contact)
                line_limit(x, inv_mass, lines_b, rest_b, max_stretch, max_compression, contact)
                ring_limit(x, inv_mass, lines_c, rest_c, max_stretch, max_compression, contact)
            strain_limit(x, inv_mass, lim_springs, lim_lo, lim_hi, 1, contact)
            for i in range(n):
                if inv_mass[i] > 0.0:
                    for d in range(3):
                        v[i, d] = (x[i, d] - xp[i, d]) / dt
            collide(x, v, inv_mass, a0, b0, a1, b1, radii, margin, friction, dt, floor, use_floor, contact,
                    cand, xb, BROAD_SLACK, xp)
        # final rounds: contact-aware strain limiting (contacts slide along the surfaces of the last
        # collision instead of into them), then collision (with final_rounds == 0: no collision after it)
        # then up to extra_rounds more while a structural spring is stretched beyond the trigger
        rounds = max(final_rounds, 1)
        for _r in range(rounds + extra_rounds):
            if _r >= rounds and _worst_stretch2(x, lim_springs, lim_hi, inv_mass) <= extra_trigger2:
                break
            for i in range(n):
                for d in range(3):
                    f[i, d] = x[i, d]
            if straddles and _r >= rounds:  # a limb between two particles of a stretched spring: lift it off
                release_straddles(x, inv_mass, lim_springs, lim_hi, extra_trigger2, a1, b1, radii, margin, opposed)
            for _sweep in range(final_sweeps):
                line_limit(x, inv_mass, lines_a, rest_a, max_stretch, max_compression, contact)
                line_limit(x, inv_mass, lines_b, rest_b, max_stretch, max_compression, contact)
                ring_limit(x, inv_mass, lines_c, rest_c, max_stretch, max_compression, contact)
            strain_limit(x, inv_mass, lim_springs, lim_lo, lim_hi, 1 if final_sweeps > 0 else 0, contact)
            for i in range(n):
                for d in range(3):
                    v[i, d] += (x[i, d] - f[i, d]) / dt
            if final_rounds > 0:  # friction was applied in the interleaved passes already
                collide(x, v, inv_mass, a0, b0, a1, b1, radii, margin, 0.0, dt, floor, use_floor, contact,
                        cand, xb, BROAD_SLACK, xp)
        for i in range(n):
            sp = math.sqrt(v[i, 0] ** 2 + v[i, 1] ** 2 + v[i, 2] ** 2)
            if sp > max_speed and inv_mass[i] > 0.0:
                for d in range(3):
                    v[i, d] *= max_speed / sp


@_inline
def _rotvec_quat(p: F64, i: int) -> tuple[float, float, float, float]:  # pragma: no cover
    """Unit quaternion ``(w, x, y, z)``, ``w >= 0``, of the rotation vector ``p[i:i + 3]``."""
    rx, ry, rz = p[i], p[i + 1], p[i + 2]
    theta = math.sqrt(rx * rx + ry * ry + rz * rz)
    if theta < 1e-8:
        w, x, y, z = 1.0, 0.5 * rx, 0.5 * ry, 0.5 * rz
        n = math.sqrt(w * w + x * x + y * y + z * z)
        return w / n, x / n, y / n, z / n
    c, f = math.cos(0.5 * theta), math.sin(0.5 * theta) / theta
    if c < 0.0:
        c, f = -c, -f
    return c, f * rx, f * ry, f * rz


@_jit
def interpolate_poses(p0: F64, p1: F64, s: F64, out: F64) -> None:  # pragma: no cover
    """Articulated interpolation between poses ``p0`` and ``p1`` ``(P,)`` at fractions ``s (K,)``
    into ``out (K, P)``: the root position linearly, every rotation slerped along the shorter arc
    (reference: ``avatar.interpolate_poses(..., backend="numpy")``)."""
    for k in range(s.shape[0]):
        t = s[k]
        for d in range(3):
            out[k, d] = (1.0 - t) * p0[d] + t * p1[d]
    for i in range(3, p0.shape[0], 3):
        aw, ax, ay, az = _rotvec_quat(p0, i)
        bw, bx, by, bz = _rotvec_quat(p1, i)
        dot = aw * bw + ax * bx + ay * by + az * bz
        if dot < 0.0:
            bw, bx, by, bz, dot = -bw, -bx, -by, -bz, -dot
        theta = math.acos(min(dot, 1.0))
        st = math.sin(theta)
        for k in range(s.shape[0]):
            t = s[k]
            if st < 1e-6:
                w0, w1 = 1.0 - t, t
            else:
                w0, w1 = math.sin((1.0 - t) * theta) / st, math.sin(t * theta) / st
            qw, qx, qy, qz = w0 * aw + w1 * bw, w0 * ax + w1 * bx, w0 * ay + w1 * by, w0 * az + w1 * bz
            qn = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            qw, qx, qy, qz = qw / qn, qx / qn, qy / qn, qz / qn
            sn = math.sqrt(qx * qx + qy * qy + qz * qz)
            scale = 2.0 if sn < 1e-12 else 2.0 * math.atan2(sn, qw) / sn
            out[k, i], out[k, i + 1], out[k, i + 2] = scale * qx, scale * qy, scale * qz


@_jit
def spring_strain(x: F64, springs: I64, rest: F64, out: F64) -> None:  # pragma: no cover
    """``out[s]`` = engineering strain ``(l - L) / L`` of spring ``s`` (reference:
    ``cloth.structural_strain(..., backend="numpy")``)."""
    for s in range(springs.shape[0]):
        _i, _j, d0, d1, d2 = _spring_vector(x, springs, s)
        out[s] = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) / rest[s] - 1.0
