"""Knees kept apart: room for the skirt between the legs as they pass in a walk.

In a walk the swing leg's knee passes the stance leg's within millimetres; in many recordings the
capsule legs touch or overlap there by a few millimetres (``walk_normal_001`` at t = 2.17 s: the
left thigh and the right shin 1 mm into each other, the shins 2 mm apart). The skirt's front
hangs between the knees, and cloth caught between two legs that close on it and move in opposite
directions has no position outside both: each of two neighbouring particles sticks to a different
leg and the spring between them is torn to 2.3x its length for a frame (skirt ``walk_normal_001``
128 %, ``walk_not-confident_001`` 34 %, session 20; ``walk_feminine_001`` 267 % in another run).

:func:`clear_legs` turns each leg out about its hip joint, along the pelvis's left-right axis, by
half of what the gap between the two legs lacks of ``clearance`` (two cloth margins, as for the
arms: :data:`~cloth_client.limb_clearance.LIMB_CLEARANCE`), at most ``max_push`` per leg at the
closest point and ``max_toe`` at its toe. The gap
is the least distance between the two legs' surfaces below mid-thigh (thigh from half-way down,
shin; the thighs always meet at the crotch, where no cloth goes between them), each capsule's
radius taken linearly along its axis. A leg turns rigidly about the axis square to its thigh and
to the pelvis's left-right axis (abduction), by the angle that moves its knee by that half (the
closest point may be above or below the knee; a second round measures again); the knee, ankle and
toe turn with it (every length kept; the pelvis does not move). The angle depends only on the gap
(a minimum of continuous distances) and the bone lengths, so it grows continuously from zero as the
knees come within the clearance and is the same from key to key for the same pose: nothing needs
carrying.

A plain numpy module, vectorised over keys: ~0.1 ms for a step's keys, and no loop over
particles. The corrected capsules are the avatar, as for the arms: the cloth collides with them,
penetration is measured against them and the renderer draws them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import CAPSULE_INDEX

__all__ = ["LEGS", "LEG_CLEARANCE", "LEG_MAX_PUSH", "clear_legs", "leg_gap"]

F64 = NDArray[np.float64]

#: Thigh, shin and foot of each side (left, right): the chains :func:`clear_legs` turns.
LEGS = np.array([[CAPSULE_INDEX[f"{side}_{n}"] for n in ("thigh", "shin", "foot")] for side in "lr"])
#: Gap kept between the legs below mid-thigh, metres: two cloth margins, as for the arms.
LEG_CLEARANCE = 0.012
#: Largest turn-out per leg (metres at the knee, all iterations together) and of its toe.
#: Legs that overlap deeper keep the rest of their overlap (the capsule legs of a knees-together
#: stance overlap by up to 37 mm, `guide_feminine_001`; turned out in full their feet would spread
#: by 10 cm): 1 cm each leaves at most 17 mm of the recordings' overlaps below 5 cm, within
#: the 18 mm the crease rule lets cloth stay half-way through (``PINCH_DEPTH``).
LEG_MAX_PUSH = 0.01
LEG_MAX_TOE = 0.03
#: Fraction of the thigh from the hip above which the gap is not measured.
THIGH_FROM = 0.5
#: Axis samples per capsule for the gap.
GAP_SAMPLES = 9


def _samples(a: F64, b: F64, radii: F64, side: int, s: F64) -> tuple[F64, F64]:
    """Axis points ``(N, 2 S, 3)`` and radii ``(2 S,)`` of one leg's thigh (from ``THIGH_FROM``) and shin."""
    thigh, shin = LEGS[side, 0], LEGS[side, 1]
    st = THIGH_FROM + (1.0 - THIGH_FROM) * s
    pts = np.concatenate([a[:, thigh, None] + st[None, :, None] * (b[:, thigh, None] - a[:, thigh, None]),
                          a[:, shin, None] + s[None, :, None] * (b[:, shin, None] - a[:, shin, None])], axis=1)
    r = np.concatenate([(1.0 - st) * radii[thigh, 0] + st * radii[thigh, 1],
                        (1.0 - s) * radii[shin, 0] + s * radii[shin, 1]])
    return pts, r


