"""Floor contact: a published foot never goes through the floor.

The silhouette ends where the feet stand, and the root is placed from it (the feet line and the
templates' scale, :mod:`tracker_service.silhouette.placement`); the appearance network's reading
then turns the joints (:mod:`tracker_service.pipeline.refinement`) and is pelvis-relative. Where the
reading straightens a leg the silhouette shows bent (a deep crouch, which the network reads with
the ankles too low), the ankle ends up below the floor with the pelvis at the right height. The
floor is evidence the reading does not have, so the leg is bent back onto it:

1. The ankle's floor level is its height standing straight with the foot flat
   (``Body.standing_root_height`` down the thigh and shin). An ankle more than ``tolerance_m``
   below it is raised to that depth below the floor level; the hip stays where it is.
2. Analytic two-bone inverse kinematics: the knee flexes about its own hinge (its local ``x`` axis
   in the hip's frame) until the hip-to-ankle distance is the one the raised ankle needs, then the
   hip swings the leg (the smallest rotation) onto the raised ankle. The foot keeps its
   orientation in the world (flat stays flat).

A pose whose pelvis is near the floor (lying, sitting on it) is left as it is: there the floor
says nothing about the knees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from protocol.rotations import axis_rotation, matrix_to_rotvec, rotvec_to_matrix
from protocol.skeleton import JOINT_INDEX, LIMITS_DEG, PARENTS, POSE_SIZE, ROT_SLOT, Body
from tracker_service.body.kinematics import fk_global
from tracker_service.pipeline.refinement import swing_rotation

__all__ = ["FloorParams", "ankle_floor_height", "floor_contact"]

_LEGS = tuple(tuple(JOINT_INDEX[f"{s}_{n}"] for n in ("hip", "knee", "ankle")) for s in "lr")
_KNEE_MAX = float(np.radians(LIMITS_DEG["l_knee"][0][1]))


@dataclass(frozen=True)
class FloorParams:
    """How far a published ankle may sink below its floor level.

    Attributes
    ----------
    tolerance_m : float
        Depth below the ankle's floor level left as it is (the silhouette's own noise, soft
        shoes); deeper, the ankle is raised to this depth.
    min_hip_clearance_m : float
        The floor constrains a leg only while its hip is at least this far above the ankle's floor
        level.
    """

    tolerance_m: float = 0.02
    min_hip_clearance_m: float = 0.25

    def __post_init__(self) -> None:
        for name in ("tolerance_m", "min_hip_clearance_m"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v}")


def ankle_floor_height(body: Body) -> float:
    """Height (metres) of ``body``'s ankle joint above the floor standing straight, foot flat."""
    j = JOINT_INDEX
    return float(body.standing_root_height() + body.offsets[j["l_knee"], 1] + body.offsets[j["l_ankle"], 1])


def _flex_for_distance(u: NDArray[np.float64], w: NDArray[np.float64], dist: float, lo: float,
                       hi: float) -> float:
    """The extra knee flexion ``t`` in ``[lo, hi]`` with ``|u + Rx(t) w|`` closest to ``dist``.

    ``|u + Rx(t) w|^2 = |u|^2 + |w|^2 + 2 u . Rx(t) w`` and ``u . Rx(t) w = A cos t + B sin t + C``
    with ``A = u_y w_y + u_z w_z``, ``B = u_z w_y - u_y w_z``, ``C = u_x w_x``: a sinusoid of ``t``.
    """
    a = u[1] * w[1] + u[2] * w[2]
    b = u[2] * w[1] - u[1] * w[2]
    c = u[0] * w[0]
    want = 0.5 * (dist * dist - u @ u - w @ w) - c  # = R cos(t - phi)
    r = float(np.hypot(a, b))
    if r < 1e-12:
        return 0.0
    phi = float(np.arctan2(b, a))
    base = float(np.arccos(np.clip(want / r, -1.0, 1.0)))
    cands = [float(np.clip((t + np.pi) % (2 * np.pi) - np.pi, lo, hi)) for t in (phi + base, phi - base)]
    return min(cands, key=lambda t: abs(r * np.cos(t - phi) - want))


def floor_contact(pose: NDArray[np.float64], body: Body, params: FloorParams) -> NDArray[np.float64]:
    """Bend each leg whose ankle is below the floor back onto it (see the module docstring).

    Parameters
    ----------
    pose : (P,) float64
        World pose (layout of :mod:`protocol.skeleton`), floor at ``y = 0``.
    body : Body
        The skeleton it is published with.
    params : FloorParams

    Returns
    -------
    (P,) float64
        A new pose: the root and the hips' positions unchanged, the legs that went through the
        floor bent onto it.
    """
    pose = np.asarray(pose, np.float64)
    if pose.shape != (POSE_SIZE,):
        raise ValueError(f"pose must have shape ({POSE_SIZE},), got {pose.shape}")
    out = pose.copy()
    if not np.isfinite(pose).all():
        return out
    level = ankle_floor_height(body)
    pos, glob = fk_global(pose, body)
    for hip, knee, ankle in _LEGS:
        target_y = level - params.tolerance_m
        if pos[ankle, 1] >= target_y or pos[hip, 1] < level + params.min_hip_clearance_m:
            continue
        target = pos[ankle].copy()
        target[1] = target_y
        g_hip, g_pelvis = glob[hip], glob[PARENTS[hip]]
        k_local = rotvec_to_matrix(pose[3 + 3 * ROT_SLOT[knee]: 6 + 3 * ROT_SLOT[knee]])
        u = body.offsets[knee]  # the thigh in the hip's frame
        w = k_local @ body.offsets[ankle]  # the shin in the hip's frame
        dist = float(np.linalg.norm(target - pos[hip]))
        # the knee's flexion so far (about +x), and how much more it may bend
        flex_now = float(np.arctan2(-w[2], -w[1]))
        t = _flex_for_distance(u, w, dist, -max(flex_now, 0.0), max(_KNEE_MAX - flex_now, 0.0))
        k_new = axis_rotation("X", t) @ k_local
        reach = g_hip @ (u + k_new @ body.offsets[ankle])  # hip -> ankle, world, before the swing
        g_hip_new = swing_rotation(reach, target - pos[hip]) @ g_hip
        g_knee_new = g_hip_new @ k_new
        out[3 + 3 * ROT_SLOT[hip]: 6 + 3 * ROT_SLOT[hip]] = matrix_to_rotvec(g_pelvis.T @ g_hip_new)
        out[3 + 3 * ROT_SLOT[knee]: 6 + 3 * ROT_SLOT[knee]] = matrix_to_rotvec(k_new)
        # the foot keeps its world orientation
        out[3 + 3 * ROT_SLOT[ankle]: 6 + 3 * ROT_SLOT[ankle]] = matrix_to_rotvec(g_knee_new.T @ glob[ankle])
    return out
