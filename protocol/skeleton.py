"""The body skeleton every process shares: joints, parent tree, rest offsets, pose-vector layout,
joint limits, body parts and capsules.

Axes and units
--------------
World and body frames are right-handed, **Y up**, metres, seconds, radians. In the rest pose the
body stands upright facing **+Z**, arms straight out to the sides (a T-pose); the subject's left
is **+X**. A camera in front of the subject looks along -Z.

Pose vector
-----------
``pose (P,) float``, ``P = 3 + 3 * len(ROT_JOINTS) = 60``::

    pose[0:3]          root (pelvis = mid-point of the two hip joints) position in the world, metres
    pose[3:6]          root orientation, rotation vector (axis * angle, radians), body -> world
    pose[6+3k:9+3k]    local rotation of ROT_JOINTS[k+1] relative to its parent, rotation vector

A local rotation turns the joint's rest frame (parallel to the world axes in the T-pose); the
identity everywhere is the T-pose. Examples: left elbow flexion is a rotation about -Y, right elbow
flexion about +Y, knee flexion about +X, lowering the left arm to the side about -Z.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "CAPSULES",
    "CAPSULE_OWNER",
    "END_JOINTS",
    "JOINT_INDEX",
    "JOINT_NAMES",
    "LIMITS_DEG",
    "MIRROR_JOINTS",
    "N_CAPSULES",
    "N_JOINTS",
    "N_PARTS",
    "PARENTS",
    "PARTS",
    "POSE_SIZE",
    "ROT_JOINTS",
    "Body",
    "body_from_measurements",
    "clamp_pose",
    "default_body",
    "limit_violation_deg",
    "mirror_pose",
    "rest_pose",
    "standing_pose",
]

JOINT_NAMES: Final[tuple[str, ...]] = (
    "pelvis", "spine", "chest", "neck", "head", "head_top",
    "l_clavicle", "l_shoulder", "l_elbow", "l_wrist", "l_hand_tip",
    "r_clavicle", "r_shoulder", "r_elbow", "r_wrist", "r_hand_tip",
    "l_hip", "l_knee", "l_ankle", "l_toe",
    "r_hip", "r_knee", "r_ankle", "r_toe",
)
N_JOINTS: Final[int] = len(JOINT_NAMES)
JOINT_INDEX: Final[dict[str, int]] = {n: i for i, n in enumerate(JOINT_NAMES)}

_PARENT_NAMES: Final[dict[str, str | None]] = {
    "pelvis": None, "spine": "pelvis", "chest": "spine", "neck": "chest", "head": "neck",
    "head_top": "head",
    "l_clavicle": "chest", "l_shoulder": "l_clavicle", "l_elbow": "l_shoulder", "l_wrist": "l_elbow",
    "l_hand_tip": "l_wrist",
    "r_clavicle": "chest", "r_shoulder": "r_clavicle", "r_elbow": "r_shoulder", "r_wrist": "r_elbow",
    "r_hand_tip": "r_wrist",
    "l_hip": "pelvis", "l_knee": "l_hip", "l_ankle": "l_knee", "l_toe": "l_ankle",
    "r_hip": "pelvis", "r_knee": "r_hip", "r_ankle": "r_knee", "r_toe": "r_ankle",
}
PARENTS: Final[tuple[int, ...]] = tuple(
    -1 if _PARENT_NAMES[n] is None else JOINT_INDEX[_PARENT_NAMES[n]]  # type: ignore[index]
    for n in JOINT_NAMES
)
#: Joints without a rotation of their own (end effectors).
END_JOINTS: Final[tuple[str, ...]] = ("head_top", "l_hand_tip", "r_hand_tip", "l_toe", "r_toe")
#: Joints that carry a rotation in the pose vector, root first.
ROT_JOINTS: Final[tuple[str, ...]] = tuple(n for n in JOINT_NAMES if n not in END_JOINTS)
POSE_SIZE: Final[int] = 3 + 3 * len(ROT_JOINTS)
#: Index of each joint's rotation slot in ``pose[3:].reshape(-1, 3)``, or -1 for end joints.
ROT_SLOT: Final[tuple[int, ...]] = tuple(
    ROT_JOINTS.index(n) if n in ROT_JOINTS else -1 for n in JOINT_NAMES
)
#: Left/right counterpart of every joint (itself on the midline).
MIRROR_JOINTS: Final[tuple[int, ...]] = tuple(
    JOINT_INDEX["r_" + n[2:]] if n.startswith("l_") else JOINT_INDEX["l_" + n[2:]] if n.startswith("r_")
    else JOINT_INDEX[n]
    for n in JOINT_NAMES
)

#: Body parts used for visibility / occlusion (eq. 14) and the 15 silhouette parts.
PARTS: Final[tuple[str, ...]] = (
    "pelvis", "torso", "head",
    "l_upper_arm", "l_forearm", "l_hand", "r_upper_arm", "r_forearm", "r_hand",
    "l_thigh", "l_shin", "l_foot", "r_thigh", "r_shin", "r_foot",
)
N_PARTS: Final[int] = len(PARTS)

#: Capsules ``(name, part, joint_a, joint_b)``; radii live in :class:`Body` (``capsule_radii``).
CAPSULES: Final[tuple[tuple[str, str, str, str], ...]] = (
    ("pelvis", "pelvis", "l_hip", "r_hip"),
    ("abdomen", "torso", "pelvis", "chest"),
    ("thorax", "torso", "chest", "neck"),
    ("shoulders", "torso", "l_shoulder", "r_shoulder"),
    ("neck", "head", "neck", "head"),
    ("skull", "head", "head", "head_top"),
    ("l_upper_arm", "l_upper_arm", "l_shoulder", "l_elbow"),
    ("l_forearm", "l_forearm", "l_elbow", "l_wrist"),
    ("l_hand", "l_hand", "l_wrist", "l_hand_tip"),
    ("r_upper_arm", "r_upper_arm", "r_shoulder", "r_elbow"),
    ("r_forearm", "r_forearm", "r_elbow", "r_wrist"),
    ("r_hand", "r_hand", "r_wrist", "r_hand_tip"),
    ("l_thigh", "l_thigh", "l_hip", "l_knee"),
    ("l_shin", "l_shin", "l_knee", "l_ankle"),
    ("l_foot", "l_foot", "l_ankle", "l_toe"),
    ("r_thigh", "r_thigh", "r_hip", "r_knee"),
    ("r_shin", "r_shin", "r_knee", "r_ankle"),
    ("r_foot", "r_foot", "r_ankle", "r_toe"),
)
N_CAPSULES: Final[int] = len(CAPSULES)
CAPSULE_INDEX: Final[dict[str, int]] = {c[0]: i for i, c in enumerate(CAPSULES)}
CAPSULE_JOINTS: Final[NDArray[np.int64]] = np.array(
    [[JOINT_INDEX[a], JOINT_INDEX[b]] for _, _, a, b in CAPSULES], dtype=np.int64
)
CAPSULE_PART: Final[NDArray[np.int64]] = np.array([PARTS.index(p) for _, p, _, _ in CAPSULES], dtype=np.int64)


def _ancestors(j: int) -> list[int]:
    out = [j]
    while PARENTS[out[-1]] >= 0:
        out.append(PARENTS[out[-1]])
    return out


#: The joint whose frame carries each capsule: the deepest common ancestor of its two ends (the
#: first end for a bone; the chest for the shoulders' bar, the pelvis for the hips').
CAPSULE_OWNER: Final[NDArray[np.int64]] = np.array(
    [next(j for j in _ancestors(int(a)) if j in _ancestors(int(b))) for a, b in CAPSULE_JOINTS], dtype=np.int64)

#: Joint limits, degrees, on the rotation-vector components (x, y, z) of each left/midline joint;
#: right joints mirror them (x kept, y and z negated). The root is unlimited.
LIMITS_DEG: Final[dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]]] = {
    "spine": ((-45, 80), (-50, 50), (-45, 45)),
    "chest": ((-45, 70), (-50, 50), (-45, 45)),
    "neck": ((-60, 70), (-70, 70), (-50, 50)),
    "head": ((-70, 70), (-90, 90), (-50, 50)),
    "l_clavicle": ((-40, 40), (-45, 45), (-30, 50)),
    "l_shoulder": ((-135, 135), (-150, 100), (-135, 135)),
    "l_elbow": ((-100, 100), (-170, 10), (-30, 30)),
    "l_wrist": ((-100, 100), (-90, 90), (-60, 60)),
    "l_hip": ((-140, 50), (-70, 70), (-45, 90)),
    "l_knee": ((-10, 170), (-45, 45), (-30, 30)),
    "l_ankle": ((-70, 70), (-50, 50), (-50, 50)),
}


def _limit_arrays() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    lo = np.full((len(ROT_JOINTS), 3), -np.inf)
    hi = np.full((len(ROT_JOINTS), 3), np.inf)
    for k, name in enumerate(ROT_JOINTS):
        if name == "pelvis":
            continue
        if name.startswith("r_"):
            (x0, x1), (y0, y1), (z0, z1) = LIMITS_DEG["l_" + name[2:]]
            lim = ((x0, x1), (-y1, -y0), (-z1, -z0))
        else:
            lim = LIMITS_DEG[name]
        lo[k] = np.radians([a for a, _ in lim])
        hi[k] = np.radians([b for _, b in lim])
    return lo, hi


LIMIT_LO, LIMIT_HI = _limit_arrays()


@dataclass(frozen=True)
class Body:
    """A sized skeleton: rest offsets and capsule radii.

    Attributes
    ----------
    name : str
        Model name (e.g. ``"mMA"`` or ``"default"``).
    offsets : (J, 3) float64
        Rest-pose (T-pose) offset of each joint from its parent, in the parent's frame, metres.
        Row 0 (the root) is zero.
    capsule_radii : (C, 2) float64
        Radius at ``joint_a`` and ``joint_b`` of each entry of :data:`CAPSULES`, metres.
    measurements : dict[str, float]
        Named body measurements (``height_m``, ``chest_m``, ``waist_m``, ``hip_m``, ``weight_kg``, ...).
    """

    name: str
    offsets: NDArray[np.float64]
    capsule_radii: NDArray[np.float64]
    measurements: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        off = np.asarray(self.offsets, dtype=np.float64)
        rad = np.asarray(self.capsule_radii, dtype=np.float64)
        if off.shape != (N_JOINTS, 3):
            raise ValueError(f"offsets must be ({N_JOINTS}, 3), got {off.shape}")
        if rad.shape != (N_CAPSULES, 2):
            raise ValueError(f"capsule_radii must be ({N_CAPSULES}, 2), got {rad.shape}")
        if not (np.all(np.isfinite(off)) and np.all(np.isfinite(rad)) and np.all(rad > 0)):
            raise ValueError("offsets must be finite and capsule radii finite and positive")
        off.setflags(write=False)
        rad.setflags(write=False)
        object.__setattr__(self, "offsets", off)
        object.__setattr__(self, "capsule_radii", rad)

    @property
    def bone_lengths(self) -> NDArray[np.float64]:
        """(J,) float64: length of the bone from each joint's parent to the joint (0 for the root)."""
        return np.linalg.norm(self.offsets, axis=1)

    @property
    def height(self) -> float:
        """Standing height in metres (measured, else from the rest skeleton)."""
        if "height_m" in self.measurements:
            return float(self.measurements["height_m"])
        return float(self.standing_root_height() + self.offsets[1:6, 1].sum())

    @property
    def leg_length(self) -> float:
        """Hip joint to ankle along the bones, metres (mean of both legs)."""
        bl = self.bone_lengths
        j = JOINT_INDEX
        return float(0.5 * (bl[j["l_knee"]] + bl[j["l_ankle"]] + bl[j["r_knee"]] + bl[j["r_ankle"]]))

    def standing_root_height(self) -> float:
        """Height of the pelvis above the floor when standing straight (feet flat), metres."""
        j = JOINT_INDEX
        toe_drop = -self.offsets[j["l_toe"], 1]
        foot_r = self.capsule_radii[CAPSULE_INDEX["l_foot"], 1]
        return float(-self.offsets[j["l_knee"], 1] - self.offsets[j["l_ankle"], 1] + toe_drop + foot_r)


