"""Retargeting BVH recordings onto the shared skeleton.

The source skeleton's joint *positions* (from its own forward kinematics, in metres) are mapped
onto our joints by name (:data:`ARMATURES`), then every joint's global frame is solved so that
its bone points exactly where the source's bone points (a two-axis TRIAD fit: the bone direction
exactly, a secondary axis -- hinge plane, lateral axis -- as closely as possible). Local rotations
follow as ``G_parent^T G``. Rotations therefore reproduce the source's joint *directions* on any
body; with a body fitted to the source (:func:`fit_body`) they reproduce its joint positions.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from protocol.formats.bvh import BvhFile, bvh_fk
from protocol.kinematics import fk_global
from protocol.rotations import matrix_to_rotvec, two_axis_frame
from protocol.skeleton import CAPSULES, JOINT_INDEX, JOINT_NAMES, N_JOINTS, PARENTS, POSE_SIZE, ROT_JOINTS, Body

__all__ = [
    "ARMATURES",
    "UNITS",
    "Armature",
    "SourceSkeleton",
    "artifact_mask",
    "detect_armature",
    "fit_body",
    "retarget",
    "source_skeleton",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Armature:
    """How a family of BVH skeletons maps onto ours.

    Attributes
    ----------
    name : str
    joints : dict[str, str]
        Our joint name -> source spec: a joint name, ``"A+B"`` (mid-point of two joints) or
        ``"A@end"`` (A's end site, or A's bone continued when the end site is missing/zero).
    head : str, chest : str
        Source joints whose relative rotation gives the head's yaw/roll.
    stamped_fps_override : dict[float, float]
        Frame rates known to be stamped wrongly by this armature's converter (stamped -> true).
    """

    name: str
    joints: dict[str, str]
    head: str
    chest: str
    stamped_fps_override: dict[float, float]


def _sides(spec: dict[str, tuple[str, str]], mid: dict[str, str]) -> dict[str, str]:
    out = dict(mid)
    for ours, (left, right) in spec.items():
        out["l_" + ours], out["r_" + ours] = left, right
    return out


ARMATURES: tuple[Armature, ...] = (
    Armature("bandai", _sides(
        {"clavicle": ("Shoulder_L", "Shoulder_R"), "shoulder": ("UpperArm_L", "UpperArm_R"),
         "elbow": ("LowerArm_L", "LowerArm_R"), "wrist": ("Hand_L", "Hand_R"),
         "hand_tip": ("Hand_L@end", "Hand_R@end"), "hip": ("UpperLeg_L", "UpperLeg_R"),
         "knee": ("LowerLeg_L", "LowerLeg_R"), "ankle": ("Foot_L", "Foot_R"), "toe": ("Toes_L", "Toes_R")},
        {"pelvis": "UpperLeg_L+UpperLeg_R", "spine": "Spine", "chest": "Chest", "neck": "Neck",
         "head": "Head", "head_top": "Head@end"}), "Head", "Chest", {}),
    Armature("cmu_motionbuilder", _sides(
        {"clavicle": ("LeftShoulder", "RightShoulder"), "shoulder": ("LeftArm", "RightArm"),
         "elbow": ("LeftForeArm", "RightForeArm"), "wrist": ("LeftHand", "RightHand"),
         "hand_tip": ("LFingers@end", "RFingers@end"), "hip": ("LeftUpLeg", "RightUpLeg"),
         "knee": ("LeftLeg", "RightLeg"), "ankle": ("LeftFoot", "RightFoot"),
         "toe": ("LeftToeBase", "RightToeBase")},
        {"pelvis": "LeftUpLeg+RightUpLeg", "spine": "Spine", "chest": "Spine1", "neck": "Neck1",
         "head": "Head", "head_top": "Head@end"}), "Head", "Spine1", {}),
    Armature("cmu_3dsmax", _sides(
        {"clavicle": ("LeftCollar", "RightCollar"), "shoulder": ("LeftShoulder", "RightShoulder"),
         "elbow": ("LeftElbow", "RightElbow"), "wrist": ("LeftWrist", "RightWrist"),
         "hand_tip": ("LFingers@end", "RFingers@end"), "hip": ("LeftHip", "RightHip"),
         "knee": ("LeftKnee", "RightKnee"), "ankle": ("LeftAnkle", "RightAnkle"), "toe": ("LeftToe", "RightToe")},
        {"pelvis": "LeftHip+RightHip", "spine": "Chest", "chest": "Chest2", "neck": "Neck",
         "head": "Head", "head_top": "Head@end"}), "Head", "Chest2", {}),
    Armature("daz", _sides(
        {"clavicle": ("lCollar", "rCollar"), "shoulder": ("lShldr", "rShldr"),
         "elbow": ("lForeArm", "rForeArm"), "wrist": ("lHand", "rHand"),
         "hand_tip": ("lMid2@end", "rMid2@end"), "hip": ("lThigh", "rThigh"),
         "knee": ("lShin", "rShin"), "ankle": ("lFoot", "rFoot"), "toe": ("lFoot@end", "rFoot@end")},
        {"pelvis": "lThigh+rThigh", "spine": "abdomen", "chest": "chest", "neck": "neck",
         "head": "head", "head_top": "head@end"}), "head", "chest", {}),
    Armature("makehuman_cmu", _sides(
        {"clavicle": ("lcollar", "rcollar"), "shoulder": ("lshoulder", "rshoulder"),
         "elbow": ("lelbow", "relbow"), "wrist": ("lhand", "rhand"),
         "hand_tip": ("finger3-3.l@end", "finger3-3.r@end"), "hip": ("lhip", "rhip"),
         "knee": ("lknee", "rknee"), "ankle": ("lfoot", "rfoot"), "toe": ("toe3-1.l", "toe3-1.r")},
        {"pelvis": "lhip+rhip", "spine": "abdomen", "chest": "chest", "neck": "neck1",
         "head": "head", "head_top": "head@end"}), "head", "chest", {25.0: 120.0}),
    Armature("cmu_lowercase", _sides(
        {"clavicle": ("lcollar", "rcollar"), "shoulder": ("lshoulder", "rshoulder"),
         "elbow": ("lelbow", "relbow"), "wrist": ("lhand", "rhand"),
         "hand_tip": ("lefthandindex1@end", "righthandindex1@end"), "hip": ("lhip", "rhip"),
         "knee": ("lknee", "rknee"), "ankle": ("lfoot", "rfoot"), "toe": ("lefttoebase", "righttoebase")},
        {"pelvis": "lhip+rhip", "spine": "abdomen", "chest": "chest", "neck": "neck1",
         "head": "head", "head_top": "head@end"}), "head", "chest", {}),
)

# Continuation length of a missing end site, as a fraction of the source's leg length.
_VIRTUAL_END = {"head_top": 0.24, "l_hand_tip": 0.22, "r_hand_tip": 0.22, "l_toe": 0.10, "r_toe": 0.10}


def _names(spec: str) -> list[str]:
    return spec.replace("@end", "").split("+")


def detect_armature(names: list[str]) -> Armature:
    """The first armature in :data:`ARMATURES` whose every mapped joint exists in ``names``.

    Raises
    ------
    ValueError
        No known armature matches (the message lists the closest one's missing joints).
    """
    have = set(names)
    best: tuple[int, Armature, list[str]] | None = None
    for arm in ARMATURES:
        missing = sorted({n for spec in arm.joints.values() for n in _names(spec)} - have)
        if not missing:
            return arm
        if best is None or len(missing) < best[0]:
            best = (len(missing), arm, missing)
    assert best is not None
    raise ValueError(f"unknown BVH armature; closest is {best[1].name!r}, missing joints {best[2]}")


@dataclass(frozen=True)
class SourceSkeleton:
    """A recording mapped onto our joints, before solving rotations.

    Attributes
    ----------
    positions : (F, J, 3) float64
        Source positions of our joints, metres.
    head_lateral : (F, 3) float64
        The source head's left axis (unit), carrying the head's yaw relative to the chest.
    leg_length : float
        Source hip-to-ankle length, metres.
    scale : float
        File units -> metres for bones; ``root_translation_scale`` likewise for the root.
    root_translation_scale : float
    armature : str
    """

    positions: NDArray[np.float64]
    head_lateral: NDArray[np.float64]
    leg_length: float
    scale: float
    root_translation_scale: float
    armature: str


#: Candidate file units (name, metres per unit), in order of preference.
#: CMU ASF length unit: 1 unit = 1/0.45 inch = 5.644 cm.
UNITS = (("m", 1.0), ("cm", 0.01), ("cmu", 0.0254 / 0.45), ("inch", 0.0254), ("mm", 0.001))


def _leg_units(bvh: BvhFile, arm: Armature) -> float:
    pos, _ = bvh_fk(_first_frame(bvh), 1.0)
    idx = {n: k for k, n in enumerate(bvh.names)}
    legs = []
    for s in ("l_", "r_"):
        h, k, a = (pos[0, idx[_names(arm.joints[s + n])[0]]] for n in ("hip", "knee", "ankle"))
        legs.append(np.linalg.norm(k - h) + np.linalg.norm(a - k))
    return float(np.mean(legs))


def _first_frame(bvh: BvhFile) -> BvhFile:
    return BvhFile(bvh.path, bvh.joints, bvh.frame_time, bvh.motion[:1], bvh.offset_mode)


def source_skeleton(bvh: BvhFile, armature: Armature | None = None, scale: float | None = None,
                    root_translation_scale: float | None = None) -> SourceSkeleton:
    """Map a BVH recording onto our joints, detecting units.

    Parameters
    ----------
    bvh : BvhFile
    armature : Armature, optional
        Detected from the joint names when omitted.
    scale : float, optional
        File units -> metres. Detected when omitted: the unit among m, cm, CMU units (5.64 cm),
        inch and mm that makes the leg 0.6-1.05 m long, else a scale that makes it 0.85 m.
    root_translation_scale : float, optional
        Units of the root's position channels. Detected when omitted: equal to ``scale`` unless
        the standing pelvis height is implausible for the leg length (then fitted to it).

    Returns
    -------
    SourceSkeleton
    """
    arm = armature or detect_armature(bvh.names)
    if bvh.n_frames == 0:
        raise ValueError(f"{bvh.path}: no frames")
    if scale is None:
        leg_u = _leg_units(bvh, arm)
        for unit, s in UNITS:
            if 0.6 <= leg_u * s <= 1.05:
                scale = s
                log.debug("%s: units %s", bvh.path, unit)
                break
        else:
            scale = 0.85 / leg_u
            log.warning("%s: leg length %.3g units fits no known unit; scaling it to 0.85 m", bvh.path, leg_u)
    idx = {n: k for k, n in enumerate(bvh.names)}
    pos, rot = bvh_fk(bvh, scale, root_translation_scale)

    def resolve(ours: str, spec: str) -> NDArray[np.float64]:
        if "+" in spec:
            a, b = spec.split("+")
            return 0.5 * (pos[:, idx[a]] + pos[:, idx[b]])
        if spec.endswith("@end"):
            jn = spec[:-4]
            k = idx[jn]
            j = bvh.joints[k]
            if j.end_site is not None and np.linalg.norm(j.end_site) * scale > 1e-4:
                return pos[:, k] + np.einsum("fij,j->fi", rot[:, k], j.end_site * scale)
            return pos[:, k]  # placeholder, continued below once the leg length is known
        return pos[:, idx[spec]]

    out = np.empty((bvh.n_frames, N_JOINTS, 3))
    for ours in JOINT_NAMES:
        out[:, JOINT_INDEX[ours]] = resolve(ours, arm.joints[ours])
    j = JOINT_INDEX
    leg = float(np.mean(np.linalg.norm(out[:, j["l_knee"]] - out[:, j["l_hip"]], axis=-1)
                        + np.linalg.norm(out[:, j["l_ankle"]] - out[:, j["l_knee"]], axis=-1)))
    for ours, frac in _VIRTUAL_END.items():
        spec = arm.joints[ours]
        if not spec.endswith("@end"):
            continue
        k = idx[spec[:-4]]
        bj = bvh.joints[k]
        if bj.end_site is not None and np.linalg.norm(bj.end_site) * scale > 1e-4:
            continue
        # continue the incoming bone: its direction in the parent's frame, turned by the joint's rotation
        d = bj.offset / max(float(np.linalg.norm(bj.offset)), 1e-12)
        out[:, j[ours]] = pos[:, k] + frac * leg * np.einsum("fij,j->fi", rot[:, k], d)
    if root_translation_scale is None:
        pelvis_h = float(np.median(out[:, j["pelvis"], 1]))
        if not 0.4 * leg <= pelvis_h <= 2.5 * leg:
            root = bvh.joints[0]
            ycol = [root.channel_start + q for q, c in enumerate(root.channels) if c == "Yposition"]
            ty = float(np.median(bvh.motion[:, ycol[0]])) if ycol else 0.0
            if abs(ty) > 1e-9:
                rest = pelvis_h - ty * scale  # pelvis height not due to the root translation
                rts = (1.0 * leg - rest) / ty
                log.warning("%s: pelvis %.2f m high for a %.2f m leg; root translation units differ "
                            "from the bones (x%.3g)", bvh.path, pelvis_h, leg, rts / scale)
                return source_skeleton(bvh, arm, scale, rts)
        root_translation_scale = scale
    head_lat = _head_lateral(bvh, arm, rot, out)
    return SourceSkeleton(out, head_lat, leg, float(scale), float(root_translation_scale), arm.name)


def _head_lateral(bvh: BvhFile, arm: Armature, rot: NDArray[np.float64],
                  pos: NDArray[np.float64]) -> NDArray[np.float64]:
    idx = {n: k for k, n in enumerate(bvh.names)}
    j = JOINT_INDEX
    lat = _unit(pos[:, j["l_shoulder"]] - pos[:, j["r_shoulder"]])
    rel = rot[:, idx[arm.head]] @ np.swapaxes(rot[:, idx[arm.chest]], -1, -2)
    return _unit(np.einsum("fij,fj->fi", rel, lat))


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _perp(v: NDArray[np.float64], axis: NDArray[np.float64]) -> NDArray[np.float64]:
    return v - np.sum(v * axis, axis=-1, keepdims=True) * axis


def _bend_axis(upper: NDArray[np.float64], lower: NDArray[np.float64], fallback: NDArray[np.float64],
               lo_deg: float = 5.0, hi_deg: float = 25.0) -> NDArray[np.float64]:
    """Direction (unit, perpendicular to ``upper``) into which ``lower`` bends away from ``upper``;
    blends smoothly into ``fallback`` (projected) as the limb straightens."""
    u = _unit(upper)
    d = _perp(_unit(lower), u)
    s = np.linalg.norm(d, axis=-1, keepdims=True)
    t = np.clip((s - np.sin(np.radians(lo_deg))) / (np.sin(np.radians(hi_deg)) - np.sin(np.radians(lo_deg))), 0, 1)
    w = t * t * (3 - 2 * t)
    fb = _unit(_perp(fallback, u))
    mix = w * (d / np.maximum(s, 1e-12)) + (1 - w) * fb
    bad = np.linalg.norm(mix, axis=-1, keepdims=True) < 1e-3
    return _unit(np.where(bad, fb, mix))


def retarget(src: SourceSkeleton, body: Body) -> NDArray[np.float64]:
    """Solve our pose vectors from source joint positions.

    Parameters
    ----------
    src : SourceSkeleton
    body : Body
        Target body; its rest offsets define the bone directions to align and the root
        translation is scaled by ``body.leg_length / src.leg_length``.

    Returns
    -------
    (F, P) float64
    """
    S = src.positions
    f = S.shape[0]
    j = JOINT_INDEX
    off = body.offsets
    G = np.zeros((f, N_JOINTS, 3, 3))
    ex, ey, ez = np.eye(3)

    def b(name: str) -> NDArray[np.float64]:
        return S[:, j[name]]

    def solve(name: str, child: str, b_rest: NDArray[np.float64], b_target: NDArray[np.float64]) -> None:
        G[:, j[name]] = two_axis_frame(off[j[child]], b(child) - b(name), b_rest, b_target)

    lat_hip = _unit(b("l_hip") - b("r_hip"))
    lat_sh = _unit(b("l_shoulder") - b("r_shoulder"))
    solve("pelvis", "spine", ex, lat_hip)
    solve("spine", "chest", ex, lat_hip + lat_sh)
    solve("chest", "neck", ex, lat_sh)
    solve("neck", "head", ex, lat_sh + src.head_lateral)
    solve("head", "head_top", ex, src.head_lateral)
    for s in ("l_", "r_"):
        solve(s + "clavicle", s + "shoulder", ey, G[:, j["chest"]] @ ey)
        upper, fore = b(s + "elbow") - b(s + "shoulder"), b(s + "wrist") - b(s + "elbow")
        solve(s + "shoulder", s + "elbow", ez, _bend_axis(upper, fore, G[:, j[s + "clavicle"]] @ ez))
        # the elbow and knee keep their parent's hinge axis, so they stay pure hinges
        solve(s + "elbow", s + "wrist", ey, G[:, j[s + "shoulder"]] @ ey)
        solve(s + "wrist", s + "hand_tip", ey, G[:, j[s + "elbow"]] @ ey)
        thigh, shin = b(s + "knee") - b(s + "hip"), b(s + "ankle") - b(s + "knee")
        foot_fwd = b(s + "toe") - b(s + "ankle")
        # the knee bends backwards: the thigh frame's +Z is opposite the shin's bend direction
        hinge = -_bend_axis(thigh, shin, -foot_fwd)
        solve(s + "hip", s + "knee", ez, hinge)
        solve(s + "knee", s + "ankle", ex, G[:, j[s + "hip"]] @ ex)
        solve(s + "ankle", s + "toe", ex, G[:, j[s + "knee"]] @ ex)
    poses = np.zeros((f, POSE_SIZE))
    poses[:, :3] = b("pelvis") * (body.leg_length / src.leg_length)
    rots = np.zeros((f, len(ROT_JOINTS), 3))
    for k, name in enumerate(ROT_JOINTS):
        jj = j[name]
        par = PARENTS[jj]
        local = G[:, jj] if par < 0 else np.swapaxes(G[:, par], -1, -2) @ G[:, jj]
        rots[:, k] = matrix_to_rotvec(local)
    poses[:, 3:] = rots.reshape(f, -1)
    return poses


def fit_body(src: SourceSkeleton, poses: NDArray[np.float64], name: str = "fitted",
             valid: NDArray[np.bool_] | None = None) -> Body:
    """A body whose rest offsets reproduce the source skeleton under ``poses``.

    Each offset is the median over frames of the source bone expressed in the parent joint's
    solved frame, so ``fk(poses, fit_body(src, poses))`` matches ``src.positions``.

    Parameters
    ----------
    src : SourceSkeleton
    poses : (F, P) float
        Output of :func:`retarget` for ``src``.
    name : str
    valid : (F,) bool, optional
        Frames to use.

    Returns
    -------
    Body
    """
    from protocol.skeleton import body_from_measurements

    S = src.positions
    m = np.ones(len(S), bool) if valid is None else np.asarray(valid, bool)
    base = body_from_measurements(float(np.clip(src.leg_length / 0.49, 0.8, 2.3)))
    _, G = fk_global(poses[m], base)
    offsets = np.zeros((N_JOINTS, 3))
    for jj in range(1, N_JOINTS):
        par = PARENTS[jj]
        local = np.einsum("fji,fj->fi", G[:, par], S[m, jj] - S[m, par])
        offsets[jj] = np.median(local, axis=0)
    radii = base.capsule_radii.copy()
    meas = dict(base.measurements)
    assert len(radii) == len(CAPSULES)
    return Body(name=name, offsets=offsets, capsule_radii=radii, measurements=meas)


def artifact_mask(positions: NDArray[np.float64], fps: float, lead_frames: int = 12,
                  max_accel: float = 1000.0) -> tuple[int, NDArray[np.bool_]]:
    """Find converter artefacts: leading rest/T-pose/blend frames and glitches.

    A frame is an artefact when some joint's acceleration (second difference of positions)
    exceeds ``max_accel``. Over all 252 shared recordings, clean motion stays below ~820 m/s^2
    (fast hands and feet included; Bandai takes below 240), while the converters' T-pose, rest and
    blend frames jump with 1,200-14,000 m/s^2 and the right-leg glitch of ``60_10`` reaches 9,000.

    Parameters
    ----------
    positions : (F, J, 3) float
        Joint positions, metres.
    fps : float
    lead_frames : int
        How many leading frames may be artefacts to trim.
    max_accel : float
        Acceleration threshold, m/s^2.

    Returns
    -------
    start : int
        First clean frame (frames before it should be dropped).
    valid : (F,) bool
        False on frames around a glitch after ``start``.
    """
    f = len(positions)
    valid = np.ones(f, bool)
    if f < 3:
        return 0, valid
    p = np.asarray(positions, dtype=np.float64)
    acc = np.linalg.norm(p[2:] - 2 * p[1:-1] + p[:-2], axis=-1).max(axis=1) * fps * fps  # centred at 1..F-2
    bad = np.flatnonzero(acc > max_accel)
    lead = bad[bad < lead_frames]
    start = int(lead.max()) + 1 if len(lead) else 0
    for g in bad[bad >= lead_frames]:
        valid[int(g): int(g) + 3] = False  # the frames around the centred frame g + 1
    return start, valid
