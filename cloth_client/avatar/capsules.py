"""The avatar the cloth is simulated on: body capsules and pin frames from a ``BodyInfo`` and poses.

Received poses arrive at 15-120 Hz, sometimes with gaps. Between two of them the avatar is moved
along an articulated interpolation (root position linear, every joint rotation slerped), sampled at
``K + 1`` key instants per cloth step and run through :func:`protocol.fk_global`, so a forearm
swings on an arc instead of cutting a chord through the cloth. A jump no human can make (a joint
faster than :attr:`Continuity.max_joint_speed`, the root faster than
:attr:`Continuity.max_root_speed`, or a gap longer than :attr:`Continuity.max_gap_s`) is a
*discontinuity* (tracker re-initialisation, teleport): :mod:`cloth_client.solver.driver` then carries the
cloth along with the root's rigid motion instead of dragging it through the jump.

Numba kernels do the per-key work (:mod:`cloth_client.avatar.pose_kernels` for the interpolation,
:mod:`cloth_client.contact.seam_kernels` for the seam's pins); :func:`interpolate_poses_reference` and
the ``*_reference`` functions of :mod:`cloth_client.contact.seam` are their plain numpy references.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cloth_client.avatar.leg_clearance import clear_legs
from cloth_client.avatar.limb_clearance import (
    LIMB_CLEARANCE,
    LIMBS,
    TRUNK,
    clear_limbs,
    clear_limbs_track,
    limb_overlap,
)
from cloth_client.avatar.pose_kernels import interpolate_poses as interpolate_kernel
from cloth_client.contact.collision import CapsuleTrack
from cloth_client.contact.seam import check_seam_rest
from cloth_client.contact.seam_kernels import SEAM_LENGTH_ROUNDS, SEAM_LENGTH_SLACK
from cloth_client.contact.seam_kernels import covered as covered_kernel
from cloth_client.contact.seam_kernels import keep_seam_length as keep_seam_length_kernel
from cloth_client.contact.seam_kernels import push_out as push_out_kernel
from cloth_client.contact.seam_kernels import slide_seam as slide_seam_kernel
from protocol.kinematics import fk_global
from protocol.rotations import matrix_to_quat, quat_slerp, rotvec_to_matrix
from protocol.skeleton import CAPSULE_JOINTS, POSE_SIZE, Body
from protocol.wire.messages import BodyInfo, body_from_body_info

__all__ = [
    "LIMBS",
    "TRUNK",
    "AvatarKeys",
    "Continuity",
    "avatar_capsules",
    "body_of",
    "capsule_endpoints",
    "interpolate_poses",
    "interpolate_poses_reference",
    "is_discontinuity",
    "limb_overlap",
    "pose_keys",
    "rigid_root_delta",
    "swing_vectors",
]

F64 = NDArray[np.float64]


def body_of(info: BodyInfo | Body) -> Body:
    """The :class:`~protocol.skeleton.Body` of a ``BodyInfo`` (rebuilt) or a ``Body`` (unchanged)."""
    return info if isinstance(info, Body) else body_from_body_info(info)


def capsule_endpoints(body: Body, poses: F64) -> tuple[F64, F64]:
    """World endpoints of every body capsule.

    Parameters
    ----------
    body : Body
    poses : (N, P) or (P,) float64

    Returns
    -------
    a, b : (N, C, 3) float64
        (``(C, 3)`` for a single pose), metres.
    """
    joints, _ = fk_global(poses, body)
    return joints[..., CAPSULE_JOINTS[:, 0], :], joints[..., CAPSULE_JOINTS[:, 1], :]


def _rotvec_from_quat(q: F64) -> F64:
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    theta = 2.0 * np.arctan2(s, q[..., 0])
    scale = np.where(s < 1e-12, 2.0, theta / np.maximum(s, 1e-300))
    out: F64 = v * scale[..., None]
    return out


def interpolate_poses(p0: F64, p1: F64, s: F64) -> F64:
    """Articulated interpolation between two poses.

    Parameters
    ----------
    p0, p1 : (P,) float64
        Poses at fraction 0 and 1.
    s : (K,) float64
        Fractions in [0, 1].

    Returns
    -------
    (K, P) float64
        Root position linear, root and joint rotations slerped along the shorter arc (the kernel
        :func:`cloth_client.avatar.pose_kernels.interpolate_poses`; :func:`interpolate_poses_reference`
        is its plain numpy reference).
    """
    s = _check_poses(p0, p1, s)
    res = np.empty((len(s), POSE_SIZE))
    interpolate_kernel(np.ascontiguousarray(p0, dtype=np.float64), np.ascontiguousarray(p1, dtype=np.float64),
                       np.ascontiguousarray(s), res)
    return res


def interpolate_poses_reference(p0: F64, p1: F64, s: F64) -> F64:
    """:func:`interpolate_poses` in plain numpy: rotation vectors through matrices and
    :func:`protocol.rotations.quat_slerp` (reference of :func:`cloth_client.avatar.pose_kernels.interpolate_poses`)."""
    s = _check_poses(p0, p1, s)
    q0 = matrix_to_quat(rotvec_to_matrix(p0[3:].reshape(-1, 3)))  # (R, 4)
    q1 = matrix_to_quat(rotvec_to_matrix(p1[3:].reshape(-1, 3)))
    q = quat_slerp(q0[None], q1[None], np.broadcast_to(s[:, None], (len(s), len(q0))))
    out = np.empty((len(s), POSE_SIZE))
    out[:, :3] = (1.0 - s[:, None]) * p0[:3] + s[:, None] * p1[:3]
    out[:, 3:] = _rotvec_from_quat(q).reshape(len(s), -1)
    return out


def _check_poses(p0: F64, p1: F64, s: F64) -> F64:
    """``s`` as float64, after checking that ``p0`` and ``p1`` are poses ``(P,)``."""
    s = np.asarray(s, dtype=np.float64)
    if np.shape(p0) != (POSE_SIZE,) or np.shape(p1) != (POSE_SIZE,):
        raise ValueError(f"poses must have shape ({POSE_SIZE},), got {np.shape(p0)} and {np.shape(p1)}")
    return s


@dataclass(frozen=True)
class AvatarKeys:
    """The avatar sampled at ``K + 1`` evenly spaced instants of one cloth step.

    Attributes
    ----------
    track : CapsuleTrack
        Capsule endpoints per key, ``(K + 1, C, 3)``.
    joints : (K + 1, J, 3) float64
        Joint positions per key.
    rotations : (K + 1, J, 3, 3) float64
        Global joint orientations per key (for pin targets).
    limb_memory : (2, 3, 3) float64 or None
        The sunk-limb corrections at the last key, to carry into the next step's keys
        (:func:`~cloth_client.avatar.limb_clearance.clear_limbs_track`); None without the clearance rule.
    """

    track: CapsuleTrack
    joints: F64
    rotations: F64
    limb_memory: F64 | None = None

    def pin_targets(self, pin_joint: NDArray[np.int64], pin_local: F64, axis: NDArray[np.int64] | None = None,
                    axis_s: F64 | None = None, axis_local: F64 | None = None,
                    roll: NDArray[np.int64] | None = None) -> F64:
        """World positions ``(K + 1, P, 3)`` of pins.

        Parameters
        ----------
        pin_joint : (P,) int64
            Joint whose frame carries each pin's offset.
        pin_local : (P, 3) float64
            Offset in that frame, metres.
        axis : (P, 2) int64, optional
            Joints ``a, b`` of the bone axis the pin is anchored on (default: the pin's joint).
        axis_s : (P,) float64, optional
            Anchor parameter ``s`` along that axis: the target is ``(1 - s) J_a + s J_b + R pin_local``.
        axis_local : (P, 3) float64, optional
            Unit direction of the axis ``J_a -> J_b`` in the joint's frame in the build pose. With it
            the joint frame ``R`` is first swung by the smallest rotation that carries this direction
            onto the current axis (the twist about the axis stays the joint's): a ring of pins round
            a bone stays square to that bone however the joints between ``J_a`` and ``J_b`` bend.
        roll : (2,) int64, optional
            Joints ``l, r`` of a line the ring rolls with (the skirt's waistband: the hip joints).
            With ``axis`` and ``axis_local``, each pin's offset from its anchor is then turned by the smallest
            rotation that carries the line's component square to the axis onto the line itself:
            a roll about the front-back direction only (no pitch, no twist; none in a standing pose,
            whose hip line is square to the spine), so a waistband tilts with a swinging pelvis
            instead of being crossed by its hip as the pelvis rolls against the chest (up to 40 deg
            in the CMU salsa takes, `60_10`, whose hip rose 97 mm through the ring).
        """
        r = self.rotations[:, pin_joint]  # (K+1, P, 3, 3)
        if axis is None or axis_s is None:
            origin = self.joints[:, pin_joint]
        else:
            s = axis_s[None, :, None]
            origin = (1.0 - s) * self.joints[:, axis[:, 0]] + s * self.joints[:, axis[:, 1]]
        offset: F64 = np.einsum("kpij,pj->kpi", r, pin_local)
        if axis is not None and axis_local is not None:
            u = self.joints[:, axis[:, 1]] - self.joints[:, axis[:, 0]]
            u /= np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
            c = np.einsum("kpij,pj->kpi", r, axis_local)
            offset = swing_vectors(c, u, offset)
            if roll is not None:
                line = self.joints[:, roll[1]] - self.joints[:, roll[0]]  # (K+1, 3)
                line = line / np.maximum(np.linalg.norm(line, axis=-1, keepdims=True), 1e-12)
                line = np.broadcast_to(line[:, None], u.shape)
                square = line - np.einsum("kpi,kpi->kp", line, u)[..., None] * u
                norm = np.linalg.norm(square, axis=-1, keepdims=True)
                ok = norm[..., 0] > 1e-6  # a line along the axis has no roll to follow
                square = square / np.maximum(norm, 1e-12)
                offset = np.where(ok[..., None], swing_vectors(square, line, offset), offset)
        out: F64 = origin + offset
        return out

    def _check_points(self, points: F64) -> None:
        """Raise ValueError unless ``points`` is ``(K + 1, P, 3)`` for this track's keys."""
        if np.ndim(points) != 3 or np.shape(points)[0] != self.track.n_keys or np.shape(points)[2] != 3:
            raise ValueError(f"points must have shape ({self.track.n_keys}, P, 3), got {np.shape(points)}")

    def push_out(self, points: F64, clearance: float) -> F64:
        """``points (K + 1, P, 3)`` moved to at least ``clearance`` outside the body at their key
        (two projection passes over the nearest capsule; reference:
        :func:`cloth_client.contact.seam.push_out_reference`)."""
        self._check_points(points)
        moved = np.array(points, dtype=np.float64, order="C")
        push_out_kernel(moved, np.ascontiguousarray(self.track.a), np.ascontiguousarray(self.track.b),
                        np.ascontiguousarray(self.track.radii), float(clearance), 2)
        return moved

    def slide_seam(self, points: F64, clearance: float, spread: int = 0, wrap: bool = False,
                   rest: F64 | None = None) -> F64:
        """``points (K + 1, P, 3)``, pins in seam order, slid out of the body parts covering them:
        each part's covered pins carried together along one direction, the move spread over
        ``spread`` pins either side with a linear fall-off (round the seam when ``wrap``), pushed
        radially to ``clearance``, then, given the seam's segment rest lengths ``rest (S,)`` (``S =
        P`` when ``wrap``, else ``P - 1``), what is still stretched shortened
        (:meth:`keep_seam_length`). :func:`cloth_client.contact.seam_kernels.slide_seam` documents the
        rule (reference: :func:`cloth_client.contact.seam.slide_seam_reference`)."""
        self._check_points(points)
        if spread < 0:
            raise ValueError(f"spread must be >= 0, got {spread}")
        seg = check_seam_rest(points.shape[1], rest, wrap)
        moved = np.array(points, dtype=np.float64, order="C")
        slide_seam_kernel(moved, np.ascontiguousarray(self.track.a), np.ascontiguousarray(self.track.b),
                          np.ascontiguousarray(self.track.radii), float(clearance), int(spread), bool(wrap), seg)
        return moved

    def keep_seam_length(self, points: F64, clearance: float, rest: F64, rounds: int = SEAM_LENGTH_ROUNDS,
                         slack: float = SEAM_LENGTH_SLACK) -> F64:
        """``points (K + 1, P, 3)``, a seam's pins in order, with every segment ``i -> i + 1`` longer
        than ``(1 + slack) rest[i]`` shortened and the pins kept ``clearance`` outside the body
        (``rest (S,)``: ``S = P`` closes the ring). :func:`cloth_client.contact.seam_kernels.keep_seam_length`
        documents the rule (reference: :func:`cloth_client.contact.seam.keep_seam_length_reference`)."""
        self._check_points(points)
        seg = check_seam_rest(points.shape[1], rest, wrap=np.size(rest) == points.shape[1])
        out = np.array(points, dtype=np.float64, order="C")
        keep_seam_length_kernel(out, np.ascontiguousarray(self.track.a), np.ascontiguousarray(self.track.b),
                                np.ascontiguousarray(self.track.radii), float(clearance), seg, int(rounds),
                                float(slack))
        return out

    def covered(self, points: F64, margin: float | F64) -> NDArray[np.bool_]:
        """Which of ``points (K + 1, P, 3)`` lie within ``margin`` of the body at their key, ``(P,)``
        (true if at any key): a shrugging shoulder over a collar pin, a hand on the waistband.

        ``margin`` is a distance in metres, or one per capsule ``(C,)`` (reference:
        :func:`cloth_client.contact.seam.covered_reference`)."""
        res = np.empty(points.shape[1], dtype=bool)
        reach = np.broadcast_to(np.asarray(margin, dtype=np.float64), (self.track.radii.shape[0],))
        covered_kernel(np.ascontiguousarray(points, dtype=np.float64), self.track.a, self.track.b,
                       self.track.radii, np.ascontiguousarray(reach), res)
        return res


def swing_vectors(c: F64, u: F64, y: F64) -> F64:
    """``y (..., 3)`` rotated by the smallest rotation taking unit ``c`` onto unit ``u`` (same shapes;
    Rodrigues with ``w = c x u``: ``y cos + w x y + w (w . y) / (1 + cos)``)."""
    w = np.cross(c, u)
    cos = np.einsum("...i,...i->...", c, u)[..., None]
    out: F64 = y * cos + np.cross(w, y) + w * np.einsum("...i,...i->...", w, y)[..., None] / np.maximum(1.0 + cos, 1e-9)
    return out


def pose_keys(body: Body, poses: F64, clearance: float | None = LIMB_CLEARANCE,
              limb_memory: F64 | None = None) -> AvatarKeys:
    """Capsules and joint frames of a pose sequence ``(K + 1, P)`` (one FK call for all keys).

    With ``clearance`` (metres; None: the recorded limbs) knees that come within two cloth margins
    of each other are turned apart (:func:`~cloth_client.avatar.leg_clearance.clear_legs`), then sunk
    upper arms, forearms and hands are turned out of
    the trunk (:func:`~cloth_client.avatar.limb_clearance.clear_limbs_track`, continuing from
    ``limb_memory``, the previous step's :attr:`AvatarKeys.limb_memory`, whose last key is
    ``poses[0]``); ``joints`` stay the recorded ones.
    """
    joints, rot = fk_global(np.atleast_2d(poses), body)
    a = joints[:, CAPSULE_JOINTS[:, 0]]
    b = joints[:, CAPSULE_JOINTS[:, 1]]
    memory = None
    if clearance is not None:
        a, b = clear_legs(a, b, body.capsule_radii)
        a, b, memory = clear_limbs_track(a, b, body.capsule_radii, limb_memory, clearance,
                                         first_given=limb_memory is not None)
    return AvatarKeys(CapsuleTrack(a, b, body.capsule_radii), joints, rot, memory)


def avatar_capsules(body: Body, poses: F64, clearance: float | None = LIMB_CLEARANCE) -> tuple[F64, F64]:
    """Capsule endpoints of the avatar the cloth is dressed on: :func:`capsule_endpoints` with the
    knees kept apart and sunk upper arms, forearms and hands turned out of the trunk (``(N, C, 3)``,
    or ``(C, 3)`` for one pose ``(P,)``; the poses are taken as consecutive keys, each continuing
    the previous one's corrections)."""
    a, b = capsule_endpoints(body, poses)
    if clearance is None:
        return a, b
    a, b = clear_legs(a, b, body.capsule_radii)
    return clear_limbs(a, b, body.capsule_radii, clearance)


@dataclass(frozen=True)
class Continuity:
    """Thresholds that separate fast human motion from a jump of the input.

    Attributes
    ----------
    max_joint_speed : float
        m/s; the fastest human joint motion (a kicking foot, a throwing hand) stays below ~20 m/s.
    max_root_speed : float
        m/s; a sprint reaches ~10 m/s.
    max_gap_s : float
        Longest gap between two frames that is still bridged by interpolation, seconds.
    """

    max_joint_speed: float = 25.0
    max_root_speed: float = 12.0
    max_gap_s: float = 0.5


def is_discontinuity(body: Body, p0: F64, p1: F64, dt: float, limits: Continuity | None = None,
                     joints: tuple[F64, F64] | None = None) -> bool:
    """True if going from pose ``p0`` to ``p1`` in ``dt`` seconds is not a plausible human motion.

    Parameters
    ----------
    body : Body
    p0, p1 : (P,) float64
    dt : float
        Time between the two poses, seconds (<= 0 counts as a discontinuity).
    limits : Continuity, optional
    joints : ((J, 3), (J, 3)) float64, optional
        The two poses' joint positions when the caller has them (default: computed here).
    """
    lim = limits or Continuity()
    if not dt > 0 or dt > lim.max_gap_s:
        return True
    if np.linalg.norm(p1[:3] - p0[:3]) > lim.max_root_speed * dt:
        return True
    if joints is None:
        j, _ = fk_global(np.stack([p0, p1]), body)  # one batched FK for both poses
        j0, j1 = j[0], j[1]
    else:
        j0, j1 = joints
    return bool(np.linalg.norm(j1 - j0, axis=-1).max() > lim.max_joint_speed * dt)


def rigid_root_delta(p0: F64, p1: F64) -> tuple[F64, F64]:
    """Rigid motion ``x -> R x + t`` that carries the root frame of pose ``p0`` onto that of ``p1``.

    Returns
    -------
    R : (3, 3) float64
    t : (3,) float64
    """
    r0 = rotvec_to_matrix(p0[3:6])
    r1 = rotvec_to_matrix(p1[3:6])
    rot: F64 = r1 @ r0.T
    return rot, p1[:3] - rot @ p0[:3]
