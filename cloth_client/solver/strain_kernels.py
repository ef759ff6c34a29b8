"""Numba kernels of the solver's strain limiting: long-range attachments, line and ring solves,
Gauss-Seidel sweeps, all contact-aware, and the stretch that triggers extra rounds.

:mod:`cloth_client.solver.reference` describes the passes and holds their plain numpy references
(``*_reference``); tests hold both equal. The contact-aware moves keep shapes that the fast-math
flags of :mod:`cloth_client._jit` make matter for bit-identity: moves multiplied before the branch
that adds them, contact normals read inside :func:`_slide`'s loop. Compare any change bitwise with
the previous kernels, on particles with two contact normals too.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from cloth_client._jit import inline_kernel as _inline
from cloth_client._jit import jit_kernel as _jit
from cloth_client.solver.force_kernels import spring_vector

__all__ = ["SLIDE_FLOOR", "line_limit", "long_range_attach", "ring_limit", "strain_limit", "touching",
           "worst_stretch2"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
B1 = NDArray[np.bool_]

#: Least share of a constraint's unconstrained mobility the sliding line solve credits it with: a
#: spring's diagonal entry is ``sum w (u . P u)`` (``P``: onto the tangent space of the surfaces a
#: particle touches) instead of ``sum w``, floored at this share of ``sum w`` so a spring whose both
#: ends are held against the body (nearly along both normals) is not corrected by an unbounded slide
#: (a move of at most about ``1 / sqrt(SLIDE_FLOOR)`` = 2 times the unconstrained one; 0.1 gave the same
#: 26-take sample but one frame at 1,060 % on ``cmu/01_01``, 313 % with 0.25).
SLIDE_FLOOR = 0.25
#: Relative margins of the squared-length tests that skip a square root without changing a result: a
#: squared length below ``hi**2 * _INSIDE`` and above ``lo**2 * _OUTSIDE`` is within ``[lo, hi]``, one
#: above ``(s L)**2 * _OUTSIDE`` has a ratio ``l / L`` above ``s``, whatever the rounding of the root.
_INSIDE, _OUTSIDE = 1.0 - 1e-12, 1.0 + 1e-12


@_jit
def long_range_attach(x: F64, inv_mass: F64, anchor: I64, reach: F64) -> None:  # pragma: no cover
    """Pull every free particle ``i`` back within ``reach[i]`` of particle ``anchor[i]`` (its pin;
    reference: :func:`~cloth_client.solver.reference.long_range_attach_reference`)."""
    for i in range(x.shape[0]):
        if inv_mass[i] <= 0.0:
            continue
        a = np.uint64(anchor[i])
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

    :func:`_tangent` takes these six numbers instead of the array: an array
    handed to an inlined helper with branches costs a reference-count increment and decrement per
    call (more than the arithmetic of an untouched particle)."""
    return contact[i, 0], contact[i, 1], contact[i, 2], contact[i, 3], contact[i, 4], contact[i, 5]


@_jit
def touching(contact: F64, out: B1) -> None:  # pragma: no cover
    """``out[i]``: whether particle ``i`` rests on any surface (a nonzero normal in ``contact[i]``;
    reference: :func:`~cloth_client.solver.reference.touching_reference`).

    The strain passes take these flags (``touch``): one byte per particle instead of the six
    normals, read for every particle a pass moves (the collision passes change
    ``contact``; the substep kernel refreshes the flags after each)."""
    for i in range(contact.shape[0]):
        out[i] = ((contact[i, 0] != 0.0) | (contact[i, 1] != 0.0) | (contact[i, 2] != 0.0)
                  | (contact[i, 3] != 0.0) | (contact[i, 4] != 0.0) | (contact[i, 5] != 0.0))


@_inline
def _flags(contact: F64, touch: B1 | None) -> B1:  # pragma: no cover
    """``touch``, or the :func:`touching` flags of ``contact`` when None (a call without them)."""
    if touch is None:
        out = np.empty(contact.shape[0], dtype=np.bool_)
        touching(contact, out)
        return out
    return touch


