"""The contract every process shares: skeleton, forward kinematics, messages, codec, Zenoh keys and
session configuration, motion files (BVH, gesture scripts)."""

from protocol.kinematics import fk, fk_global
from protocol.skeleton import (
    JOINT_NAMES,
    N_JOINTS,
    N_PARTS,
    PARENTS,
    PARTS,
    POSE_SIZE,
    ROT_JOINTS,
    Body,
    body_from_measurements,
    default_body,
    standing_pose,
)

__all__ = [
    "JOINT_NAMES",
    "N_JOINTS",
    "N_PARTS",
    "PARENTS",
    "PARTS",
    "POSE_SIZE",
    "ROT_JOINTS",
    "Body",
    "body_from_measurements",
    "default_body",
    "fk",
    "fk_global",
    "standing_pose",
]
