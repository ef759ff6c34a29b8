"""Knees kept apart: room for the skirt between the legs as they pass in a walk.

In a walk the swing leg's knee passes the stance leg's within millimetres; in many recordings the
capsule legs touch or overlap there by a few millimetres (``walk_normal_001`` at t = 2.17 s: the
left thigh and the right shin 1 mm into each other, the shins 2 mm apart). The skirt's front
hangs between the knees, and cloth caught between two legs that close on it and move in opposite
directions has no position outside both: each of two neighbouring particles sticks to a different
leg and the spring between them is torn to 2.3x its length for a frame (skirt ``walk_normal_001``
128 %, ``walk_not-confident_001`` 34 %; ``walk_feminine_001`` 267 % in another run).

:func:`clear_legs` turns each leg out about its hip joint, along the pelvis's left-right axis, by
half of what the gap between the two legs lacks of ``clearance`` (two cloth margins, as for the
arms: :data:`~cloth_client.avatar.limb_clearance.LIMB_CLEARANCE`), at most ``max_push`` per leg at the
knee and ``max_toe`` at its toe. "Apart" is the way the legs' closest points lie along that axis:
left and right as usual, the other way round for legs crossed in a cross-step (blended over
:data:`CROSS_BLEND` where the closest points are level). The gap
is the least distance between the two legs' surfaces below mid-thigh (thigh from half-way down,
shin; the thighs always meet at the crotch, where no cloth goes between them), each capsule's
radius taken linearly along its axis. A leg turns rigidly about the axis square to its thigh and
to the pelvis's left-right axis (abduction), by the angle that moves its knee by that half (the
closest point may be above or below the knee, and knees that pass at an angle open the gap by
less than they move: up to four rounds measure again and scale the next move by the gap the last
one opened, until a key lacks less than :data:`LEG_TOLERANCE`; a round that closed the gap instead
is undone, so the rule never makes an overlap worse); the knee, ankle and
toe turn with it (every length kept; the pelvis does not move). The angle depends only on the gap
(a minimum of continuous distances), the bone lengths and the side, so it grows continuously from
zero as the knees come within the clearance (to within the tolerance) and is the same from key to
key for the same pose: nothing needs carrying.

A plain numpy module, vectorised over keys and run only on the keys that need it: 0.2 ms for a
step's five keys when the legs are apart, 1.7-2 ms when knees 5 mm apart need three rounds (11 % of
the recordings' frames have legs closer than the clearance); no loop over particles. The
corrected capsules are the avatar, as for the arms: the cloth collides with them,
penetration is measured against them and the renderer draws them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from protocol.rotations import rotvec_to_matrix
from protocol.skeleton import CAPSULE_INDEX

__all__ = ["CROSS_BLEND", "LEGS", "LEG_CLEARANCE", "LEG_MAX_PUSH", "LEG_MAX_TOE", "LEG_TOLERANCE", "clear_legs",
           "leg_gap"]

F64 = NDArray[np.float64]

#: Thigh, shin and foot of each side (left, right): the chains :func:`clear_legs` turns.
LEGS = np.array([[CAPSULE_INDEX[f"{side}_{n}"] for n in ("thigh", "shin", "foot")] for side in "lr"])
#: Gap kept between the legs below mid-thigh, metres: two cloth margins, as for the arms.
LEG_CLEARANCE = 0.012
#: Largest turn-out per leg (metres at the knee, all iterations together) and of its toe.
#: Legs that overlap deeper keep the rest of their overlap (the capsule legs of a knees-together
#: stance overlap by up to 37 mm, `guide_feminine_001`; turned out in full their feet would spread
#: by 10 cm). With 1 cm each such a stance keeps up to 26 mm (`guide_feminine_001` 36.6 -> 25.8
#: mm), where the crease rule lets cloth stay half-way through (``PINCH_DEPTH``, 9 mm each side).
LEG_MAX_PUSH = 0.01
LEG_MAX_TOE = 0.03
#: Deficit (metres per leg at the knee) below which a key is left as it is: the rounds stop there.
LEG_TOLERANCE = 2.5e-4
#: Lateral offset (metres) between the legs' closest points over which "apart" turns from left /
#: right to the crossed way round: legs crossed in a cross-step are turned further apart the way
#: they are crossed, not into each other.
CROSS_BLEND = 0.005
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
    active = np.arange(len(a2))
    gain = np.ones(len(a2))  # gap opened per metre of knee move and leg, measured from the last round
    last_gap, last_move = np.zeros(len(a2)), np.zeros(len(a2))
    saved_a, saved_b = a2.copy(), b2.copy()
    for it in range(iterations + 1):
        gap, near_l, near_r = leg_gap(a2[active], b2[active], radii)
        if it:
            # a round that closed the gap (legs so deeply crossed that their closest points swap
            # sides) is undone and the key left there: the rule never makes an overlap worse
            worse = gap < last_gap[active] - 1e-9
            back = active[worse]
            a2[back], b2[back] = saved_a[back], saved_b[back]
            active, gap, near_l, near_r = active[~worse], gap[~worse], near_l[~worse], near_r[~worse]
            # a secant step: the gap opens by less than the knees move where they pass at an angle
            moved = last_move[active] > 1e-9
            opened = (gap - last_gap[active]) / np.maximum(2.0 * last_move[active], 1e-12)
            gain[active] = np.where(moved, np.clip(opened, 0.2, 1.0), gain[active])
        if it == iterations:
            break
        want = 0.5 * (clearance - gap)  # per leg, metres of gap
        keep = want > LEG_TOLERANCE
        active, gap, want, near_l, near_r = active[keep], gap[keep], want[keep], near_l[keep], near_r[keep]
        if not len(active):
            break
        last_gap[active] = gap
        saved_a[active], saved_b[active] = a2[active], b2[active]
        want = want / gain[active]  # metres at the knee
        lateral = a2[active, pelvis] - b2[active, pelvis]  # right hip -> left hip
        lateral /= np.maximum(np.linalg.norm(lateral, axis=-1, keepdims=True), 1e-12)
        # which way is apart: the left leg's closest point left of the right leg's (+1), or the
        # legs crossed (-1), blended over CROSS_BLEND so that the turn stays continuous
        side_of = np.clip(np.einsum("ni,ni->n", near_l - near_r, lateral) / CROSS_BLEND, -1.0, 1.0)
        for side, sign in ((0, 1.0), (1, -1.0)):
            thigh, _shin, foot = LEGS[side]
            hip = a2[active, thigh]  # the thigh starts at the hip joint, which stays
            femur = b2[active, thigh] - hip
            knee = np.maximum(np.linalg.norm(femur, axis=-1), 1e-12)
            toe = np.maximum(np.linalg.norm(b2[active, foot] - hip, axis=-1), 1e-12)
            cap = np.minimum(max_push / knee, max_toe / toe)  # radians
            angle = np.minimum(want * np.abs(side_of) / knee, np.maximum(cap - used[side, active], 0.0))
            used[side, active] += angle
            if side == 0:
                last_move[active] = angle * knee
            axis = np.cross(femur, (sign * side_of)[:, None] * lateral)  # the knee turns towards +-lateral
            norm = np.linalg.norm(axis, axis=-1, keepdims=True)
            angle = np.where(norm[:, 0] > 1e-9, angle, 0.0)
            axis = axis / np.maximum(norm, 1e-12)
            ends = np.concatenate([a2[active][:, LEGS[side]], b2[active][:, LEGS[side]]], axis=1)  # (m, 6, 3)
            turn = rotvec_to_matrix(axis * angle[:, None])  # (m, 3, 3)
            turned = hip[:, None] + np.einsum("nij,nkj->nki", turn, ends - hip[:, None])
            a2[active[:, None], LEGS[side][None, :]] = turned[:, :3]
            b2[active[:, None], LEGS[side][None, :]] = turned[:, 3:]
    return (a2[0], b2[0]) if one else (a2, b2)