@_inline
def _slide(contact: F64, i: np.uint64, w: float, dx: float, dy: float,
           dz: float) -> tuple[float, float, float]:  # pragma: no cover
    """The move ``w * d`` of particle ``i`` less any component of it into the surfaces it touches.

    ``contact[i]`` holds up to two unit normals (``[0:3]`` and ``[3:6]``, zero when unused); with
    two (a crease between body parts) the move is projected alternately until it points into
    neither surface, so pinched cloth slides along the crease. Callers use it for touching
    particles only (see :func:`touching`; the move of the others is ``w * d``), then add the move
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
                 contact: F64, touch: B1 | None = None) -> None:  # pragma: no cover
    """Provot-style strain limiting: project each spring's length into ``[lo, hi]`` (Gauss-Seidel).

    Odd iterations sweep backwards (symmetric Gauss-Seidel). ``contact (N, 6)`` holds the unit
    normals of up to two surfaces each particle rests on (zero if none): moves into them are dropped;
    ``touch (N,) bool``, optional, its :func:`touching` flags (computed here when not given). A
    spring whose squared length is clearly within its bounds (:data:`_INSIDE`, :data:`_OUTSIDE`) is
    passed over without a square root. Reference:
    :func:`~cloth_client.solver.reference.strain_limit_reference` (particle-disjoint batches).
    """
    flags = _flags(contact, touch)
    n_springs = springs.shape[0]
    for it in range(iterations):
        for k in range(n_springs):
            s = k if it % 2 == 0 else n_springs - 1 - k  # symmetric Gauss-Seidel: alternate sweeps
            i = np.uint64(springs[s, 0])  # unsigned: no wrap-around test on each access
            j = np.uint64(springs[s, 1])
            dx = x[j, 0] - x[i, 0]
            dy = x[j, 1] - x[i, 1]
            dz = x[j, 2] - x[i, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < hi[s] * hi[s] * _INSIDE and d2 > lo[s] * lo[s] * _OUTSIDE:
                continue  # clearly within bounds (no square root)
            length = math.sqrt(d2)
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
            # bits (fast-math contraction), which would void the sweep
            w = wi * c
            if flags[i]:
                mx, my, mz = _slide(contact, i, w, dx, dy, dz)
            else:
                mx, my, mz = w * dx, w * dy, w * dz
            x[i, 0] += mx
            x[i, 1] += my
            x[i, 2] += mz
            w = -wj * c
            if flags[j]:
                mx, my, mz = _slide(contact, j, w, dx, dy, dz)
            else:
                mx, my, mz = w * dx, w * dy, w * dz
            x[j, 0] += mx
            x[j, 1] += my
            x[j, 2] += mz


@_jit
def line_limit(x: F64, inv_mass: F64, lines: I64, rest: F64, max_stretch: float, max_compression: float,
               contact: F64, touch: B1 | None = None) -> None:  # pragma: no cover
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

    ``touch (N,) bool``, optional: the :func:`touching` flags of ``contact`` (computed here when not
    given). Particle indices are used unsigned (``np.uint64``: no wrap-around test on each access); a
    spring whose squared length lies clearly inside its bounds (by a relative ``1e-12``, far above the
    rounding of the square root) is inactive without a square root; a line without an active spring
    is skipped, and the elimination and the moves of the others span their first to last active
    spring only (outside it every row is the identity and every move zero); an inactive spring's row
    of the system is the identity (``cp = dp = 0``, as ``0 / 1`` gives), the off-diagonal entry
    shared by rows ``k`` and ``k + 1`` is computed once, a particle that touches nothing skips the
    projections (the identity then) and one next to no active spring the move (zero): the same
    numbers as the plain form (reference:
    :func:`~cloth_client.solver.reference.line_limit_reference`).
    """
    flags = _flags(contact, touch)
    m = lines.shape[1]
    nx = np.empty((m, 3))
    cons = np.empty(m)
    act = np.zeros(m, dtype=np.bool_)
    cp = np.empty(m)
    dp = np.empty(m)
    lam = np.zeros(m)
    for ln in range(lines.shape[0]):
        row = lines[ln]
        first = last = -1  # the line's first and last active springs
        c = 0.0  # row k - 1's upper off-diagonal entry: row k's lower one (the same expression)
        for k in range(-1, m - 1):
            # spring k + 1 first: the elimination of row k needs whether it is active, and its direction
            q = k + 1
            if q < m - 1:
                i, j = np.uint64(row[q]), np.uint64(row[q + 1])
                dx, dy, dz = x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2]
                d2 = dx * dx + dy * dy + dz * dz
                hi = rest[ln, q] * (1.0 + max_stretch)
                lo = rest[ln, q] * (1.0 - max_compression)
                if d2 < hi * hi * _INSIDE and d2 > lo * lo * _OUTSIDE:  # clearly within bounds: inactive
                    act[q] = False
                else:
                    length = math.sqrt(d2)
                    w = inv_mass[i] + inv_mass[j]
                    active = (length > hi or length < lo) and length > 1e-12 and w > 0.0
                    act[q] = active
                    if active:
                        last = q
                        if first < 0:
                            first = q
                        nx[q, 0], nx[q, 1], nx[q, 2] = dx / length, dy / length, dz / length
                        cons[q] = length - (hi if length > hi else lo)
            if k < 0:
                continue
            # forward elimination of row k
            if not act[k]:
                cp[k] = 0.0
                dp[k] = 0.0
                continue
            i, j = np.uint64(row[k]), np.uint64(row[k + 1])
            wi, wj = inv_mass[i], inv_mass[j]
            n0, n1, n2 = nx[k, 0], nx[k, 1], nx[k, 2]
            # J W P J^T: each end only moves in the tangent space of the surfaces it touches
            if flags[i]:
                bi = _tangent_dot(_normals(contact, i), n0, n1, n2, n0, n1, n2)
            else:
                bi = n0 * n0 + n1 * n1 + n2 * n2
            if flags[j]:
                bj = _tangent_dot(_normals(contact, j), n0, n1, n2, n0, n1, n2)
            else:
                bj = n0 * n0 + n1 * n1 + n2 * n2
            b = max(wi * bi + wj * bj, SLIDE_FLOOR * (wi + wj))
            d = -cons[k]
            if k > 0 and act[k - 1]:
                a = c
                denom = b - a * cp[k - 1]
                d -= a * dp[k - 1]
            else:
                denom = b
            if k + 1 < m - 1 and act[k + 1]:
                if flags[j]:
                    dot = _tangent_dot(_normals(contact, j), n0, n1, n2, nx[k + 1, 0], nx[k + 1, 1], nx[k + 1, 2])
                else:
                    dot = n0 * nx[k + 1, 0] + n1 * nx[k + 1, 1] + n2 * nx[k + 1, 2]
                c = -inv_mass[j] * dot
            else:
                c = 0.0
            cp[k] = c / denom
            dp[k] = d / denom
        if first < 0:
            continue
        lam[last] = dp[last]
        for k in range(last + 1, first - 1, -1):  # back substitution, and the moves as it goes
            if first <= k - 1 < last:
                lam[k - 1] = dp[k - 1] - cp[k - 1] * lam[k]
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
            if flags[i]:
                mx, my, mz = _tangent(_normals(contact, i), mx, my, mz)  # the move the system was solved for
                mx, my, mz = _slide(contact, i, w, mx, my, mz)
            else:
                mx, my, mz = w * mx, w * my, w * mz
            x[i, 0] += mx
            x[i, 1] += my
            x[i, 2] += mz


