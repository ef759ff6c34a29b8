"""Arms kept out of the trunk: the avatar's self-intersection resolved before the cloth.

Recordings and the capsule body let a forearm or a hand sink into the trunk: a hand pressed on the
hip, an arm swung across the belly, or simply a real hip narrower than its capsule (in the shared
recordings up to 14 cm deep, most often 2-7 cm, in 40 of 252 takes). No cloth position is then
outside both parts, so cloth under the limb ends inside one of them, and a limb that later leaves
the trunk drags the garment with it. An upper arm pressed against the ribs or the hip (an arm held
tight to the side; CMU ``61_10`` up to 38 mm deep) leaves no room for the cape caught under it,
which the arm then drags (cape ``call_normal_001`` 261 %, ``61_10_scaled`` 325 % strain).

:func:`clear_limbs` moves each sunk limb out the way the arm itself would move: the elbow turns about
the shoulder and the wrist about the elbow (every length kept) until the limb's surface is
``clearance`` away from the trunk's; the hand is carried with the wrist and then turns the same way.
An upper arm turns about the fixed shoulder: its elbow moves by the push over the deepest point's
axis fraction (a lever, at least :data:`~cloth_client.avatar.limb_kernels.UPPER_ARM_MIN_LEVER`), the
forearm and hand ride along. The push is along the outward normal of the trunk surface nearest the
deepest point of the limb's axis, by that point's depth plus the clearance, so it grows
continuously from zero as a limb comes within the clearance. The correction is carried from key to
key (:func:`clear_limbs_track`): where the nearest surface flips (at a trunk part's axis, in the
crease between hip and thigh) a fresh correction would jump to the other side, so the previous one
is kept instead. A limb passing right through the trunk has no continuous way out: a side whose
forearm would need more than ``MAX_PUSH`` is left as recorded, for
:meth:`cloth_client.solver.driver.ClothDriver._ghosted`.

The corrected capsules are the avatar: the cloth collides with them, penetration is measured
against them and the renderer draws them (:attr:`cloth_client.solver.driver.ClothDriver.body_capsules`;
:func:`cloth_client.avatar.capsules.avatar_capsules` for a pose sequence without a driver).

The numba kernels of both rules are in :mod:`cloth_client.avatar.limb_kernels`; the functions here
run them, and :func:`limb_overlap_reference` and :func:`clear_limbs_track_reference` are their plain
numpy references (tests hold both equal).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cloth_client.avatar import limb_kernels as K
from cloth_client.contact.collision import round_cone_reference
from protocol.skeleton import CAPSULE_INDEX

__all__ = ["ARMS", "LIMBS", "LIMB_CLEARANCE", "MAX_PUSH", "TRUNK", "clear_limbs", "clear_limbs_track",
           "clear_limbs_track_reference", "limb_overlap", "limb_overlap_reference"]

F64 = NDArray[np.float64]

#: Capsules that can sink into the body in a recording (forearms, hands) and the capsules they sink
#: into (pelvis, abdomen, thorax, thighs). LIMBS is (forearm, hand) per side.
LIMBS = np.array([CAPSULE_INDEX[n] for n in ("l_forearm", "l_hand", "r_forearm", "r_hand")])
TRUNK = np.array([CAPSULE_INDEX[n] for n in ("pelvis", "abdomen", "thorax", "l_thigh", "r_thigh")])
#: Upper arm, forearm and hand of each side: the chains :func:`clear_limbs` turns.
ARMS = np.array([[CAPSULE_INDEX[f"{side}_{n}"] for n in ("upper_arm", "forearm", "hand")] for side in "lr"])
#: Default gap left between a cleared limb's surface and the trunk's, metres: two cloth margins
#: (:attr:`cloth_client.solver.cloth.ClothParams.margin`), room for a layer of cloth between hand and hip.
LIMB_CLEARANCE = 0.012
#: Deepest fresh push (metres) :func:`clear_limbs` makes; deeper limbs are ghosted by the driver. Past the
#: ~16 cm where a forearm's axis reaches the pelvis's or the abdomen's (radius 10-12 cm, forearm 3-4
#: cm, clearance), where the nearest surface flips side: the correction carried from the previous
#: key keeps such a limb on the side it came from (14 cm, the limit before, left the hand of CMU
#: ``131_01``, whose push at the pelvis's axis is 14.9 cm, ghosted: 21-25 mm of penetration).
MAX_PUSH = 0.17


def limb_overlap(a: F64, b: F64, radii: F64, limbs: NDArray[np.int64] = LIMBS,
                 trunk: NDArray[np.int64] = TRUNK, samples: int = 9) -> F64:
    """How deep each limb capsule's surface sinks into the trunk capsules in one pose.

    Parameters
    ----------
    a, b : (C, 3) float64
        Capsule endpoints, metres.
    radii : (C, 2) float64
        Capsule radii at ``a`` and ``b``.
    limbs, trunk : (L,), (T,) int64
        Capsule indices.
    samples : int
        Points sampled along each limb's axis.

    Returns
    -------
    (L,) float64
        Largest ``r_limb(s) - d_trunk(s)`` over the axis samples ``s`` and the trunk capsules,
        metres (``d_trunk`` the signed distance of the axis point to a trunk surface): > 0 when the
        two surfaces overlap by that much, e.g. a forearm swung through the hips.

    Runs the kernel :func:`cloth_client.avatar.limb_kernels.limb_overlap`; :func:`limb_overlap_reference`
    is its plain numpy reference.
    """
    _check_samples(samples)
    a64, b64 = np.ascontiguousarray(a, dtype=np.float64), np.ascontiguousarray(b, dtype=np.float64)
    r64 = np.ascontiguousarray(radii, dtype=np.float64)
    li, ti = np.ascontiguousarray(limbs, dtype=np.int64), np.ascontiguousarray(trunk, dtype=np.int64)
    n = a64.shape[0] if a64.ndim == 2 else -1
    if a64.shape != (n, 3) or b64.shape != (n, 3) or r64.shape != (n, 2) or li.ndim != 1 or ti.ndim != 1:
        raise ValueError(f"limb_overlap: a, b must be (C, 3), radii (C, 2); got {a64.shape}, {b64.shape}, "
                         f"{r64.shape}")  # the kernel checks the capsule indices against C
    res = np.empty(len(li))
    K.limb_overlap(a64, b64, r64, li, ti, np.linspace(0.0, 1.0, samples), res)
    return res


def limb_overlap_reference(a: F64, b: F64, radii: F64, limbs: NDArray[np.int64] = LIMBS,
                           trunk: NDArray[np.int64] = TRUNK, samples: int = 9) -> F64:
    """:func:`limb_overlap` in plain numpy (reference of :func:`cloth_client.avatar.limb_kernels.limb_overlap`)."""
    _check_samples(samples)
    depth, _ = _axis_depth(a[None], b[None], radii, limbs, trunk, np.linspace(0.0, 1.0, samples))
    out: F64 = depth[0].max(axis=1)
    return out


def _check_samples(samples: int) -> None:
    if samples < 1:
        raise ValueError(f"samples must be >= 1, got {samples}")


def _axis_depth(a: F64, b: F64, radii: F64, limbs: NDArray[np.int64], trunk: NDArray[np.int64],
                s: F64) -> tuple[F64, F64]:
    """Overlap of limb axis samples with the trunk, per key.

    Parameters
    ----------
    a, b : (K, C, 3) float64
    radii : (C, 2) float64
    limbs : (L,) int64
    trunk : (T,) int64
    s : (S,) float64
        Axis fractions.

    Returns
    -------
    depth : (K, L, S) float64
        ``r_limb(s) - min_t d_t(s)``, metres.
    normal : (K, L, S, 3) float64
        Outward normal of the nearest trunk surface.
    """
    k, n_l, n_s, n_t = a.shape[0], len(limbs), len(s), len(trunk)
    pts = a[:, limbs, None] + s[None, None, :, None] * (b[:, limbs] - a[:, limbs])[:, :, None]  # (K, L, S, 3)
    # every key's points against every key's trunk (K is small), then the matching key's block
    d, nrm, _ = round_cone_reference(pts.reshape(-1, 3), a[:, trunk].reshape(-1, 3), b[:, trunk].reshape(-1, 3),
                                     np.tile(radii[trunk, 0], k), np.tile(radii[trunk, 1], k))
    kk = np.arange(k)
    d = d.reshape(k, n_l * n_s, k, n_t)[kk, :, kk].reshape(k, n_l, n_s, n_t)
    nrm = nrm.reshape(k, n_l * n_s, k, n_t, 3)[kk, :, kk].reshape(k, n_l, n_s, n_t, 3)
    nearest = d.argmin(axis=-1)
    d_min = np.take_along_axis(d, nearest[..., None], axis=-1)[..., 0]
    normal = np.take_along_axis(nrm, nearest[..., None, None], axis=-2)[..., 0, :]
    r = (1.0 - s)[None, :] * radii[limbs, 0][:, None] + s[None, :] * radii[limbs, 1][:, None]  # (L, S)
    return r[None] - d_min, normal


def clear_limbs(a: F64, b: F64, radii: F64, clearance: float = LIMB_CLEARANCE, max_push: float = MAX_PUSH,
                iterations: int = 4, samples: int = 9) -> tuple[F64, F64]:
    """Capsule endpoints with every sunk upper arm, forearm and hand turned out of the trunk.

    :func:`clear_limbs_track` with no correction carried in (keys taken in time order); see there
    for the rule and the parameters.

    Returns
    -------
    a, b : same shape as the input
        Copies; unchanged where no limb is within ``clearance`` of the trunk and no carried
        correction holds one.
    """
    a2, b2, _ = clear_limbs_track(a, b, radii, None, clearance, max_push, iterations, samples)
    return a2, b2


def clear_limbs_track(a: F64, b: F64, radii: F64, memory: F64 | None = None, clearance: float = LIMB_CLEARANCE,
                      max_push: float = MAX_PUSH, iterations: int = 4, samples: int = 9,
                      first_given: bool = False) -> tuple[F64, F64, F64]:
    """Capsule endpoints of keys in time order with every sunk upper arm, forearm and hand turned out
    of the trunk, and the corrections to carry to the next key.

    Each round takes the upper arm, the forearm, then the hand, of each side. The upper arm's elbow
    turns about the shoulder by ``p n / max(s, UPPER_ARM_MIN_LEVER)`` (``p``, ``n``, ``s`` as below;
    the forearm and hand carried with it, lengths kept). For the forearm and the hand the deepest
    sample ``s`` of the capsule's axis must move by ``p n`` (``p`` its depth plus the clearance, ``n`` the nearest trunk
    surface's outward normal). The capsule's ends move by the least-norm split of that,
    ``(1 - s) p n / D`` and ``s p n / D`` with ``D = (1 - s)^2 + s^2``; the near end (elbow, wrist)
    turns about its parent's pivot (shoulder, elbow) towards its target, the far end is carried
    with it and turns about it towards its own, every length kept. A moved wrist carries the hand.

    The correction is carried from key to key. Started afresh at every key, the nearest surface
    can flip between two keys (at a trunk part's axis, or in the crease between hip and thigh,
    where alternate pushes out of the two parts end in different places): a recorded hand in that
    crease was put 15 cm apart on two keys 8 ms apart, dragging the cloth through itself. So when
    the fresh correction moves a joint (elbow, wrist, hand tip) more than
    :data:`~cloth_client.avatar.limb_kernels.CARRY_JUMP` from the previous key's correction, the
    previous one is applied instead (its offsets, each joint turned about its moved parent, lengths
    kept): pushed out as above if the limb sinks with it, else relaxed towards the recording by as
    much of :data:`~cloth_client.avatar.limb_kernels.RELAX_RATE` as keeps the limb clear (bisection).
    The corrected limb thus stays on the side of the trunk it was turned to; the fresh correction
    takes over again once it comes within ``CARRY_JUMP`` of the carried one. Where the two agree,
    keys are corrected exactly as without the memory. A carried correction is dropped (the arm
    goes back to the recording) when the recorded limb is clear of the trunk but no part of the
    way back to it is (an arm swung through the side of the hips and held behind them).

    Parameters
    ----------
    a, b : (K, C, 3) or (C, 3) float64
        Capsule endpoints per key, metres (the arm chains: ``b[upper_arm] = a[forearm]``,
        ``b[forearm] = a[hand]``).
    radii : (C, 2) float64
    memory : (2, 3, 3) float64, optional
        Per side (left, right), how far the elbow, wrist and hand tip were moved from the recorded
        ones at the key before ``a[0]`` (zeros: not moved), as returned by the previous call with
        the same recording; None: none.
    clearance : float
        Gap to leave between the limb's surface and the trunk's, metres.
    max_push : float
        A side whose forearm's deepest axis sample would have to move further than this (metres)
        is left as recorded (a hand alone over it: the hand), since a limb passing through the
        trunk has no continuous way out; the driver ghosts it instead.
    iterations : int
        Rounds per side (each clears the deepest axis sample of each capsule).
    samples : int
        Axis samples per capsule.
    first_given : bool
        ``memory`` is the correction of ``a[0]`` itself, not of a key before it: the keys start
        where the previous call's last key ended (the same pose), and the correction is applied
        to it as it is.

    Returns
    -------
    a, b : same shape as the input
        Copies; unchanged where no limb is within ``clearance`` of the trunk and no carried
        correction holds one.
    memory : (2, 3, 3) float64
        The offsets at the last key.

    Runs the kernel :func:`cloth_client.avatar.limb_kernels.clear_limbs`;
    :func:`clear_limbs_track_reference` is its plain numpy reference.
    """
    single, a2, b2, mem = _track_inputs(a, b, memory)
    s = np.linspace(0.0, 1.0, samples)
    K.clear_limbs(a2, b2, np.ascontiguousarray(radii, dtype=np.float64), ARMS, TRUNK, s, clearance, max_push,
                  iterations, mem, first_given)
    if single:
        return a2[0], b2[0], mem
    return a2, b2, mem


def clear_limbs_track_reference(a: F64, b: F64, radii: F64, memory: F64 | None = None,
                                clearance: float = LIMB_CLEARANCE, max_push: float = MAX_PUSH, iterations: int = 4,
                                samples: int = 9, first_given: bool = False) -> tuple[F64, F64, F64]:
    """:func:`clear_limbs_track` in plain numpy, same rule and parameters (reference of
    :func:`cloth_client.avatar.limb_kernels.clear_limbs`)."""
    single, a2, b2, mem = _track_inputs(a, b, memory)
    s = np.linspace(0.0, 1.0, samples)
    for k in range(len(a2)):  # key after key: each continues from the previous key's correction
        _clear_key(a2[k:k + 1], b2[k:k + 1], radii, mem, clearance, max_push, iterations, s, k == 0 and first_given)
    if single:
        return a2[0], b2[0], mem
    return a2, b2, mem


def _track_inputs(a: F64, b: F64, memory: F64 | None) -> tuple[bool, F64, F64, F64]:
    """``(single, a (K, C, 3), b (K, C, 3), memory (2, 3, 3))``: copies of the inputs of
    :func:`clear_limbs_track` (``single``: one key ``(C, 3)`` was given)."""
    single = a.ndim == 2
    a2 = np.array(a[None] if single else a, dtype=np.float64)
    b2 = np.array(b[None] if single else b, dtype=np.float64)
    mem = np.zeros((2, 3, 3)) if memory is None else np.array(memory, dtype=np.float64)
    if mem.shape != (2, 3, 3):
        raise ValueError(f"memory must have shape (2, 3, 3), got {mem.shape}")
    return single, a2, b2, mem


def _clear_key(a: F64, b: F64, radii: F64, mem: F64, clearance: float, max_push: float, iterations: int,
               s: F64, given: bool) -> None:
    """One key ``(1, C, 3)`` of :func:`clear_limbs_track_reference`, in place (``mem`` too);
    ``given``: ``mem`` is this key's own correction."""
    for side, chain in enumerate(ARMS):
        if _deepest(a, b, radii, chain[1], clearance, s)[0][0] > max_push:
            mem[side] = 0.0
            continue  # a side whose forearm cannot be cleared stays as recorded (the driver ghosts it)
        raw_a, raw = a[0, chain].copy(), b[0, chain].copy()
        lengths = np.linalg.norm(raw - raw_a, axis=-1)
        warm = bool((np.linalg.norm(mem[side], axis=-1) > 1e-12).any())
        if given:
            if warm:
                _rebuild(a, b, chain, raw, mem[side], 1.0, lengths)
            continue
        _arm_out(a, b, radii, chain, clearance, max_push, iterations, s)
        fresh_size = float(np.linalg.norm(b[0, chain] - raw, axis=-1).max())
        if warm and np.linalg.norm(b[0, chain] - raw - mem[side], axis=-1).max() > K.CARRY_JUMP:
            # the fresh correction jumped: carry the previous one, pushed out if it sinks, else
            # relaxed as far as it stays clear (at most RELAX_RATE of it)
            a[0, chain], b[0, chain] = raw_a, raw
            _rebuild(a, b, chain, raw, mem[side], 1.0, lengths)
            if _sunk(a, b, radii, chain, clearance, s):
                _arm_out(a, b, radii, chain, clearance, max_push, iterations, s)
            else:
                lo, hi = 1.0 - K.RELAX_RATE, 1.0
                _rebuild(a, b, chain, raw, mem[side], lo, lengths)
                if _sunk(a, b, radii, chain, clearance, s):
                    for _ in range(K.RELAX_STEPS):
                        mid = 0.5 * (lo + hi)
                        _rebuild(a, b, chain, raw, mem[side], mid, lengths)
                        if _sunk(a, b, radii, chain, clearance, s):
                            lo = mid
                        else:
                            hi = mid
                    _rebuild(a, b, chain, raw, mem[side], hi, lengths)
                    if hi == 1.0 and fresh_size == 0.0:  # recorded limb clear, the way back blocked
                        a[0, chain], b[0, chain] = raw_a, raw
        mem[side] = b[0, chain] - raw


