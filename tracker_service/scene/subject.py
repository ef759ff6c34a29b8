"""The synthetic scene's person: random human proportions (never one of the 30 models), clothes
that change the silhouette (loose shirt with short or long sleeves, trousers or a skirt, shoes,
optionally long hair), and a skinned triangle mesh posed by linear blend skinning.

The mesh is built once in the rest (T-) pose from lofted elliptical cross-sections (torso, hips,
skirt, shoes), tubes (limbs, sleeves, trouser legs) and ellipsoids (head, hair, hands). Every vertex
follows at most two joint frames of :func:`protocol.kinematics.fk_global`, blended near joints so
elbows, knees and the spine bend smoothly; posing is one gather and two small matrix products.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.kinematics import fk, fk_global
from protocol.skeleton import CAPSULES, JOINT_INDEX, PARTS, Body, rest_pose
from tracker_service.body.family import BODY_MODELS, SECTION_RATIO, Group, build_body, ellipse_axes
from tracker_service.scene.geometry import Surface, ellipsoid_rings, ring_surface, tube_rings

__all__ = ["MATERIALS", "ClothedSubject", "SubjectSpec", "build_subject", "random_subject_spec"]

#: Material slots of the subject mesh (each gets one texture).
MATERIALS: tuple[str, ...] = ("skin", "head", "shirt", "lower", "shoes", "hair")
_J = JOINT_INDEX
_P = {p: k for k, p in enumerate(PARTS)}


@dataclass(frozen=True)
class SubjectSpec:
    """Body measurements and wardrobe of the scene's person (metres, RGB 0-255); ``stoop``: extra
    forward flexion of the spine and the neck in every frame (radians; an elderly person's)."""

    group: Group
    height: float
    chest: float
    waist: float
    hip: float
    arm_ratio: float
    leg_ratio: float
    shoulder_frac: float
    skin: tuple[int, int, int]
    hair: tuple[int, int, int]
    long_hair: bool
    shirt: tuple[int, int, int]
    shirt_pattern: str
    long_sleeves: bool
    skirt: bool
    lower: tuple[int, int, int]
    lower_pattern: str
    shoes: tuple[int, int, int]
    stoop: float = 0.0


def _rgb(rng: np.random.Generator, lo: tuple[float, float, float],
         hi: tuple[float, float, float]) -> tuple[int, int, int]:
    c = rng.uniform(lo, hi)
    return int(c[0]), int(c[1]), int(c[2])


def random_subject_spec(rng: np.random.Generator) -> SubjectSpec:
    """Random adult proportions within human ranges and a random outfit.

    Height ~ N(1.74, 0.07) m (men) or N(1.62, 0.065) m (women), BMI-like girth scaling, arm and leg
    length ratios in [0.94, 1.06]. Re-drawn until at least one of height, chest, waist and hip
    differs by more than 2 cm from every model of :data:`~tracker_service.body.family.BODY_MODELS`.
    """
    while True:
        man = bool(rng.random() < 0.5)
        h = float(np.clip(rng.normal(1.74, 0.07) if man else rng.normal(1.62, 0.065), 1.50, 1.95))
        size = float(np.clip(rng.normal(1.0, 0.07), 0.85, 1.2))
        if man:
            chest = 0.54 * h * size
            waist = chest - rng.uniform(0.04, 0.16)
            hip = (chest + waist) / 2 + rng.uniform(0.04, 0.08)
        else:
            chest = 0.53 * h * size
            waist = chest - rng.uniform(0.14, 0.22)
            hip = chest + rng.uniform(0.04, 0.12)
        near = min(max(abs(h - m.height_m), abs(chest - m.chest_m), abs(waist - m.body.measurements["waist_m"]),
                       abs(hip - m.body.measurements["hip_m"])) for m in BODY_MODELS)
        if near > 0.02:
            break
    tones = np.array([[241, 204, 177], [224, 172, 138], [198, 134, 96], [141, 85, 54], [92, 58, 40]], float)
    skin = tones[rng.integers(len(tones))] * rng.uniform(0.95, 1.05)
    hairs = [(30, 22, 18), (60, 40, 25), (110, 75, 40), (170, 130, 80), (20, 20, 22)]
    skirt = (not man) and bool(rng.random() < 0.4)
    return SubjectSpec(
        group="men" if man else "women", height=h, chest=chest, waist=waist, hip=hip,
        arm_ratio=float(rng.uniform(0.94, 1.06)), leg_ratio=float(rng.uniform(0.95, 1.05)),
        shoulder_frac=float(rng.uniform(0.195, 0.215) if man else rng.uniform(0.185, 0.205)),
        skin=(int(skin[0]), int(skin[1]), int(skin[2])), hair=hairs[int(rng.integers(len(hairs)))],
        long_hair=(not man) and bool(rng.random() < 0.6),
        shirt=_rgb(rng, (20, 20, 20), (235, 235, 235)), shirt_pattern=str(rng.choice(["plain", "stripes", "checks"])),
        long_sleeves=bool(rng.random() < 0.5), skirt=skirt,
        lower=(_rgb(rng, (30, 30, 40), (120, 110, 100)) if skirt or rng.random() < 0.5
               else _rgb(rng, (40, 60, 110), (70, 90, 150))),
        lower_pattern="plain" if skirt else str(rng.choice(["denim", "plain"])),
        shoes=_rgb(rng, (20, 20, 20), (230, 230, 230)))


@dataclass(frozen=True)
class ClothedSubject:
    """The person's skinned mesh (rest pose) and skeleton.

    Attributes
    ----------
    spec : SubjectSpec
    body : Body
        The skeleton the motion is played on (also the capsule proxy for visible fractions).
    surface : Surface
        Rest-pose vertices, faces, normals and texture coordinates.
    face_part, face_material : (F,) int64
        Body part (index into PARTS) and material (index into :data:`MATERIALS`) of every face.
    bone : (V, 2) int64
        The two joints each vertex follows.
    weight : (V, 2) float64
        Blend weights (rows sum to 1).
    rest_joints : (J, 3) float64
        Joint positions of the rest pose (root at the origin).
    """

    spec: SubjectSpec
    body: Body
    surface: Surface
    face_part: NDArray[np.int64]
    face_material: NDArray[np.int64]
    bone: NDArray[np.int64]
    weight: NDArray[np.float64]
    rest_joints: NDArray[np.float64]

    def pose_mesh(self, pose: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Skin the mesh.

        Parameters
        ----------
        pose : (P,) float

        Returns
        -------
        vertices, normals : (V, 3) float64
            World positions and unit normals.
        joints : (J, 3) float64
            World joint positions.
        """
        joints, rot = fk_global(np.asarray(pose, dtype=np.float64), self.body)
        trans = joints - np.einsum("jab,jb->ja", rot, self.rest_joints)
        v0, n0 = self.surface.vertices, self.surface.normals
        out_v = np.zeros_like(v0)
        out_n = np.zeros_like(n0)
        for k in range(2):
            r = rot[self.bone[:, k]]
            w = self.weight[:, k:k + 1]
            out_v += w * (np.einsum("vab,vb->va", r, v0) + trans[self.bone[:, k]])
            out_n += w * np.einsum("vab,vb->va", r, n0)
        out_n /= np.maximum(np.linalg.norm(out_n, axis=1, keepdims=True), 1e-12)
        return out_v, out_n, joints


class _Builder:
    def __init__(self) -> None:
        self.parts: list[tuple[Surface, int, int, NDArray[np.int64], NDArray[np.float64]]] = []

    def add(self, surf: Surface, part: str, material: str, bones: NDArray[np.int64],
            weights: NDArray[np.float64]) -> None:
        self.parts.append((surf, _P[part], MATERIALS.index(material), bones, weights))

    def add_rigid(self, surf: Surface, part: str, material: str, joint: str) -> None:
        n = len(surf.vertices)
        self.add(surf, part, material, np.full((n, 2), _J[joint]), np.tile([1.0, 0.0], (n, 1)))


def _blend(s: NDArray[np.float64], at: float, width: float, before: int,
           after: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Weights moving from joint ``before`` to ``after`` around ``s = at`` (smoothstep over +-width)."""
    t = np.clip((s - (at - width)) / (2 * width), 0.0, 1.0)
    w_after = t * t * (3 - 2 * t)
    bones = np.tile([before, after], (len(s), 1))
    return bones, np.stack([1 - w_after, w_after], axis=1)


def _limb(b: _Builder, start: NDArray[np.float64], axis: NDArray[np.float64], e1: NDArray[np.float64],
          profile: list[tuple[float, float, float]], part: str, material: str, joint: str,
          parent: str | None = None, blend: float = 0.04, segments: int = 16) -> None:
    prof = np.asarray(profile)
    surf = ring_surface(tube_rings(start, axis, e1, prof, segments), u_repeat=2.0, v_scale=0.25)
    if parent is None:
        b.add_rigid(surf, part, material, joint)
    else:
        s = (surf.vertices - start) @ axis
        bones, w = _blend(s, 0.0, blend, _J[parent], _J[joint])
        b.add(surf, part, material, bones, w)


def _rounded(s0: float, s1: float, mids: list[tuple[float, float, float]],
             cap: int = 3) -> list[tuple[float, float, float]]:
    """Profile with hemispherical ends: poles beyond ``s0`` and ``s1`` by the end radii."""
    _, a0, b0 = mids[0]
    _, a1, b1 = mids[-1]
    r0, r1 = 0.5 * (a0 + b0), 0.5 * (a1 + b1)
    out = [(s0 - r0 * np.sin(t), a0 * np.cos(t), b0 * np.cos(t)) for t in np.linspace(np.pi / 2, 0, cap + 1)[:-1]]
    out += mids
    out += [(s1 + r1 * np.sin(t), a1 * np.cos(t), b1 * np.cos(t)) for t in np.linspace(0, np.pi / 2, cap + 1)[1:]]
    return [(float(s), float(a), float(c)) for s, a, c in out]


def build_subject(spec: SubjectSpec) -> ClothedSubject:
    """Build the skeleton and the clothed rest-pose mesh of ``spec``."""
    h = spec.height
    body = build_body("subject", spec.group, h, spec.chest, spec.waist, spec.hip, arm_ratio=spec.arm_ratio,
                      leg_ratio=spec.leg_ratio, shoulder_frac=spec.shoulder_frac)
    rj = fk(rest_pose(), body)
    bl = body.bone_lengths
    rc, rw, rh = SECTION_RATIO[spec.group]
    a_c, b_c = ellipse_axes(spec.chest, rc)
    a_w, b_w = ellipse_axes(spec.waist, rw)
    a_h, b_h = ellipse_axes(spec.hip, rh)
    rad = {c[0]: body.capsule_radii[k] for k, c in enumerate(CAPSULES)}
    y_sp, y_ch, y_nk = rj[_J["spine"], 1], rj[_J["chest"], 1], rj[_J["neck"], 1]
    y_sh = rj[_J["l_shoulder"], 1]
    sw2 = rj[_J["l_shoulder"], 0]
    b = _Builder()
    up, x_ax, z_ax = np.array([0.0, 1, 0]), np.array([1.0, 0, 0]), np.array([0.0, 0, 1])
    loose = 0.012
    chain = [(0.0, _J["pelvis"]), (y_sp, _J["spine"]), (y_ch, _J["chest"])]

    def torso(profile: list[tuple[float, float, float]], part: str, material: str, zoff: float = 0.0) -> None:
        prof = np.asarray(profile)
        surf = ring_surface(tube_rings((0, 0, zoff), up, x_ax, prof, 28), u_repeat=4.0, v_scale=0.25)
        y = surf.vertices[:, 1]
        bones, w = _blend(y, y_sp, 0.35 * y_sp, chain[0][1], chain[1][1])
        upper = y > 0.5 * (y_sp + y_ch)
        b2, w2 = _blend(y, y_ch, 0.35 * (y_ch - y_sp), chain[1][1], chain[2][1])
        bones[upper], w[upper] = b2[upper], w2[upper]
        b.add(surf, part, material, bones, w)

    # hips / shorts region (under the shirt), then the loose shirt
    torso(_rounded(-0.07 * h, 0.11 * h, [(-0.06 * h, 0.8 * a_h, 0.82 * b_h), (-0.035 * h, 0.97 * a_h, b_h),
                                         (-0.01 * h, a_h, b_h), (0.04 * h, 0.5 * (a_h + a_w), 0.5 * (b_h + b_w)),
                                         (0.09 * h, a_w, b_w), (0.11 * h, a_w, b_w)], cap=2),
          "pelvis", "lower", zoff=-0.01)
    hem = 0.03 * h if spec.skirt else -0.015 * h
    top = y_nk + 0.005
    a_hem = float(np.interp(hem, [-0.01 * h, 0.04 * h, 0.09 * h], [a_h, 0.5 * (a_h + a_w), a_w]))
    b_hem = float(np.interp(hem, [-0.01 * h, 0.04 * h, 0.09 * h], [b_h, 0.5 * (b_h + b_w), b_w]))
    shirt = [(hem, a_hem + 2 * loose, b_hem + 2 * loose), (0.09 * h, max(a_w, 0.9 * a_hem) + 1.5 * loose, b_w + loose),
             (0.17 * h, 0.5 * (a_w + a_c) + loose, 0.5 * (b_w + b_c) + loose), (y_ch, a_c + loose, b_c + loose),
             (y_sh - 0.035 * h, a_c, 0.95 * b_c), (y_sh, sw2 + 0.8 * rad["l_upper_arm"][0], 0.72 * b_c),
             (y_sh + 0.018 * h, 0.8 * sw2, 0.6 * b_c), (top - 0.01, 1.7 * rad["neck"][0], 1.4 * rad["neck"][0]),
             (top, 1.45 * rad["neck"][0], 1.25 * rad["neck"][0])]
    torso([(hem - 0.002, 0.5 * shirt[0][1], 0.5 * shirt[0][2]), *shirt, (top + 0.004, 0.0, 0.0)], "torso", "shirt")
    if spec.skirt:
        y_kn = rj[_J["l_knee"], 1]
        skirt = [(0.06 * h + 0.002, 0.0, 0.0), (0.06 * h, a_w + loose, b_w + loose), (0.0, a_h + 0.01, b_h + 0.01),
                 (y_kn + 0.12, 1.3 * a_h, 1.45 * b_h), (y_kn + 0.10, 1.28 * a_h, 1.42 * b_h), (y_kn + 0.12, 0.0, 0.0)]
        torso(skirt[::-1], "pelvis", "lower", zoff=-0.01)
    # neck and head
    nr = rad["neck"][0]
    _limb(b, rj[_J["neck"]] - (0, 0.02, 0), up, x_ax, _rounded(0.0, bl[_J["head"]] + 0.02, [(0.0, nr, nr),
          (bl[_J["head"]] + 0.02, 0.95 * nr, 0.95 * nr)], cap=2), "head", "skin", "neck", "chest")
    crown = rj[_J["head_top"], 1] + rad["skull"][1]
    hh = (0.13 if spec.group != "children" else 0.17) * h
    hb, hl = 2 * rad["skull"][1] * 0.88, 2 * rad["skull"][1] * 1.1
    head_c = np.array([0.0, crown - hh / 2, 0.012])
    ring = ellipsoid_rings(head_c, (hb / 2, hh / 2, hl / 2), 18, 24)
    ring[:, :, 0] *= np.linspace(1.0, 0.72, 18)[:, None] ** 1.5  # narrower jaw
    b.add_rigid(ring_surface(ring), "head", "head", "head")
    if spec.long_hair:
        hair_c = head_c + np.array([0.0, -0.054 * h, -0.035])
        hair = ellipsoid_rings(hair_c, (0.5 * hb + 0.012, 0.5 * hh + 0.03, 0.42 * hl), 12, 20)
        b.add_rigid(ring_surface(hair, u_repeat=2.0), "head", "hair", "head")
    # arms, hands, legs, shoes (both sides)
    for side, sx in (("l", 1.0), ("r", -1.0)):
        ax = np.array([sx, 0.0, 0.0])
        sh, el, wr = rj[_J[f"{side}_shoulder"]], rj[_J[f"{side}_elbow"]], rj[_J[f"{side}_wrist"]]
        lu, lf, lh = bl[_J[f"{side}_elbow"]], bl[_J[f"{side}_wrist"]], bl[_J[f"{side}_hand_tip"]]
        ua0, ua1 = rad[f"{side}_upper_arm"]
        fa0, fa1 = rad[f"{side}_forearm"]
        _limb(b, sh, ax, up, _rounded(0.04, lu, [(0.04, ua0, ua0), (0.5 * lu, 0.95 * ua0, 0.92 * ua0), (lu, ua1, ua1)]),
              f"{side}_upper_arm", "skin", f"{side}_shoulder")
        end = 0.45 * lu if not spec.long_sleeves else lu + 0.02
        sl = [(0.01, 0.9 * ua0 + loose, 0.9 * ua0 + loose), (0.3 * lu, ua0 + loose, ua0 + loose),
              (end, 0.95 * ua0 + 1.6 * loose, 0.95 * ua0 + 1.6 * loose)]
        _limb(b, sh, ax, up, _rounded(0.01, end, sl[:2] + sl[2:] if end > 0.3 * lu else [sl[0], sl[2]], cap=2),
              f"{side}_upper_arm", "shirt", f"{side}_shoulder")
        _limb(b, el, ax, up, _rounded(0.0, lf, [(0.0, fa0, fa0), (0.35 * lf, fa0, 0.95 * fa0), (lf, fa1, 0.85 * fa1)]),
              f"{side}_forearm", "skin", f"{side}_elbow", f"{side}_shoulder")
        if spec.long_sleeves:
            _limb(b, el, ax, up, _rounded(0.0, lf - 0.015, [(0.0, fa0 + 1.5 * loose, fa0 + 1.5 * loose),
                  (lf - 0.015, fa1 + 1.4 * loose, fa1 + 1.4 * loose)], cap=2), f"{side}_forearm", "shirt",
                  f"{side}_elbow", f"{side}_shoulder")
        hs = h / 1.7
        tip = lh - 0.013 * hs  # the cap reaches the hand_tip joint (finger tips)
        hp = [(0.01, 0.016 * hs, 0.030 * hs), (0.45 * lh, 0.014 * hs, 0.045 * hs), (tip, 0.010 * hs, 0.030 * hs)]
        _limb(b, wr, ax, up, _rounded(0.01, tip, hp, cap=2), f"{side}_hand", "skin", f"{side}_wrist")
        hip, kn, an = rj[_J[f"{side}_hip"]], rj[_J[f"{side}_knee"]], rj[_J[f"{side}_ankle"]]
        lt, ls = bl[_J[f"{side}_knee"]], bl[_J[f"{side}_ankle"]]
        th0, th1 = rad[f"{side}_thigh"]
        sh0, sh1 = rad[f"{side}_shin"]
        dn = np.array([0.0, -1.0, 0.0])
        extra = 0.0 if spec.skirt else loose * 1.5
        mat = "skin" if spec.skirt else "lower"
        thigh = [(-0.02, th0 + extra, th0 + extra), (0.5 * lt, 0.85 * th0 + extra, 0.85 * th0 + extra),
                 (lt, th1 + extra, th1 + extra)]
        _limb(b, hip, dn, z_ax, _rounded(-0.02, lt, thigh, cap=2), f"{side}_thigh", mat, f"{side}_hip", "pelvis", 0.05)
        hem_r = sh1 + (0.03 if not spec.skirt else 0.0)
        shin = [(0.0, th1 + extra, th1 + extra), (0.3 * ls, sh0 + extra, 1.05 * sh0 + extra), (ls - 0.02, hem_r, hem_r)]
        _limb(b, kn, dn, z_ax, _rounded(0.0, ls - 0.02, shin, cap=2), f"{side}_shin", mat, f"{side}_knee",
              f"{side}_hip")
        floor = -body.standing_root_height()
        fw, ft = 0.052 * h / 1.7, rj[_J[f"{side}_toe"], 2] + 0.02
        shoe = [(-0.05 * h / 1.7, 0.5 * fw, 0.05), (-0.03, 0.8 * fw, 0.07), (0.02, fw, 0.075),
                (0.55 * ft, 1.1 * fw, 0.055), (0.9 * ft, fw, 0.04), (ft, 0.6 * fw, 0.025)]
        prof = np.asarray([(s, a, c) for s, a, c in shoe])
        rings = tube_rings((an[0], floor + 0.045, 0.0), z_ax, x_ax, prof, 16)
        rings[..., 1] = np.maximum(rings[..., 1], floor)  # flat sole
        rings = np.concatenate([rings[:1].mean(axis=1, keepdims=True).repeat(16, 1), rings,
                                rings[-1:].mean(axis=1, keepdims=True).repeat(16, 1)])
        b.add_rigid(ring_surface(rings, u_repeat=1.0, v_scale=0.3), f"{side}_foot", "shoes", f"{side}_ankle")
    return _assemble(spec, body, b, rj)


def _assemble(spec: SubjectSpec, body: Body, b: _Builder, rj: NDArray[np.float64]) -> ClothedSubject:
    offs = np.cumsum([0] + [len(p[0].vertices) for p in b.parts[:-1]])
    surf = Surface(np.concatenate([p[0].vertices for p in b.parts]),
                   np.concatenate([p[0].faces + o for p, o in zip(b.parts, offs, strict=True)]),
                   np.concatenate([p[0].normals for p in b.parts]), np.concatenate([p[0].uv for p in b.parts]))
    face_part = np.concatenate([np.full(len(p[0].faces), p[1]) for p in b.parts]).astype(np.int64)
    face_mat = np.concatenate([np.full(len(p[0].faces), p[2]) for p in b.parts]).astype(np.int64)
    bone = np.concatenate([p[3] for p in b.parts]).astype(np.int64)
    weight = np.concatenate([p[4] for p in b.parts]).astype(np.float64)
    return ClothedSubject(spec, body, surf, face_part, face_mat, bone, weight, rj)
