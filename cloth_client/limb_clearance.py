"""Forearms and hands kept out of the trunk: the avatar's self-intersection resolved before the cloth.

Recordings and the capsule body let a forearm or a hand sink into the trunk: a hand pressed on the
hip, an arm swung across the belly, or simply a real hip narrower than its capsule (in the shared
recordings up to 14 cm deep, most often 2-7 cm, in 40 of 252 takes). No cloth position is then
outside both parts, so cloth under the limb ends inside one of them, and a limb that later leaves
the trunk drags the garment with it.

:func:`clear_limbs` moves each sunk limb out the way the arm itself would move: the elbow turns about
the shoulder and the wrist about the elbow (every length kept) until the limb's surface is
``clearance`` away from the trunk's; the hand is carried with the wrist and then turns the same way.
The push is along the outward normal of the trunk surface nearest the deepest point of the limb's
axis, by that point's depth plus the clearance, so it grows continuously from zero as a limb comes
within the clearance: the corrected avatar moves as smoothly as the recorded one. A limb passing
right through the trunk has no continuous way out (the nearest surface flips side at the trunk's
axis): a side whose forearm would need more than ``MAX_PUSH`` is left as recorded, for
:meth:`cloth_client.driver.ClothDriver._ghosted`.

The corrected capsules are the avatar: the cloth collides with them, penetration is measured
against them and the renderer draws them (:func:`cloth_client.avatar.avatar_capsules`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import CAPSULE_INDEX

from . import _contact_kernels as K
from .collision import round_cone_np

__all__ = ["ARMS", "LIMBS", "LIMB_CLEARANCE", "MAX_PUSH", "TRUNK", "clear_limbs", "limb_overlap"]

F64 = NDArray[np.float64]

#: Capsules that can sink into the body in a recording (forearms, hands) and the capsules they sink
#: into (pelvis, abdomen, thorax, thighs). LIMBS is (forearm, hand) per side.
LIMBS = np.array([CAPSULE_INDEX[n] for n in ("l_forearm", "l_hand", "r_forearm", "r_hand")])
TRUNK = np.array([CAPSULE_INDEX[n] for n in ("pelvis", "abdomen", "thorax", "l_thigh", "r_thigh")])
#: Upper arm, forearm and hand of each side: the chains :func:`clear_limbs` turns.
ARMS = np.array([[CAPSULE_INDEX[f"{side}_{n}"] for n in ("upper_arm", "forearm", "hand")] for side in "lr"])
#: Default gap left between a cleared limb's surface and the trunk's, metres: two cloth margins
#: (:attr:`cloth_client.cloth.ClothParams.margin`), room for a layer of cloth between hand and hip.
LIMB_CLEARANCE = 0.012
#: Deepest push (metres) :func:`clear_limbs` makes; deeper limbs are ghosted by the driver. Short of
#: the ~16 cm where a forearm's axis reaches the pelvis's or the abdomen's (radius 10-12 cm, forearm
#: 3-4 cm, clearance) and the nearest surface flips side; 9 cm left the CMU takes with a hand 8-13 cm
#: deep in the belly ghosted (24-29 mm of penetration, see docs/CLOTH.md).
MAX_PUSH = 0.14
_CHUNK = 24  # keys per batch in clear_limbs
_MIN_LEVER = 0.25  # a point at axis fraction s moves s times the moving end: pushes at s < 0.25 capped


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
    """
    depth, _ = _axis_depth(a[None], b[None], radii, limbs, trunk, np.linspace(0.0, 1.0, samples))
    out: F64 = depth[0].max(axis=1)
    return out


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
    d, nrm, _ = round_cone_np(pts.reshape(-1, 3), a[:, trunk].reshape(-1, 3), b[:, trunk].reshape(-1, 3),
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
                iterations: int = 4, samples: int = 9, backend: str = "numba") -> tuple[F64, F64]:
    """Capsule endpoints with every sunk forearm and hand turned out of the trunk.

    Each round takes the forearm, then the hand, of each side: the deepest sample ``s`` of the
    capsule's axis must move by ``p n`` (``p`` its depth plus the clearance, ``n`` the nearest trunk
    surface's outward normal). The capsule's ends move by the least-norm split of that,
    ``(1 - s) p n / D`` and ``s p n / D`` with ``D = (1 - s)^2 + s^2``; the near end (elbow, wrist)
    turns about its parent's pivot (shoulder, elbow) towards its target, the far end is carried
    with it and turns about it towards its own, every length kept. A moved wrist carries the hand.

    Parameters
    ----------
    a, b : (K, C, 3) or (C, 3) float64
        Capsule endpoints per key, metres (the arm chains: ``b[upper_arm] = a[forearm]``,
        ``b[forearm] = a[hand]``).
    radii : (C, 2) float64
    clearance : float
        Gap to leave between the limb's surface and the trunk's, metres.
    max_push : float
        A side whose forearm's deepest axis sample would have to move further than this (metres)
        is left as recorded (a hand alone over it: the hand), since a limb passing through the
        trunk has no continuous way out (the nearest surface flips side at the trunk's axis); the
        driver ghosts it instead.
    iterations : int
        Rounds per side (each clears the deepest axis sample of each capsule).
    samples : int
        Axis samples per capsule.
    backend : {"numba", "numpy"}
        The kernel or the plain numpy reference (same rule; a test holds them equal).

    Returns
    -------
    a, b : same shape as the input
        Copies; unchanged where no limb is within ``clearance`` of the trunk.
    """
    single = a.ndim == 2
    a2 = np.array(a[None] if single else a, dtype=np.float64)
    b2 = np.array(b[None] if single else b, dtype=np.float64)
    s = np.linspace(0.0, 1.0, samples)
    if backend == "numba":
        K.clear_limbs(a2, b2, np.ascontiguousarray(radii, dtype=np.float64), ARMS, TRUNK, s, clearance, max_push,
                      iterations)
    elif backend == "numpy":
        for k0 in range(0, len(a2), _CHUNK):  # _axis_depth costs K^2: chunks of keys
            ac, bc = a2[k0:k0 + _CHUNK], b2[k0:k0 + _CHUNK]  # views: corrected in place
            for chain in ARMS:
                # a side whose forearm cannot be cleared stays as recorded (the driver ghosts it)
                fore, _, _ = _deepest(ac, bc, radii, chain[1], clearance, s)
                side = fore <= max_push
                for _ in range(iterations):
                    moved = [_turn_out(ac, bc, radii, chain, i, clearance, max_push, s, side) for i in (1, 2)]
                    if not any(moved):
                        break
    else:
        raise ValueError(f"unknown backend {backend!r}")
    if single:
        return a2[0], b2[0]
    return a2, b2


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