def body_from_measurements(
    height_m: float = 1.70,
    *,
    chest_m: float | None = None,
    waist_m: float | None = None,
    hip_m: float | None = None,
    weight_kg: float | None = None,
    shoulder_width_m: float | None = None,
    arm_ratio: float = 1.0,
    leg_ratio: float = 1.0,
    name: str = "custom",
) -> Body:
    """Build a :class:`Body` from a few measurements using standard anthropometric proportions.

    Segment lengths are fractions of stature after Drillis & Contini (1966) as tabulated by
    Winter, *Biomechanics and Motor Control of Human Movement* (4th ed., Fig. 4.1); girths default
    to adult averages scaled with height and are replaced by the given chest/waist/hip girths.

    Parameters
    ----------
    height_m : float
        Standing height, metres (0.8 to 2.3).
    chest_m, waist_m, hip_m : float, optional
        Girths (circumferences), metres.
    weight_kg : float, optional
        Used only to thicken or thin the limbs relative to the height's average (BMI 22).
    shoulder_width_m : float, optional
        Distance between the two shoulder joint centres.
    arm_ratio, leg_ratio : float
        Multipliers on arm and leg segment lengths (individual proportions).
    name : str
        Model name carried into ``BodyInfo``.

    Returns
    -------
    Body
    """
    h = float(height_m)
    if not 0.8 <= h <= 2.3:
        raise ValueError(f"height {h} m outside the supported 0.8-2.3 m")
    chest = chest_m if chest_m is not None else 0.52 * h
    waist = waist_m if waist_m is not None else 0.45 * h
    hip = hip_m if hip_m is not None else 0.54 * h
    bmi = (weight_kg / h**2) if weight_kg is not None else 22.0
    limb = float(np.clip(np.sqrt(bmi / 22.0), 0.75, 1.4))  # limb girth factor
    sw = shoulder_width_m if shoulder_width_m is not None else 0.21 * h
    thigh, shin = 0.245 * h * leg_ratio, 0.246 * h * leg_ratio
    upper, fore, hand = 0.186 * h * arm_ratio, 0.146 * h * arm_ratio, 0.108 * h * arm_ratio
    clav_in = 0.015 * h
    clav_len = max(sw / 2.0 - clav_in, 0.02)
    hip_half = 0.05 * h
    # torso: pelvis -> spine -> chest -> neck base; pelvis sits at ~0.52 h, neck base at ~0.83 h
    pelvis_h = thigh + shin + 0.039 * h
    neck_h = 0.83 * h
    torso = neck_h - pelvis_h
    spine_l, chest_l, neck_l = 0.21 * torso, 0.36 * torso, 0.43 * torso
    off = {
        "pelvis": (0, 0, 0),
        "spine": (0, spine_l, 0), "chest": (0, chest_l, 0), "neck": (0, neck_l, 0),
        "head": (0, 0.055 * h, 0), "head_top": (0, 0.115 * h - 0.048 * h, 0),  # skull capsule top at h
        "l_clavicle": (clav_in, neck_l - 0.025 * h, 0), "l_shoulder": (clav_len, 0, 0),
        "l_elbow": (upper, 0, 0), "l_wrist": (fore, 0, 0), "l_hand_tip": (hand, 0, 0),
        "l_hip": (hip_half, 0, 0), "l_knee": (0, -thigh, 0), "l_ankle": (0, -shin, 0),
        "l_toe": (0, -0.03 * h, 0.075 * h),
    }
    offsets = np.zeros((N_JOINTS, 3))
    for n, v in off.items():
        offsets[JOINT_INDEX[n]] = v
        if n.startswith("l_"):
            offsets[JOINT_INDEX["r_" + n[2:]]] = (-v[0], v[1], v[2])
    # capsule radii from girths (circumference / 2 pi), limbs scaled with height and weight
    def r_of(girth: float) -> float:
        return girth / (2 * np.pi)

    rad = {
        "pelvis": (0.75 * r_of(hip), 0.75 * r_of(hip)),
        "abdomen": (0.8 * r_of(waist), 0.85 * r_of(chest)),
        "thorax": (0.85 * r_of(chest), 0.55 * r_of(chest)),
        "shoulders": (0.045 * h * limb, 0.045 * h * limb),
        "neck": (0.032 * h, 0.030 * h),
        "skull": (0.050 * h, 0.048 * h),
        "l_upper_arm": (0.029 * h * limb, 0.023 * h * limb),
        "l_forearm": (0.022 * h * limb, 0.016 * h * limb),
        "l_hand": (0.017 * h, 0.012 * h),
        "l_thigh": (0.052 * h * limb, 0.033 * h * limb),
        "l_shin": (0.031 * h * limb, 0.021 * h * limb),
        "l_foot": (0.024 * h, 0.018 * h),
    }
    radii = np.zeros((N_CAPSULES, 2))
    for c, (cname, _, _, _) in enumerate(CAPSULES):
        key = "l_" + cname[2:] if cname.startswith("r_") else cname
        radii[c] = rad[key]
    meas = {"height_m": h, "chest_m": float(chest), "waist_m": float(waist), "hip_m": float(hip),
            "shoulder_width_m": float(sw)}
    if weight_kg is not None:
        meas["weight_kg"] = float(weight_kg)
    return Body(name=name, offsets=offsets, capsule_radii=radii, measurements=meas)


