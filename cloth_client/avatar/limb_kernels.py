"""Numba kernels of the sunk-limb rules: limb-trunk overlap and arms turned out of the trunk.

:mod:`cloth_client.avatar.limb_clearance` describes the rules and holds the plain numpy references
(:func:`~cloth_client.avatar.limb_clearance.limb_overlap_reference`,
:func:`~cloth_client.avatar.limb_clearance.clear_limbs_track_reference`); tests hold both equal.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from cloth_client._jit import inline_kernel as _inline
from cloth_client._jit import jit_kernel as _jit
from cloth_client.contact.cone_kernels import GEO_COLS, capsule_geometry, round_cone_geo

__all__ = ["CARRY_JUMP", "RELAX_RATE", "RELAX_STEPS", "UPPER_ARM_MIN_LEVER", "clear_limbs", "limb_overlap"]

F64 = NDArray[np.float64]

#: A limb correction (:func:`clear_limbs`) that moves a joint further than this (metres) from the
#: previous key's correction is taken for a flip of the nearest trunk surface (it can also be a
#: fast motion seen through keys closer than ~3.5 ms): the previous correction is carried over.
CARRY_JUMP = 0.02
#: Largest fraction of a carried-over correction given back to the recording per key, and the
#: bisection steps that find how much of it keeps the limb clear.
RELAX_RATE = 0.25
RELAX_STEPS = 6
#: Smallest axis fraction a push of the upper arm is levered at (:func:`clear_limbs`): the shoulder
#: end cannot move, so a push near it turns the elbow by push / fraction; this caps that gain at 4.
UPPER_ARM_MIN_LEVER = 0.25


@_jit
def limb_overlap(a: F64, b: F64, radii: F64, limbs: NDArray[np.int64], trunk: NDArray[np.int64], s: F64,
                 out: F64) -> None:  # pragma: no cover
    """``out[l]``: largest ``r_limb(s) - min_t d_t(s)`` over the axis samples ``s`` of limb capsule
    ``limbs[l]`` and the trunk capsules ``trunk`` (reference:
    :func:`cloth_client.avatar.limb_clearance.limb_overlap_reference`).

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
    geo = np.empty((a.shape[0], GEO_COLS))
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
    reference: :func:`cloth_client.avatar.limb_clearance.clear_limbs_track_reference`).

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
    geo = np.empty((a.shape[1], GEO_COLS))
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