def _turn_out(a: F64, b: F64, radii: F64, chain: NDArray[np.int64], i: int, clearance: float, max_push: float,
              s: F64, keys: NDArray[np.bool_]) -> bool:
    """One push of capsule ``chain[i]`` (1: forearm, 2: hand) for the ``keys`` that need it, in place;
    False when none did."""
    cap, parent = chain[i], chain[i - 1]
    push, n, sj = _deepest(a, b, radii, cap, clearance, s)
    m = keys & (push > 1e-6) & (push <= max_push)
    if not m.any():
        return False
    push, n, sj = push[m, None], n[m], sj[m, None]
    den = (1.0 - sj) ** 2 + sj**2
    near, far = a[m, cap], b[m, cap]  # copies (boolean index)
    l_near = np.linalg.norm(b[m, parent] - a[m, parent], axis=-1, keepdims=True)
    l_far = np.linalg.norm(far - near, axis=-1, keepdims=True)
    new_near = _unit_towards(a[m, parent], near + push * (1.0 - sj) / den * n, l_near, b[m, parent])
    new_far = _unit_towards(new_near, far + (new_near - near) + push * sj / den * n, l_far, far)
    b[m, parent] = new_near
    a[m, cap] = new_near
    b[m, cap] = new_far
    if i == 1:  # the hand rides the wrist
        b[m, chain[2]] += new_far - far
        a[m, chain[2]] = new_far
    return True
