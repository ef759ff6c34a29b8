"""Body-size- and facing-normalised features of one pose frame, for the gesture recogniser.

Pure code: joint positions in, small feature records out; no clock, no I/O.

Body frame
----------
Each frame gets a body frame from the hips and shoulders: ``up`` is world +Y (gravity), ``left``
is the horizontal direction of ``(l_hip - r_hip) + (l_shoulder - r_shoulder)`` (each normalised)
and ``forward = left x up`` (the way the chest faces). Arm joints are expressed relative to the
shoulder mid-point as ``(lateral, up, forward)`` where ``lateral`` is measured *outwards* for
each arm (positive = away from the midline on that arm's own side), so the left and right arm
read the same in a symmetric pose. Every length is divided by the body height ``H``.

Body height
-----------
``H`` is estimated online from bone lengths, which do not change with the pose (so a player who
starts crouched or with raised arms is measured as well as one standing): leg (hip-knee-ankle),
torso (pelvis-spine-chest-neck) and arm (shoulder-elbow-wrist) chains are divided by their share
of stature in :func:`protocol.skeleton.body_from_measurements` (0.491, 0.300 and 0.332). Only
visible chains count. The estimate is an exponential average (time constant
:attr:`FeatureConfig.height_tau_s`) with each new value clipped to +-15 % of the current one, so a
single wild frame cannot move it far.

Visibility
----------
``PoseFrame.visibility`` gives the visible fraction of each of the 15 body parts. A joint group
is used only if all its parts are at least :attr:`FeatureConfig.min_visibility` visible and its
joints are finite; otherwise the matching ``*_ok`` flag is false and the recogniser holds the
affected state machines instead of reading guessed joints.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import JOINT_INDEX, N_JOINTS, N_PARTS, PARTS

__all__ = ["ARM_SHARE", "LEG_SHARE", "TORSO_SHARE", "FeatureConfig", "FeatureExtractor", "FrameFeatures",
           "ScreenFacing"]

_J = JOINT_INDEX
_P = {name: i for i, name in enumerate(PARTS)}
#: Share of stature of the hip-knee-ankle chain (thigh 0.245 + shin 0.246).
LEG_SHARE: Final[float] = 0.491
#: Share of stature of the pelvis-spine-chest-neck chain.
TORSO_SHARE: Final[float] = 0.300
#: Share of stature of the shoulder-elbow-wrist chain (upper arm 0.186 + forearm 0.146).
ARM_SHARE: Final[float] = 0.332
_ARM_ROWS: Final[tuple[int, ...]] = (_J["l_wrist"], _J["r_wrist"], _J["l_elbow"], _J["r_elbow"])
_TORSO_PARTS: Final[tuple[int, ...]] = (_P["pelvis"], _P["torso"])
_LARM_PARTS: Final[tuple[int, ...]] = (_P["l_upper_arm"], _P["l_forearm"])
_RARM_PARTS: Final[tuple[int, ...]] = (_P["r_upper_arm"], _P["r_forearm"])
_LEG_PARTS: Final[tuple[int, ...]] = (_P["l_thigh"], _P["l_shin"], _P["r_thigh"], _P["r_shin"])


@dataclass(frozen=True)
class FeatureConfig:
    """Parameters of :class:`FeatureExtractor`.

    Attributes
    ----------
    min_visibility : float
        A body part less visible than this (fraction of its area) counts as occluded.
    height_tau_s : float
        Time constant of the body-height average, seconds.
    smooth_tau_s : float
        Time constant of the exponential smoothing of the arm and crouch features, seconds
        (against tracker jitter; the delay it adds is about this long).
    facing_tau_s : float
        Time constant of the smoothing of the body's left axis (the facing direction), seconds.
    """

    min_visibility: float = 0.1
    height_tau_s: float = 2.0
    smooth_tau_s: float = 0.03
    facing_tau_s: float = 0.1


@dataclass(frozen=True)
class ScreenFacing:
    """Where the game's screen (and camera) is, for rules that a single-camera tracker's heading
    would otherwise break.

    The player of the game faces the screen. A single camera measures where the body is (its
    ground position, the image-plane coordinates of the hands) much better than which way the hips
    point: on tracked game scripts the facing swings by up to 35 degrees either way for a fraction
    of a second while the legs are apart or the arms up, while the true facing does not move.
    Rules that need the player not to turn (the side-step's axes and turn limit, the "made in
    place" rule of the arm gestures and the crouch) also accept a motion during which the player
    *faced the screen*: the facing stayed within ``max_deg`` of ``yaw_deg`` and was on average
    within ``mean_deg`` of it (a wander swings both ways and back; a player turned towards a side,
    or turning for real, is off on average).

    Attributes
    ----------
    yaw_deg : float
        Facing of a player looking straight at the screen, degrees about +Y (0 = facing +Z, the
        tracker's camera convention).
    max_deg : float
        The facing must stay within this of ``yaw_deg`` (the tracker's game mode confines it to
        35 degrees).
    mean_deg : float
        The mean absolute difference between the facing and ``yaw_deg`` over the motion must not
        exceed this (15, the side-step's: tracked steps need up to 12 degrees, the first real take
        to give a false side-step 18; sideways walks turned 33-38 degrees away from the camera are
        rejected. The in-place rule uses 30: tracked fire rings need up to 19).
    """

    yaw_deg: float = 0.0
    max_deg: float = 40.0
    mean_deg: float = 15.0

    def faced(self, yaw: NDArray[np.float64]) -> NDArray[np.bool_]:
        """For a facing history ``yaw`` (radians, oldest first), whether the player faced the screen
        from each sample to the last one (the last sample's own entry included)."""
        off = np.abs((yaw[::-1] - math.radians(self.yaw_deg) + math.pi) % (2 * math.pi) - math.pi)
        n = np.arange(1, len(off) + 1)
        ok = (np.maximum.accumulate(off) <= math.radians(self.max_deg)) & (np.cumsum(off) / n
                                                                           <= math.radians(self.mean_deg))
        return ok[::-1]


Vec3 = tuple[float, float, float]
Vec2 = tuple[float, float]


@dataclass(slots=True)
class FrameFeatures:
    """Features of one frame (see the module docstring for the frame and units).

    Attributes
    ----------
    t : float
        Stream time, seconds.
    ok : bool
        The torso was usable, so the body frame is valid. When false, nothing else is valid.
    height : float
        Body height estimate ``H``, metres.
    yaw : float
        Facing direction, radians about +Y (0 = facing +Z, positive turns towards +X).
    left_xz : (float, float)
        World x/z of the body's left axis (unit vector).
    wrist_l, wrist_r, elbow_l, elbow_r : (float, float, float)
        ``(outward, up, forward) / H`` of each joint relative to the shoulder mid-point
        (smoothed).
    bend_l, bend_r : float
        Elbow bend of each arm, degrees (0 = straight; the angle between the upper arm and the
        forearm, smoothed). Read from the arm's own bones, so it does not depend on where the body
        is or faces; NaN when not computed.
    arm_l_ok, arm_r_ok : bool
        Upper arm and forearm of that side visible and finite.
    crouch : float
        Pelvis height above the lower ankle divided by the leg length: about 1 standing, 0.5 in a
        deep squat (smoothed). NaN when the legs are not usable.
    legs_ok : bool
        Both thighs and shins visible and finite.
    pelvis_xz, ankle_l_xz, ankle_r_xz : (float, float)
        World x/z positions, metres (not smoothed; the side-step detector measures displacements).
        The ankles are ``None`` unless ``legs_ok``.
    ankle_low_y : float
        World height of the lower ankle, metres (NaN unless ``legs_ok``); for jump detection.
    pelvis_y : float
        World height of the pelvis, metres (NaN unless ``legs_ok``); for jump detection.
    confidence : float
        The tracker's confidence in this frame, [0, 1].
    """

    t: float
    ok: bool
    height: float
    yaw: float = 0.0
    left_xz: Vec2 | None = None
    wrist_l: Vec3 | None = None
    wrist_r: Vec3 | None = None
    elbow_l: Vec3 | None = None
    elbow_r: Vec3 | None = None
    bend_l: float = math.nan
    bend_r: float = math.nan
    arm_l_ok: bool = False
    arm_r_ok: bool = False
    crouch: float = math.nan
    legs_ok: bool = False
    pelvis_xz: Vec2 | None = None
    ankle_l_xz: Vec2 | None = None
    ankle_r_xz: Vec2 | None = None
    ankle_low_y: float = math.nan
    pelvis_y: float = math.nan
    confidence: float = 1.0


def _chain(j: list[list[float]], idx: tuple[int, ...]) -> float:
    """Summed bone length along a chain of joint indices (pure Python: faster than numpy here)."""
    total = 0.0
    for a, b in itertools.pairwise(idx):
        pa, pb = j[a], j[b]
        total += math.sqrt((pb[0] - pa[0]) ** 2 + (pb[1] - pa[1]) ** 2 + (pb[2] - pa[2]) ** 2)
    return total


def _bend_deg(j: list[list[float]], idx: tuple[int, ...]) -> float:
    """Bend at the middle joint of the chain ``idx`` (shoulder, elbow, wrist), degrees: 0 when
    straight, 90 for a right angle. 0 if a bone has no length."""
    a, b, c = j[idx[0]], j[idx[1]], j[idx[2]]
    ux, uy, uz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    vx, vy, vz = c[0] - b[0], c[1] - b[1], c[2] - b[2]
    nn = math.sqrt((ux * ux + uy * uy + uz * uz) * (vx * vx + vy * vy + vz * vz))
    if nn < 1e-12:
        return 0.0
    return math.degrees(math.acos(min(max((ux * vx + uy * vy + uz * vz) / nn, -1.0), 1.0)))


def _ids(*names: str) -> tuple[int, ...]:
    return tuple(_J[n] for n in names)


_LEG_L, _LEG_R = _ids("l_hip", "l_knee", "l_ankle"), _ids("r_hip", "r_knee", "r_ankle")
_TORSO = _ids("pelvis", "spine", "chest", "neck")
_ARM_L, _ARM_R = _ids("l_shoulder", "l_elbow", "l_wrist"), _ids("r_shoulder", "r_elbow", "r_wrist")
_TORSO_JOINTS = _ids("pelvis", "spine", "chest", "neck", "l_hip", "r_hip", "l_shoulder", "r_shoulder")
_LEG_JOINTS = _LEG_L + _LEG_R


class FeatureExtractor:
    """Streaming feature extraction with an online body-height estimate.

    Parameters
    ----------
    config : FeatureConfig, optional
    height_m : float, optional
        Known body height (e.g. ``BodyInfo.measurements["height_m"]``); the starting value of the
        online estimate. Without it the first usable frame sets it.
    """

    def __init__(self, config: FeatureConfig | None = None, height_m: float | None = None) -> None:
        self.config = config or FeatureConfig()
        self._height_hint = height_m
        self.height: float | None = None
        self.leg_len: float | None = None
        self.reset(keep_height=False)

    def reset(self, keep_height: bool = True) -> None:
        """Forget the smoothing state (after a stream gap); keep the body height unless told not to."""
        if not keep_height:
            self.height = self._height_hint
            self.leg_len = None if self._height_hint is None else LEG_SHARE * self._height_hint
        self._t: float | None = None
        self._arm: list[float] | None = None  # 14 smoothed arm features: lw, rw, le, re, bend l, bend r
        self._crouch: float = math.nan
        self._left: Vec2 | None = None

    @staticmethod
    def _alpha(dt: float, tau: float) -> float:
        return 1.0 if dt <= 0 or tau <= 0 else 1.0 - math.exp(-dt / tau)

    def _update_height(self, j: list[list[float]], torso: bool, l_arm: bool, r_arm: bool, legs: bool,
                       dt: float) -> None:
        num = den = 0.0
        leg = math.nan
        if legs:
            leg = 0.5 * (_chain(j, _LEG_L) + _chain(j, _LEG_R))
            num, den = num + leg, den + LEG_SHARE
        if torso:
            num, den = num + _chain(j, _TORSO), den + TORSO_SHARE
        if l_arm or r_arm:
            arms = [_chain(j, c) for c, ok in ((_ARM_L, l_arm), (_ARM_R, r_arm)) if ok]
            num, den = num + sum(arms) / len(arms), den + ARM_SHARE
        if den == 0.0 or num <= 0.0:
            return
        est = num / den
        a = self._alpha(dt, self.config.height_tau_s)
        if self.height is None:
            self.height = est
        else:
            self.height += a * (min(max(est, 0.85 * self.height), 1.15 * self.height) - self.height)
        if legs and leg > 0:
            if self.leg_len is None:
                self.leg_len = leg
            else:
                self.leg_len += a * (min(max(leg, 0.85 * self.leg_len), 1.15 * self.leg_len) - self.leg_len)

    def update(self, t: float, joints: NDArray[np.floating], visibility: NDArray[np.floating] | None = None,
               confidence: float = 1.0) -> FrameFeatures:
        """Features of one frame.

        Parameters
        ----------
        t : float
            Stream time, seconds (frames must come in increasing time; call :meth:`reset` after a
            jump back).
        joints : (J, 3) float
            World joint positions, metres, Y up (J = 24, order of :data:`protocol.skeleton.JOINT_NAMES`).
        visibility : (N_PARTS,) float, optional
            Visible fraction of each body part (default: all visible).
        confidence : float
            Tracker confidence of the frame.

        Returns
        -------
        FrameFeatures
        """
        arr = np.asarray(joints, dtype=np.float64)
        if arr.shape != (N_JOINTS, 3):
            raise ValueError(f"joints must be ({N_JOINTS}, 3), got {arr.shape}")
        cfg = self.config
        j: list[list[float]] = arr.tolist()
        seen: list[bool]
        finite: list[bool]
        if visibility is None:
            seen = [True] * N_PARTS
        else:
            vis = np.asarray(visibility, dtype=np.float64)
            if vis.shape != (N_PARTS,):
                raise ValueError(f"visibility must be ({N_PARTS},), got {vis.shape}")
            seen = [bool(x) for x in vis >= cfg.min_visibility]
        if bool(np.isfinite(arr).all()):
            finite = [True] * N_JOINTS
        else:
            finite = [bool(np.isfinite(row).all()) for row in arr]

        def usable(parts: tuple[int, ...], idx: tuple[int, ...]) -> bool:
            return all(seen[p] for p in parts) and all(finite[i] for i in idx)

        dt = 0.0 if self._t is None else t - self._t
        self._t = t
        torso = usable(_TORSO_PARTS, _TORSO_JOINTS)
        l_arm, r_arm = usable(_LARM_PARTS, _ARM_L), usable(_RARM_PARTS, _ARM_R)
        legs = usable(_LEG_PARTS, _LEG_JOINTS)
        self._update_height(j, torso, l_arm, r_arm, legs, dt)
        if not torso or self.height is None:
            return FrameFeatures(t=t, ok=False, height=self.height or math.nan, confidence=confidence)
        h = self.height
        lh, rh, ls, rs = j[_J["l_hip"]], j[_J["r_hip"]], j[_J["l_shoulder"]], j[_J["r_shoulder"]]
        hx, hz, sx, sz = lh[0] - rh[0], lh[2] - rh[2], ls[0] - rs[0], ls[2] - rs[2]
        hn, sn = math.hypot(hx, hz) + 1e-9, math.hypot(sx, sz) + 1e-9
        lx, lz = hx / hn + sx / sn, hz / hn + sz / sn
        norm = math.hypot(lx, lz)
        if norm < 1e-6:  # hips and shoulders point opposite ways: keep the last frame's axis
            if self._left is None:
                return FrameFeatures(t=t, ok=False, height=h, confidence=confidence)
            lx, lz = self._left
        elif self._left is None:
            lx, lz = lx / norm, lz / norm
        else:  # smooth the axis (as a vector, so it turns through +-180 deg correctly)
            b = self._alpha(dt, cfg.facing_tau_s)
            lx, lz = self._left[0] + b * (lx / norm - self._left[0]), self._left[1] + b * (lz / norm - self._left[1])
            norm = math.hypot(lx, lz)
            lx, lz = (lx / norm, lz / norm) if norm > 1e-6 else self._left
        self._left = (lx, lz)
        # body axes: left = (lx, 0, lz), up = (0, 1, 0), forward = left x up = (-lz, 0, lx)
        mx, my, mz = 0.5 * (ls[0] + rs[0]), 0.5 * (ls[1] + rs[1]), 0.5 * (ls[2] + rs[2])
        arm: list[float] = []
        for k, sign in zip(_ARM_ROWS, (1.0, -1.0, 1.0, -1.0), strict=True):  # right arm: outward = -left
            px, py, pz = j[k][0] - mx, j[k][1] - my, j[k][2] - mz
            arm += [sign * (px * lx + pz * lz) / h, py / h, (-px * lz + pz * lx) / h]
        arm += [_bend_deg(j, _ARM_L), _bend_deg(j, _ARM_R)]
        a = self._alpha(dt, cfg.smooth_tau_s)
        if self._arm is None:
            self._arm = arm
        else:
            self._arm = [s + a * (x - s) for s, x in zip(self._arm, arm, strict=True)]
        pel = j[_J["pelvis"]]
        crouch = low = math.nan
        if legs and self.leg_len:
            low = min(j[_J["l_ankle"]][1], j[_J["r_ankle"]][1])
            raw = (pel[1] - low) / self.leg_len
            self._crouch = raw if math.isnan(self._crouch) else self._crouch + a * (raw - self._crouch)
            crouch = self._crouch
        feet = legs and not math.isnan(crouch)
        sm = self._arm
        al, ar = j[_J["l_ankle"]], j[_J["r_ankle"]]
        return FrameFeatures(
            t=t, ok=True, height=h, yaw=math.atan2(-lz, lx), left_xz=(lx, lz),
            wrist_l=(sm[0], sm[1], sm[2]), wrist_r=(sm[3], sm[4], sm[5]),
            elbow_l=(sm[6], sm[7], sm[8]), elbow_r=(sm[9], sm[10], sm[11]), bend_l=sm[12], bend_r=sm[13],
            arm_l_ok=l_arm, arm_r_ok=r_arm, crouch=crouch, legs_ok=feet,
            pelvis_xz=(pel[0], pel[2]),
            ankle_l_xz=(al[0], al[2]) if feet else None,
            ankle_r_xz=(ar[0], ar[2]) if feet else None,
            ankle_low_y=low, pelvis_y=pel[1] if feet else math.nan, confidence=float(confidence),
        )

    def run(self, times: NDArray[np.floating], joints: NDArray[np.floating],
            visibility: NDArray[np.floating] | None = None) -> list[FrameFeatures]:
        """Features of a whole sequence (a loop over :meth:`update`).

        Parameters
        ----------
        times : (N,) float
        joints : (N, J, 3) float
        visibility : (N, N_PARTS) float, optional
        """
        return [self.update(float(times[k]), joints[k], None if visibility is None else visibility[k])
                for k in range(len(times))]