def default_body() -> Body:
    """A 1.70 m adult with average proportions (the replay publisher's avatar)."""
    return body_from_measurements(1.70, name="default")


def rest_pose(n: int | None = None) -> NDArray[np.float64]:
    """The T-pose at the origin: ``(P,)`` zeros, or ``(n, P)`` if ``n`` is given."""
    return np.zeros(POSE_SIZE) if n is None else np.zeros((n, POSE_SIZE))


def standing_pose(body: Body | None = None) -> NDArray[np.float64]:
    """Relaxed standing pose (arms down at the sides, feet on the floor), facing +Z. ``(P,)``."""
    b = body or default_body()
    p = rest_pose()
    rot = p[3:].reshape(-1, 3)
    rot[ROT_JOINTS.index("l_shoulder")] = (0, 0, np.radians(-80))
    rot[ROT_JOINTS.index("r_shoulder")] = (0, 0, np.radians(80))
    rot[ROT_JOINTS.index("l_elbow")] = (0, np.radians(-8), 0)
    rot[ROT_JOINTS.index("r_elbow")] = (0, np.radians(8), 0)
    p[1] = b.standing_root_height()
    return p


def clamp_pose(poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """Clip every joint's rotation-vector components to :data:`LIMITS_DEG`.

    Parameters
    ----------
    poses : (..., P) float

    Returns
    -------
    (..., P) float64, a new array.
    """
    p = np.array(poses, dtype=np.float64, copy=True)
    rot = p[..., 3:].reshape((*p.shape[:-1], len(ROT_JOINTS), 3))
    np.clip(rot, LIMIT_LO, LIMIT_HI, out=rot)
    return p


def limit_violation_deg(poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """How far (degrees, >= 0) each joint's rotation lies outside its limits.

    Parameters
    ----------
    poses : (..., P) float

    Returns
    -------
    (..., len(ROT_JOINTS)) float64
    """
    p = np.asarray(poses, dtype=np.float64)
    rot = p[..., 3:].reshape((*p.shape[:-1], len(ROT_JOINTS), 3))
    over = np.maximum(rot - LIMIT_HI, 0) + np.maximum(LIMIT_LO - rot, 0)
    over = np.where(np.isfinite(over), over, 0.0)
    return np.degrees(over.max(axis=-1))


def mirror_pose(poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """Mirror poses across the body's sagittal plane (x -> -x), swapping left and right.

    Parameters
    ----------
    poses : (..., P) float

    Returns
    -------
    (..., P) float64
    """
    p = np.asarray(poses, dtype=np.float64)
    out = np.empty_like(p)
    out[..., 0] = -p[..., 0]
    out[..., 1:3] = p[..., 1:3]
    rot = p[..., 3:].reshape((*p.shape[:-1], len(ROT_JOINTS), 3))
    mrot = np.empty_like(rot)
    for k, name in enumerate(ROT_JOINTS):
        src = ROT_JOINTS.index(JOINT_NAMES[MIRROR_JOINTS[JOINT_INDEX[name]]])
        mrot[..., k, 0] = rot[..., src, 0]
        mrot[..., k, 1] = -rot[..., src, 1]
        mrot[..., k, 2] = -rot[..., src, 2]
    out[..., 3:] = mrot.reshape((*p.shape[:-1], -1))
    return out
