"""State machines of the two whole-body gestures: crouch (dodge high) and side-step (dodge sideways).

See :mod:`game_client.detectors` for what each gesture means, the units and the conventions
(timing windows in seconds, distances in body heights, hysteresis, occlusion holds).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .detectors import Candidate, clip01
from .features import FrameFeatures, ScreenFacing

__all__ = ["CrouchDetector", "CrouchParams", "SideStepDetector", "SideStepParams"]

log = logging.getLogger(__name__)


def _follow(current: float | None, x: float, dt: float, tau_down: float, tau_up: float) -> float:
    """``current`` moved toward ``x`` over ``dt`` seconds with time constant ``tau_down`` when ``x``
    is below it and ``tau_up`` when above (0: at once); ``x`` itself when there is no ``current``."""
    if current is None:
        return x
    tau = tau_down if x < current else tau_up
    return x if tau <= 0.0 else current + (1.0 - math.exp(-dt / tau)) * (x - current)


@dataclass(frozen=True)
class CrouchParams:
    """Thresholds of the crouch (pelvis height above the lower ankle / leg length)."""

    stand_min: float = 0.88
    crouch_max: float = 0.65
    hold_s: float = 0.05
    airborne_h: float = 0.05
    airborne_pelvis: float = 0.03  # ... with the pelvis within this (x H) of its standing height: legs straight
    landing_s: float = 0.4
    occlusion_hold_s: float = 0.5


class CrouchDetector:
    """Going down from standing into a crouch (knees bent, pelvis low)."""

    def __init__(self, p: CrouchParams) -> None:
        self.p = p
        self.reset()

    def reset(self) -> None:
        self.state = "unknown"
        self.t_stand = self.t_cross = self.t_seen = self.t_air = -math.inf
        self.floor: float | None = None
        self.stand_pelvis: float | None = None  # the pelvis's height above the floor standing (see update)
        self.low = math.inf

    def update(self, f: FrameFeatures) -> Candidate | None:
        p = self.p
        ankle_low_y = f.ankle_low_y
        if not (f.ok and f.legs_ok):
            if f.t - self.t_seen > p.occlusion_hold_s:
                self.reset()
            return None
        dt = f.t - self.t_seen if self.t_seen > -math.inf else 0.0
        self.t_seen = f.t
        # the floor follows the lower ankle down quickly and up slowly (robust to one bad frame)
        self.floor = _follow(self.floor, ankle_low_y, dt, tau_down=0.15, tau_up=3.0)
        pelvis = f.pelvis_y - self.floor
        # both feet off the floor is a jump only with the legs straight, the pelvis near its standing
        # height (a tracker whose feet lift as the person squats would otherwise hide the crouch)
        legs_straight = self.stand_pelvis is None or pelvis >= self.stand_pelvis - p.airborne_pelvis * f.height
        if ankle_low_y - self.floor > p.airborne_h * f.height and legs_straight:
            self.t_air = f.t
        c = f.crouch
        if c >= p.stand_min:
            self.state, self.t_stand = "standing", f.t
            # the standing pelvis follows a rise at once, a lower stance over a second or so
            self.stand_pelvis = _follow(self.stand_pelvis, pelvis, dt, tau_down=1.0, tau_up=0.0)
        elif self.state == "standing" and c <= p.crouch_max:
            self.state, self.t_cross, self.low = "crossing", f.t, c
        elif self.state == "crossing":
            self.low = min(self.low, c)
            if c > p.crouch_max + 0.03:
                self.state = "standing_pending"
            elif f.t - self.t_cross >= p.hold_s:
                self.state = "crouched"
                if f.t - self.t_air > p.landing_s:
                    return Candidate(self.t_stand, self.t_cross, clip01((p.crouch_max - self.low) / 0.15) * 0.5 + 0.5)
        elif self.state == "standing_pending" and c <= p.crouch_max:
            self.state, self.t_cross, self.low = "crossing", f.t, c
        return None


@dataclass(frozen=True)
class SideStepParams:
    """Thresholds of the side-step (displacements in body heights along the body axes)."""

    window_s: float = 2.0
    pelvis_min: float = 0.17
    fwd_ratio_max: float = 0.4
    foot_min: float = 0.17
    max_turn_deg: float = 20.0
    min_speed: float = 0.12  # average lateral pelvis speed over the step, body heights per second
    settle_s: float = 0.2
    settle_speed: float = 0.2
    refractory_s: float = 0.4
    trail_min: float = 0.12  # the trailing foot follows at least this far (the body relocates: not a lunge)
    capacity: int = 512


@dataclass
class SideStepDetector:
    """A step to the player's left or right (pelvis and leading foot move sideways).

    With ``screen``, a step also counts when the displacement conditions hold along the screen's
    axes instead of the body's and the player faced the screen during it
    (:class:`~game_client.features.ScreenFacing`; the turn limit is then not applied): the tracked
    facing swings by up to 35 degrees while the legs are apart, the tracked ground positions do not.
    """

    p: SideStepParams
    screen: ScreenFacing | None = None
    _buf: NDArray[np.float64] = field(init=False)
    _n: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        self._buf = np.zeros((self.p.capacity, 8))  # t, pelvis x/z, l ankle x/z, r ankle x/z, yaw
        self.reset()

    def reset(self) -> None:
        self._n = 0
        self.t_fire = -math.inf

    def update(self, f: FrameFeatures) -> Candidate | None:
        p = self.p
        if not f.ok or f.pelvis_xz is None or f.ankle_l_xz is None or f.ankle_r_xz is None or f.left_xz is None:
            return None  # occluded legs: skip the frame; old samples age out of the window
        yaw = f.yaw
        if self._n:  # unwrap the facing angle against the previous sample
            prev = self._buf[self._n - 1, 7]
            yaw = prev + (yaw - prev + math.pi) % (2 * math.pi) - math.pi
        row = (f.t, *f.pelvis_xz, *f.ankle_l_xz, *f.ankle_r_xz, yaw)
        keep = self._buf[: self._n]
        first = int(np.searchsorted(keep[:, 0], f.t - p.window_s)) if self._n else 0
        if first > 0 or self._n == p.capacity:
            first = max(first, 1)
            self._buf[: self._n - first] = keep[first:]
            self._n -= first
        self._buf[self._n] = row
        self._n += 1
        if self._n < 2 or f.t - self.t_fire < p.refractory_s:
            return None
        b = self._buf[: self._n]
        recent = int(np.searchsorted(b[:, 0], f.t - p.settle_s))
        if recent >= self._n - 1 or b[recent, 0] > f.t - 0.5 * p.settle_s:
            return None  # not enough history to tell whether the body has come to rest
        speed = math.hypot(b[-1, 1] - b[recent, 1], b[-1, 2] - b[recent, 2]) / (f.t - b[recent, 0]) / f.height
        if speed > p.settle_speed:
            return None  # still moving: wait until the step is finished
        reach = (b[:, 1] - b[-1, 1]) ** 2 + (b[:, 2] - b[-1, 2]) ** 2
        if float(reach.max()) < (p.pelvis_min * f.height) ** 2:
            return None  # the pelvis has not been far from here within the window
        d = b[-1, 1:7] - b[:-1, 1:7]  # displacement from each past sample to now
        yaw_hist = b[::-1, 7]  # facing range from each past sample to now (the body may turn and back)
        turn = (np.maximum.accumulate(yaw_hist) - np.minimum.accumulate(yaw_hist))[::-1][:-1]
        ok, pel, fwd, lead = self._conditions(f, d, f.left_xz, turn <= math.radians(p.max_turn_deg))
        if self.screen is not None and not ok.any():
            psi = math.radians(self.screen.yaw_deg)
            facing = self.screen.faced(b[:, 7])[:-1]
            ok, pel, fwd, lead = self._conditions(f, d, (math.cos(psi), -math.sin(psi)), facing)
        if not ok.any():
            return None
        k = int(np.flatnonzero(ok)[np.argmax(np.abs(pel[ok]))])
        direction = "left" if pel[k] > 0 else "right"
        score = (0.5 * clip01((abs(pel[k]) - p.pelvis_min) / 0.1)
                 + 0.5 * clip01(1 - abs(fwd[k]) / (abs(pel[k]) + 1e-9)))
        self.t_fire = f.t
        # the step started when the pelvis last stood (nearly) where it was at sample k
        log.debug("side-step %s at %.2f s: pelvis %.3f H sideways, %.3f H forwards, lead foot %.3f H, turn %.1f deg,"
                  " over %.2f s", direction, f.t, pel[k], fwd[k], lead[k], math.degrees(float(turn[k])), f.t - b[k, 0])
        before = np.flatnonzero(np.sign(pel[k]) * pel >= 0.9 * abs(pel[k]))
        start = float(b[int(before.max()), 0])
        self._n = 0
        return Candidate(start, f.t, score, direction)

    def _conditions(self, f: FrameFeatures, d: NDArray[np.float64], left_xz: tuple[float, float],
                    facing_ok: NDArray[np.bool_]) -> tuple[NDArray[np.bool_], NDArray[np.float64],
                                                           NDArray[np.float64], NDArray[np.float64]]:
        """The step conditions for each past sample, measured along the horizontal axes given by
        ``left_xz`` (the left axis; forward = left x up). Returns ``(ok, pelvis sideways, pelvis
        forwards, leading foot sideways)`` per sample, in body heights."""
        p = self.p
        lx, lz = left_xz
        lat = (d[:, [0, 2, 4]] * lx + d[:, [1, 3, 5]] * lz) / f.height  # pelvis, l ankle, r ankle
        fwd = (-d[:, 0] * lz + d[:, 1] * lx) / f.height
        pel = lat[:, 0]
        left = pel > 0  # stepping left: the left foot leads
        lead = np.where(left, lat[:, 1], -lat[:, 2])
        trail = np.where(left, lat[:, 2], -lat[:, 1])
        lead_fwd = np.where(left, -d[:, 2] * lz + d[:, 3] * lx, -d[:, 4] * lz + d[:, 5] * lx) / f.height
        elapsed = f.t - self._buf[: self._n - 1, 0]
        ok = ((np.abs(pel) >= p.pelvis_min) & (np.abs(fwd) <= p.fwd_ratio_max * np.abs(pel))
              & (lead >= p.foot_min) & (np.abs(lead_fwd) <= p.fwd_ratio_max * lead)
              & facing_ok & (np.abs(pel) >= p.min_speed * elapsed) & (trail >= p.trail_min))
        return ok, pel, fwd, lead