def _sunk(a: F64, b: F64, radii: F64, chain: NDArray[np.int64], clearance: float, s: F64) -> bool:
    """Whether the upper arm, forearm or hand of ``chain`` (one key) is nearer the trunk than ``clearance``."""
    return max(float(_deepest(a, b, radii, chain[i], clearance, s)[0][0]) for i in (0, 1, 2)) > 1e-6


def _arm_out(a: F64, b: F64, radii: F64, chain: NDArray[np.int64], clearance: float, max_push: float,
             iterations: int, s: F64) -> None:
    """Rounds of pushes of the upper arm, the forearm, then the hand, of ``chain`` (one key), in place."""
    for _ in range(iterations):
        moved = [_push_out(a, b, radii, chain, i, clearance, max_push, s) for i in (0, 1, 2)]
        if not any(moved):
            break


def _rebuild(a: F64, b: F64, chain: NDArray[np.int64], raw: F64, offset: F64, lam: float, lengths: F64) -> None:
    """Arm ``chain`` of one key ``(1, C, 3)`` set to its recorded joints ``raw`` (3, 3: elbow,
    wrist, hand tip) moved by ``lam * offset``, each turned about its moved parent, lengths kept."""
    for j in range(3):
        b[0, chain[j]] = _unit_towards(a[0, chain[j]], raw[j] + lam * offset[j], lengths[j], b[0, chain[j]])
        if j < 2:
            a[0, chain[j + 1]] = b[0, chain[j]]


