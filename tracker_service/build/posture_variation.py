"""Posture variation of the appearance network's training poses: a stoop and bent knees.

The tracker's worst held-out takes are postures the training recordings hold few of: the stooped
``bye_tired`` (trunk 20 degrees forward, knees bent; within 10 cm on 0.04-0.18 of its frames
without posture variation), the punch's deep lunge, the old and tired styles. The network reads them as a
straighter person (the trunk 8 degrees too upright, the feet 12-15 cm off in depth), and the
refinement follows it. Varying the recordings' own poses shows the network more of those postures
without new recordings:

* **trunk flexion**: the spine and chest turn forward about their parents' left-right axis
  (``+X`` in :mod:`protocol.skeleton`), 0.6 and 0.4 of an angle drawn up to ``trunk_deg``;
* **bent knees**: each knee flexes (``+X``) by up to ``knee_deg`` (the other leg by 0.6-1.0 of it),
  its hip flexes forward (``-X``) by half of it and the ankle by half of it back, so the thigh leans
  forward and the foot stays flat, as in a squat;
* the limits of :data:`protocol.skeleton.LIMITS_DEG` are kept (on the turned joints; the others
  are left as recorded), and the root is lowered so that the lowest foot joint stays where it was
  on the motion's own skeleton (the person stays on the floor; a synthetic person of another size
  may float or sink by a centimetre or two).

Arms, head and the root's orientation are left as recorded: the variation adds postures around the
recorded motions instead of inventing new ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from protocol.kinematics import fk
from protocol.rotations import matrix_to_rotvec, rotvec_to_matrix
from protocol.skeleton import JOINT_INDEX, POSE_SIZE, ROT_JOINTS, Body, clamp_pose

__all__ = ["POSTURE_VERSION", "PostureParams", "vary_posture"]

#: Bumped whenever :func:`vary_posture` changes what it draws: cached renders are named with it.
POSTURE_VERSION = 1

_FEET = np.array([JOINT_INDEX[j] for j in ("l_ankle", "r_ankle", "l_toe", "r_toe")])
_SLOT = {name: ROT_JOINTS.index(name) for name in ("spine", "chest", "l_hip", "l_knee", "l_ankle", "r_hip",
                                                    "r_knee", "r_ankle")}


@dataclass(frozen=True)
class PostureParams:
    """How the training poses are varied.

    Attributes
    ----------
    share : float
        Fraction of the frames varied, in [0, 1].
    trunk_deg : float
        Largest trunk flexion (degrees), drawn uniformly from 0.
    knee_deg : float
        Largest knee flexion (degrees), drawn uniformly from 0.
    """

    share: float = 0.5
    trunk_deg: float = 25.0
    knee_deg: float = 70.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.share <= 1.0:
            raise ValueError(f"share must be in [0, 1], got {self.share}")
        if not (0.0 <= self.trunk_deg <= 80.0 and 0.0 <= self.knee_deg <= 150.0):
            raise ValueError(f"trunk_deg must be in [0, 80] and knee_deg in [0, 150], got {self.trunk_deg}, "
                             f"{self.knee_deg}")


def vary_posture(poses: NDArray[np.float64], body: Body, rng: np.random.Generator,
                 params: PostureParams = PostureParams()) -> NDArray[np.float64]:
    """Stoop and bend the knees of a random share of the frames (see the module docstring).

    Parameters
    ----------
    poses : (F, P) float64
        Pose vectors (:mod:`protocol.skeleton` layout).
    body : Body
        The skeleton the poses are played on (to keep the feet on the floor).
    rng : numpy.random.Generator
    params : PostureParams

    Returns
    -------
    (F, P) float64
        A new array: the chosen frames varied, the others unchanged.
    """
    poses = np.array(poses, np.float64, copy=True)
    if poses.ndim != 2 or poses.shape[1] != POSE_SIZE:
        raise ValueError(f"poses must have shape (F, {POSE_SIZE}), got {poses.shape}")
    pick = np.flatnonzero(rng.random(len(poses)) < params.share)
    if not len(pick):
        return poses
    n = len(pick)
    trunk = np.radians(rng.uniform(0.0, params.trunk_deg, n))
    knee = np.radians(rng.uniform(0.0, params.knee_deg, n))
    sides = rng.uniform(0.6, 1.0, (n, 2))
    sides[np.arange(n), rng.integers(0, 2, n)] = 1.0  # one leg bends the full angle
    turns = {"spine": 0.6 * trunk, "chest": 0.4 * trunk}
    for k, side in enumerate("lr"):
        bend = knee * sides[:, k]
        turns |= {f"{side}_knee": bend, f"{side}_hip": -0.5 * bend, f"{side}_ankle": -0.5 * bend}
    slots = np.array([_SLOT[name] for name in turns])
    cols = (3 + 3 * slots[:, None] + np.arange(3)).ravel()  # only the turned joints are touched
    new = poses[pick].copy()
    about_x = np.stack(list(turns.values()), axis=1)[..., None] * np.array([1.0, 0.0, 0.0])  # (n, m, 3)
    # about the parent's left-right axis: the turn first, then the recorded rotation
    rot = rotvec_to_matrix(about_x) @ rotvec_to_matrix(new[:, cols].reshape(n, -1, 3))
    new[:, cols] = matrix_to_rotvec(rot).reshape(n, -1)
    new[:, cols] = clamp_pose(new)[:, cols]  # the rest stay as recorded, bit for bit
    new[:, 1] += fk(poses[pick], body)[:, _FEET, 1].min(axis=1) - fk(new, body)[:, _FEET, 1].min(axis=1)
    poses[pick] = new
    return poses