def leg_gap(a: F64, b: F64, radii: F64, samples: int = GAP_SAMPLES) -> tuple[F64, F64, F64]:
    """Least surface gap between the legs below mid-thigh, per key.

    Parameters
    ----------
    a, b : (N, C, 3) float64
        Capsule endpoints of ``N`` keys.
    radii : (C, 2) float64
    samples : int
        Axis samples per capsule (thigh from ``THIGH_FROM``, shin).

    Returns
    -------
    gap : (N,) float64
        Metres; negative where the legs overlap.
    left, right : (N, 3) float64
        The closest axis samples of the left and the right leg.
    """
    s = np.linspace(0.0, 1.0, samples)
    pl, rl = _samples(a, b, radii, 0, s)
    pr, rr = _samples(a, b, radii, 1, s)
    d = np.linalg.norm(pl[:, :, None] - pr[:, None], axis=-1) - rl[None, :, None] - rr[None, None, :]
    flat = d.reshape(len(d), -1).argmin(axis=1)
    i, j = np.unravel_index(flat, d.shape[1:])
    k = np.arange(len(d))
    return d[k, i, j], pl[k, i], pr[k, j]


def clear_legs(a: F64, b: F64, radii: F64, clearance: float = LEG_CLEARANCE, max_push: float = LEG_MAX_PUSH,
               max_toe: float = LEG_MAX_TOE, iterations: int = 4) -> tuple[F64, F64]:
    """Capsule endpoints with the legs turned apart where their gap is under ``clearance``.

    Parameters
    ----------
    a, b : (N, C, 3) or (C, 3) float64
        Capsule endpoints (keys in any order: each is corrected on its own).
    radii : (C, 2) float64
    clearance : float
        Gap to leave between the legs below mid-thigh, metres.
    max_push, max_toe : float
        Largest move of a leg's knee and of its toe, metres, all iterations together.
    iterations : int
        Rounds of measuring the gap and turning the legs.

    Returns
    -------
    a, b : same shape as the input
        Copies; unchanged on keys whose legs are ``clearance`` apart.
    """
    one = np.ndim(a) == 2
    a2 = np.array(a[None] if one else a, dtype=np.float64)
    b2 = np.array(b[None] if one else b, dtype=np.float64)
    pelvis = CAPSULE_INDEX["pelvis"]  # its axis runs from the left hip joint to the right
    used = np.zeros((2, len(a2)))  # angle turned so far per leg, radians
    for _ in range(iterations):
        gap = leg_gap(a2, b2, radii)[0]
        want = np.maximum(0.5 * (clearance - gap), 0.0)  # per leg, metres at the knee
        if not np.any(want > 0.0):
            break
        lateral = a2[:, pelvis] - b2[:, pelvis]  # right hip -> left hip
        lateral /= np.maximum(np.linalg.norm(lateral, axis=-1, keepdims=True), 1e-12)
        for side, sign in ((0, 1.0), (1, -1.0)):
            thigh, _shin, foot = LEGS[side]
            hip = a2[:, thigh].copy()  # the thigh starts at the hip joint, which stays
            femur = b2[:, thigh] - hip
            knee = np.maximum(np.linalg.norm(femur, axis=-1), 1e-12)
            toe = np.maximum(np.linalg.norm(b2[:, foot] - hip, axis=-1), 1e-12)
            cap = np.minimum(max_push / knee, max_toe / toe)  # radians
            angle = np.minimum(want / knee, np.maximum(cap - used[side], 0.0))
            used[side] += angle
            axis = np.cross(femur, sign * lateral)  # turning about it takes the knee towards +-lateral
            norm = np.linalg.norm(axis, axis=-1, keepdims=True)
            moving = (angle > 0.0) & (norm[:, 0] > 1e-9)
            axis = axis / np.maximum(norm, 1e-12)
            for cap_index in LEGS[side]:
                for ends in (a2, b2):
                    turned = hip + _rotate(axis, angle, ends[:, cap_index] - hip)
                    ends[:, cap_index] = np.where(moving[:, None], turned, ends[:, cap_index])
    return (a2[0], b2[0]) if one else (a2, b2)


def _rotate(axis: F64, angle: F64, y: F64) -> F64:
    """``y (N, 3)`` turned by ``angle (N,)`` radians about unit ``axis (N, 3)`` (Rodrigues)."""
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    out: F64 = y * c + np.cross(axis, y) * s + axis * np.einsum("ni,ni->n", axis, y)[:, None] * (1.0 - c)
    return out