def _unit_towards(pivot: F64, target: F64, length: F64, keep: F64) -> F64:
    """``pivot + length * unit(target - pivot)`` per row (``keep`` where degenerate)."""
    d = target - pivot
    n = np.linalg.norm(d, axis=-1, keepdims=True)
    out: F64 = np.where(n > 1e-12, pivot + d * (length / np.maximum(n, 1e-300)), keep)
    return out


def _deepest(a: F64, b: F64, radii: F64, cap: int, clearance: float, s: F64) -> tuple[F64, F64, F64]:
    """Per key: the push (depth + clearance) of capsule ``cap``'s deepest axis sample ``(K,)``, the
    nearest trunk surface's outward normal there ``(K, 3)`` and the sample's axis fraction ``(K,)``."""
    depth, normal = _axis_depth(a, b, radii, np.array([cap]), TRUNK, s)
    depth, normal = depth[:, 0] + clearance, normal[:, 0]  # (K, S), (K, S, 3)
    kk = np.arange(len(depth))
    j = depth.argmax(axis=1)
    return depth[kk, j], normal[kk, j], s[j]


def _push_out(a: F64, b: F64, radii: F64, chain: NDArray[np.int64], i: int, clearance: float, max_push: float,
              s: F64) -> bool:
    """One push of capsule ``chain[i]`` (0: upper arm, 1: forearm, 2: hand) of one key ``(1, C, 3)``
    along the nearest trunk surface's normal, in place; False when it needs none (or more than
    ``max_push``)."""
    cap = chain[i]
    push_, n, sj_ = _deepest(a, b, radii, cap, clearance, s)
    if not 1e-6 < push_[0] <= max_push:
        return False
    far = b[:, cap].copy()
    if i == 0:  # the shoulder stays: the elbow turns about it, levered at the push's axis fraction
        lever = push_[0] / max(sj_[0], K.UPPER_ARM_MIN_LEVER)
        if lever > max_push:
            return False
        length = np.linalg.norm(far - a[:, cap], axis=-1, keepdims=True)
        b[:, cap] = _unit_towards(a[:, cap], far + lever * n, length, far)
    else:
        parent = chain[i - 1]
        push, sj = push_[:, None], sj_[:, None]
        den = (1.0 - sj) ** 2 + sj**2
        near = a[:, cap].copy()
        l_near = np.linalg.norm(b[:, parent] - a[:, parent], axis=-1, keepdims=True)
        l_far = np.linalg.norm(far - near, axis=-1, keepdims=True)
        new_near = _unit_towards(a[:, parent], near + push * (1.0 - sj) / den * n, l_near, b[:, parent])
        b[:, parent] = new_near
        a[:, cap] = new_near
        b[:, cap] = _unit_towards(new_near, far + (new_near - near) + push * sj / den * n, l_far, far)
    for j in range(i + 1, 3):  # the rest of the arm rides the moved end (elbow or wrist)
        b[:, chain[j]] += b[:, cap] - far
        a[:, chain[j]] = b[:, chain[j - 1]]
    return True