@_jit
def ring_limit(x: F64, inv_mass: F64, rings: I64, rest: F64, max_stretch: float, max_compression: float,
               contact: F64, touch: B1 | None = None) -> None:  # pragma: no cover
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
    wrap by a compare, not a modulo; a spring whose squared length is clearly above the slackest
    ratio so far is passed over without a square root); ``touch`` as in :func:`line_limit`. Reference:
    :func:`~cloth_client.solver.reference.ring_limit_reference`.
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
            i = j
            d2 = dx * dx + dy * dy + dz * dz
            r = rest[ln, k]
            if d2 > slack * slack * (r * r) * _OUTSIDE:
                continue  # clearly above the slackest ratio so far: no root, no division
            ratio = math.sqrt(d2) / r
            if ratio < slack:
                slack = ratio
                cut = k
        src = cut + 1 if cut + 1 < m else 0
        for k in range(m):
            rows[ln, k] = rings[ln, src]
            if k < m - 1:
                rows_rest[ln, k] = rest[ln, src]
            src = src + 1 if src + 1 < m else 0
    line_limit(x, inv_mass, rows, rows_rest, max_stretch, max_compression, contact, _flags(contact, touch))


@_jit
def worst_stretch2(x: F64, springs: I64, hi: F64, inv_mass: F64) -> float:  # pragma: no cover
    """Largest ``(l / hi)**2`` over the ``springs`` with a free end (no round can shorten a spring
    between two pins: a collar spread round the skull would run every extra round in vain; reference:
    :func:`~cloth_client.solver.reference.worst_stretch2_reference`)."""
    worst = 0.0
    for s in range(springs.shape[0]):
        i, j, d0, d1, d2 = spring_vector(x, springs, s)
        if inv_mass[i] + inv_mass[j] <= 0.0:
            continue
        r = (d0 * d0 + d1 * d1 + d2 * d2) / (hi[s] * hi[s])
        if not r <= worst:  # a NaN propagates, as in the numpy reference
            worst = r
    return worst
