"""The five gesture state machines of the game (Okada & Stenger, §4), over :class:`FrameFeatures`.

The arm gestures (transform, strike, fire ring) are here; the crouch and the side-step are in
:mod:`game_client.body_detectors`.

Each detector reads one frame's features and returns a :class:`Candidate` on the frame where its
gesture completes. Timing windows are in seconds and distances in body heights ``H`` (see
:mod:`game_client.features`), so the same thresholds hold at 15-120 Hz and for any body size.
Every threshold that separates an "in" from an "out" state has hysteresis, so tracker jitter
around a threshold cannot toggle a state on every frame. When the joints a detector needs are
occluded it keeps its state for up to ``occlusion_hold_s`` and then starts over.

What each gesture means here (``up``/``out``/``fwd`` of a wrist are relative to the shoulder
mid-point in body heights, ``out`` measured away from the midline on the wrist's own side). Arm
gestures are rejected while the wrist path shows a wave (more than 4 direction reversals of at
least 0.06 H), and :class:`~game_client.gestures.GestureRecognizer` also drops arm gestures and
crouches made while the body turned or travelled (a dance, a walk).

transform
    Both wrists out to the sides near shoulder height (``out >= 0.28``, ``|up| <= 0.12``) for
    0.12 s, then within 2 s both wrists resting on the chest (``out <= 0.13``,
    ``-0.26 <= up <= 0.02``, ``0 <= fwd <= 0.22``, out and up moving < 0.08 H) for 0.06 s. Ends when the
    hands reach the chest. (A single camera sees hands in front of the torso only inside its
    silhouette: the tracker reports hands on the chest lower and wider than they are, hands
    hanging at the sides at >= 0.11 H out and below -0.26.) Or, where the tracker puts the hands
    where hanging hands would be, the elbows tell: if the arms were seen straight in the T (mean
    elbow bend <= 25 deg) and folded (>= 60 deg) while the wrists were still >= 0.18 H out, within
    0.6 s, both elbows bent (mean >= 40 deg, each >= 25) with the wrists in front of the torso
    (``out <= 0.20``, ``-0.33 <= up <= -0.10``: not at the face) held 0.12 s also count.
crouch (:mod:`game_client.body_detectors`)
    From standing (pelvis height over the lower ankle >= 0.88 leg lengths) down to <= 0.65 leg
    lengths held for 0.05 s, not within 0.4 s of both feet leaving the floor (a jump landing; feet
    off the floor count only with the pelvis within 0.03 H of its standing height, legs straight).
    Ends when the ratio crosses 0.65.
side_step (:mod:`game_client.body_detectors`)
    Within 2 s the pelvis moves >= 0.17 H along the body's left/right axis at >= 0.12 H/s on
    average, with at most 0.4 of that forwards/backwards; the leading foot moves >= 0.17 H the
    same way (also mostly sideways); the facing stays within 20 deg; and the pelvis has come to
    rest (< 0.2 H/s over 0.2 s). Or the same along the screen's axes, without the turn limit, if
    the player faced the screen (:class:`~game_client.features.ScreenFacing`). Ends on that
    frame; ``direction`` is the player's ``left`` or ``right``.
strike
    The right wrist rises above the head line (``up >= 0.10``) while the left wrist stays below
    ``up = -0.10`` (or holds the same grip: wrists within 0.15 H, as in a two-handed chop) and is
    seen in >= 30 % of the frames, then falls from ``up = 0.05`` to ``up = -0.15`` in <= 0.14 s
    (>= 1.4 H/s) in front of the body (mean ``fwd >= 0`` through that band: a chop towards the
    opponent, not an arm circle coming down at the side or behind), and not as a loop: at the
    heights -0.10, -0.05, 0 and 0.05 the wrist comes down on average at most 0.025 H further out
    than it went up (an arm circle goes up in front and comes down at the side, outside its way
    up; a strike comes down its way up or inside it). Ends when it passes ``-0.15``.
fire_ring
    Both wrists rise to ``up >= -0.08`` (about shoulder height or above), apart (>= 0.12 H) and at
    some point not stretched out sideways for 0.1 s in a row (``out <= 0.36``: not a T-pose, nor
    arms passing in from a T towards the chest), for 0.45-3.3 s, then
    both fall to ``up <= -0.22`` within 0.5 s of leaving that zone and within 1 s of the lower
    wrist leaving the top (its highest point less 0.05 H: the whole lowering is quick, not only
    its last part; the slowest real fire ring takes 0.72 s). The raise must be seen: after
    a reset (stream start, gap, glitch, long occlusion) the arms must first be seen below the
    raised zone (``up < -0.10``), so arms that are already up when the recogniser joins and are
    then dropped do not count. A raise that starts within 0.6 s of the previous drop (any drop
    from the raised zone, seen raise or not) is rhythmic (a waving of both arms) and ignored.
    Ends when the second wrist passes ``-0.22``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Protocol

from .features import FrameFeatures, Vec3

__all__ = [
    "Candidate", "FireRingDetector", "FireRingParams", "StrikeDetector", "StrikeParams", "TransformDetector",
    "TransformParams", "clip01",
]

log = logging.getLogger(__name__)


class _Occludable(Protocol):
    t_seen: float

    def reset(self) -> None: ...


def _seen(det: _Occludable, t: float, visible: bool, hold_s: float) -> bool:
    """Common occlusion handling: a detector whose arms are not visible keeps its state for
    ``hold_s`` seconds, then resets; returns whether this frame can be used."""
    if not visible:
        if t - det.t_seen > hold_s:
            det.reset()
        return False
    det.t_seen = t
    return True


@dataclass(frozen=True)
class Candidate:
    """A completed gesture as a detector reports it (times in stream seconds)."""

    start_s: float
    end_s: float
    score: float  # margin-based quality in [0, 1]
    direction: str | None = None


def clip01(x: float) -> float:
    """``x`` clipped to [0, 1]."""
    return 0.0 if x < 0.0 else 1.0 if x > 1.0 else x


class _Swings:
    """Counts direction reversals (zigzag with a minimum swing) of a few coordinates; the largest
    count over the coordinates is :attr:`count`. A waving hand reverses many times."""

    def __init__(self, min_swing: float) -> None:
        self.min_swing = min_swing
        self.count = 0
        self._n: list[int] = []
        self._ext: list[float] = []
        self._dir: list[int] = []

    def reset(self) -> None:
        self.count = 0
        self._n, self._ext, self._dir = [], [], []

    def add(self, *x: float) -> None:
        if not self._ext:
            self._ext, self._dir, self._n = list(x), [0] * len(x), [0] * len(x)
            return
        m = self.min_swing
        for i, v in enumerate(x):
            d, e = self._dir[i], self._ext[i]
            if d >= 0 and v < e - m:
                self._n[i] += d > 0
                self._dir[i], self._ext[i] = -1, v
            elif d <= 0 and v > e + m:
                self._n[i] += d < 0
                self._dir[i], self._ext[i] = 1, v
            elif (d > 0 and v > e) or (d < 0 and v < e):
                self._ext[i] = v
        self.count = max(self._n)


def _cross_time(t0: float, x0: float, t1: float, x1: float, level: float) -> float:
    """Time at which a linear motion from (t0, x0) to (t1, x1) passes ``level`` (clamped to [t0, t1])."""
    if t0 == -math.inf or x0 == x1:
        return t1
    a = (x0 - level) / (x0 - x1)
    return t0 + (t1 - t0) * min(max(a, 0.0), 1.0)


@dataclass(frozen=True)
class FireRingParams:
    """Thresholds of the fire-ring gesture (lengths in body heights, times in seconds)."""

    raise_up: float = -0.08
    hysteresis: float = 0.02
    low_up: float = -0.22
    min_raised_s: float = 0.45
    max_raised_s: float = 3.3
    max_drop_s: float = 0.5
    top_margin: float = 0.05  # the lowering starts when the lower wrist leaves the top (its peak minus this) ...
    max_lower_s: float | None = 1.0  # ... and must reach low_up within this (None: no bound)
    min_separation: float = 0.12
    max_out: float = 0.36  # both wrists must at some point be up with out <= this (not a T) ...
    upright_s: float = 0.1  # ... for this long in a row (not arms passing from a T towards the chest)
    max_swings: int = 4
    min_swing: float = 0.06
    rhythm_gap_s: float = 0.6
    raise_seen: bool = True  # the arms must be seen below the raised zone before the raise counts
    occlusion_hold_s: float = 0.5


class FireRingDetector:
    """Both arms raised (apart, not waving), then both brought down quickly: the last part of the way
    (from the raised zone to the hips) within ``max_drop_s`` and the whole lowering (from the lower
    wrist leaving the top, ``top_margin`` below its peak) within ``max_lower_s``.

    The raise is part of the gesture: after a reset (start of the stream, a gap, a glitch, a long
    occlusion) the arms must be seen below the raised zone before a raise can start one, so arms
    that are already up when the recogniser joins (the middle of a wave or of some other movement)
    and are then dropped are not a fire ring.
    """

    def __init__(self, p: FireRingParams) -> None:
        self.p = p
        self.swings = _Swings(p.min_swing)
        self.t_cycle_end = -math.inf  # when both arms last came down from the raised zone (seen or not)
        self.arms_up = False
        self.seen_low = False
        self.reset()

    def reset(self, keep_seen: bool = False) -> None:
        """Start over; ``keep_seen`` keeps knowing that the arms were seen down (a restart after
        another arm gesture, whose end the recogniser saw, rather than after a hole in the stream)."""
        seen = keep_seen and self.seen_low
        self.state = "idle"
        self.t_raised = self.t_exit = self.t_seen = self.t_prev = -math.inf
        self.prev_lo = self.prev_hi = math.nan
        self.peak = -math.inf
        self.t_top = -math.inf  # when the lower wrist last left the top (peak - top_margin): the lowering's start
        self.min_sep = math.inf
        self.rhythmic = False
        self.upright = False
        self.t_upright = math.inf  # since when the arms have been up and not stretched out (inf: not now)
        self.seen_low = seen or not self.p.raise_seen
        self.swings.reset()

    def update(self, f: FrameFeatures) -> Candidate | None:
        p = self.p
        if not _seen(self, f.t, f.ok and f.arm_l_ok and f.arm_r_ok, p.occlusion_hold_s):
            return None
        wl, wr = f.wrist_l, f.wrist_r
        assert wl is not None and wr is not None
        lo, hi = min(wl[1], wr[1]), max(wl[1], wr[1])
        out: Candidate | None = None
        if lo < p.raise_up - p.hysteresis:
            self.seen_low = True
        if lo >= p.raise_up:
            self.arms_up = True
        elif hi <= p.low_up and self.arms_up:  # any drop from the raised zone counts for the rhythm rule
            self.arms_up = False
            self.t_cycle_end = _cross_time(self.t_prev, self.prev_hi, f.t, hi, p.low_up)
        if self.state == "idle" and lo >= p.raise_up and not self.seen_low and self.t_prev == -math.inf:
            log.debug("fire ring at %.2f s: arms already up when the detector (re)started; waiting for them "
                      "to come down", f.t)
        if self.state == "idle":
            if lo >= p.raise_up and self.seen_low:
                self.state = "raised"
                self.t_raised = _cross_time(self.t_prev, self.prev_lo, f.t, lo, p.raise_up)
                self.rhythmic = 0.0 <= self.t_raised - self.t_cycle_end < p.rhythm_gap_s
                self.peak, self.min_sep, self.upright, self.t_upright = lo, math.inf, False, math.inf
                self.swings.reset()
        if self.state == "raised":
            self.peak = max(self.peak, lo)
        if self.state in ("raised", "dropping"):
            top = self.peak - p.top_margin
            if lo >= top:
                self.t_top = f.t
            elif self.prev_lo >= top:
                self.t_top = _cross_time(self.t_prev, self.prev_lo, f.t, lo, top)
        if self.state == "raised":
            if lo >= p.raise_up and max(wl[0], wr[0]) <= p.max_out:
                self.t_upright = min(self.t_upright, f.t)
                self.upright = self.upright or f.t - self.t_upright >= p.upright_s - 1e-9
            else:
                self.t_upright = math.inf
            self.min_sep = min(self.min_sep, wl[0] + wr[0])
            self.swings.add(wl[0], wl[2], wr[0], wr[2])
            if lo < p.raise_up - p.hysteresis:
                self.t_exit = _cross_time(self.t_prev, self.prev_lo, f.t, lo, p.raise_up - p.hysteresis)
                dur = self.t_exit - self.t_raised
                fine = (p.min_raised_s <= dur <= p.max_raised_s and self.swings.count <= p.max_swings
                        and self.min_sep >= p.min_separation and self.upright and not self.rhythmic)
                self.state = "dropping" if fine else "rejected"
                if not fine:
                    log.debug("fire ring at %.2f s not armed: raised %.2f s, %d swings, separation %.2f, "
                              "upright %s, rhythmic %s", f.t, dur, self.swings.count, self.min_sep,
                              self.upright, self.rhythmic)
        if self.state in ("dropping", "rejected"):
            if lo >= p.raise_up and self.state == "dropping":
                self.state = "raised"
            elif hi <= p.low_up:
                t_low = _cross_time(self.t_prev, self.prev_hi, f.t, hi, p.low_up)
                drop = t_low - self.t_exit
                lower = t_low - self.t_top
                quick = drop <= p.max_drop_s and (p.max_lower_s is None or lower <= p.max_lower_s)
                if self.state == "dropping" and not quick:
                    log.debug("fire ring at %.2f s too slow: %.2f s from raised to low, %.2f s from the top", f.t,
                              drop, lower)
                if self.state == "dropping" and quick:
                    speed = (self.peak - p.low_up) / max(t_low - self.t_exit, 0.05)
                    score = 0.5 * clip01((self.peak - p.raise_up) / 0.2) + 0.5 * clip01(speed / 1.0)
                    out = Candidate(self.t_raised, t_low, score)
                self.state = "idle"
            elif lo >= p.raise_up:  # rejected but raised again: a new attempt
                self.state = "idle"
            elif f.t - self.t_exit > max(p.max_drop_s, 1.5):
                self.state = "idle"
        self.t_prev, self.prev_lo, self.prev_hi = f.t, lo, hi
        return out


@dataclass(frozen=True)
class StrikeParams:
    """Thresholds of the strike (right arm up above the head, then down fast)."""

    raise_up: float = 0.10
    band_top: float = 0.05
    band_bottom: float = -0.15
    max_band_s: float = 0.14  # band_top -> band_bottom in this time: >= 1.4 H/s on average
    min_raised_s: float = 0.0
    max_raised_s: float = 4.0
    left_max_up: float = -0.10
    together_max: float = 0.15  # wrists closer than this: a two-handed swing, still a strike
    min_left_seen: float = 0.3  # fraction of the gesture's frames in which the left arm was visible
    max_swings: int = 4
    min_swing: float = 0.06
    min_drop_fwd: float = 0.0  # mean forward position of the wrist through the band: a chop in front, not a circle
    loop_levels: tuple[float, ...] = (-0.10, -0.05, 0.0, 0.05)  # heights at which the way down is compared ...
    max_loop_out: float | None = 0.025  # ... with the way up: at most this much further out on average (None: off)
    occlusion_hold_s: float = 0.5


class StrikeDetector:
    """Right arm swung up above the head and brought down fast in front of the body (left arm low or
    on the same grip).

    "In front": the wrist's mean forward offset from the shoulders while it crosses the band is at
    least ``min_drop_fwd``. A strike chops down towards the opponent in front; an arm circle
    (windmill) that comes down at the side or behind the shoulders is not one.

    "Not a loop": a strike comes down the way it went up, or inside it (a chop in front after a
    swing up at the side); an arm circle goes up one way and comes down another, outside it (up in
    front, down at the side). At each height of ``loop_levels`` the wrist's outward offset where it
    passed on the way down is compared with where it passed on the way up (the last rise, by linear
    interpolation between frames, so any frame rate reads the same); the mean difference must not
    exceed ``max_loop_out``. The outward offset is the image's horizontal for a player facing the
    camera, the coordinate a single camera measures best: a tracker that cannot see an arm pointing
    at the camera (so reports the circle's raise in front late, snapping up) still places the
    circle's way down further out than its way up.
    """

    def __init__(self, p: StrikeParams) -> None:
        self.p = p
        self.swings = _Swings(p.min_swing)
        self.reset()

    def reset(self) -> None:
        self.state = "idle"
        self.t_raised = self.t_top = self.t_seen = self.t_prev = self.t_last_raised = -math.inf
        self.prev_up = self.prev_fwd = self.prev_out = math.nan
        self.fwd_sum, self.fwd_n = 0.0, 0
        self.peak = -math.inf
        self.left_ok = True
        self.left_seen = self.frames = 0
        self.up_out: dict[float, float] = {}  # outward offset at each loop level on the last way up
        self.down_out: dict[float, float] = {}  # ... and on the way down since the top
        self.swings.reset()

    def _loop_out(self) -> float:
        """Mean of (way down - way up) outward offsets over the loop levels passed both ways (0 if none)."""
        d = [self.down_out[x] - self.up_out[x] for x in self.down_out if x in self.up_out]
        return sum(d) / len(d) if d else 0.0

    def _track_levels(self, up: float, out: float) -> None:
        """Record where the wrist crossed each loop level, up or down, since the previous frame."""
        u0, o0 = self.prev_up, self.prev_out
        if math.isnan(u0) or u0 == up:
            return
        for x in self.p.loop_levels:
            if u0 < x <= up or up < x <= u0:
                at = o0 + (out - o0) * (x - u0) / (up - u0)
                if up > u0:  # on the way up (possibly after a false start down): the latest rise counts
                    self.up_out[x] = at
                    self.down_out.pop(x, None)
                elif self.state == "idle":  # down while idle: that rise is over
                    self.up_out.pop(x, None)
                else:
                    self.down_out.setdefault(x, at)

    def _left_fine(self, f: FrameFeatures) -> bool:
        wl, wr = f.wrist_l, f.wrist_r
        assert wl is not None and wr is not None
        self.frames += 1
        if not f.arm_l_ok:
            return True
        self.left_seen += 1
        if wl[1] <= self.p.left_max_up:
            return True
        return bool(wl[0] + wr[0] <= self.p.together_max and abs(wl[1] - wr[1]) <= self.p.together_max)

    def update(self, f: FrameFeatures) -> Candidate | None:
        p = self.p
        if not _seen(self, f.t, f.ok and f.arm_r_ok, p.occlusion_hold_s):
            return None
        wr = f.wrist_r
        assert wr is not None
        up = float(wr[1])
        out: Candidate | None = None
        if self.state == "idle" and up >= p.raise_up:
            self.state, self.t_raised, self.peak, self.left_ok = "raised", f.t, up, True
            self.left_seen = self.frames = 0
            self.swings.reset()
        self._track_levels(up, float(wr[0]))
        if self.state != "idle":
            self.left_ok = self.left_ok and self._left_fine(f)
        if self.state == "raised":
            self.peak = max(self.peak, up)
            self.swings.add(wr[0], wr[2])
            if up >= p.raise_up:
                self.t_last_raised = f.t
            if up < p.band_top:
                self.state = "falling"
                self.t_top = _cross_time(self.t_prev, self.prev_up, f.t, up, p.band_top)
                self.fwd_sum, self.fwd_n = (0.0, 0) if math.isnan(self.prev_fwd) else (self.prev_fwd, 1)
        if self.state == "falling":
            self.fwd_sum, self.fwd_n = self.fwd_sum + float(wr[2]), self.fwd_n + 1
            if up >= p.raise_up:
                self.state = "raised"
            elif up <= p.band_bottom:
                t_low = _cross_time(self.t_prev, self.prev_up, f.t, up, p.band_bottom)
                band = t_low - self.t_top
                dur = self.t_last_raised - self.t_raised
                seen = self.left_seen / max(self.frames, 1)  # the left arm must be seen to rule out two arms
                fwd = self.fwd_sum / self.fwd_n
                loop = self._loop_out()
                if fwd < p.min_drop_fwd:
                    log.debug("strike at %.2f s not in front: wrist %.2f H forward through the band", f.t, fwd)
                if p.max_loop_out is not None and loop > p.max_loop_out:
                    log.debug("strike at %.2f s is a loop: down %.3f H further out than up", f.t, loop)
                if (band <= p.max_band_s and self.left_ok and self.swings.count <= p.max_swings
                        and p.min_raised_s <= dur + 1e-9 and dur <= p.max_raised_s and seen >= p.min_left_seen
                        and fwd >= p.min_drop_fwd and (p.max_loop_out is None or loop <= p.max_loop_out)):
                    speed = (p.band_top - p.band_bottom) / max(band, 1e-3)
                    score = 0.5 * clip01((self.peak - p.raise_up) / 0.15) + 0.5 * clip01(speed / 3.0)
                    out = Candidate(self.t_raised, t_low, score * (0.6 + 0.4 * seen))
                self.state = "idle"
            elif f.t - self.t_top > 1.0:
                self.state = "idle"
        self.t_prev, self.prev_up, self.prev_fwd, self.prev_out = f.t, up, float(wr[2]), float(wr[0])
        return out


@dataclass(frozen=True)
class TransformParams:
    """Thresholds of the ninja transformation (arms out to the sides, then onto the chest)."""

    out_min: float = 0.28
    out_up_abs: float = 0.12
    out_hold_s: float = 0.12
    chest_out_max: float = 0.13
    chest_up_min: float = -0.26
    chest_up_max: float = 0.02
    chest_fwd_min: float = 0.0
    chest_fwd_max: float = 0.22
    chest_hold_s: float = 0.06
    chest_still: float = 0.08  # each wrist's out and up move at most this far during the chest hold (not its
    # forward offset: a single camera's depth of a hand on the chest jumps by 0.1-0.2 H between frames)
    straight_max_deg: float = 25.0  # the bent path needs the arms seen straight in the T (mean bend) ...
    fold_min_deg: float = 60.0  # ... and then folded this much on average ...
    fold_out_min: float = 0.18  # ... while the wrists were still this far out on average (coming in) ...
    fold_window_s: float = 0.6  # ... within this time of the last straight T frame
    bent_min_deg: float | None = 40.0  # or: elbows bent this much on average (None: chest zone only)
    bent_each_min_deg: float = 25.0  # ... each at least this much
    bent_out_max: float = 0.20  # ... with both wrists inside this (not out to the sides)
    bent_up_min: float = -0.33  # ... and between these heights (below the mouth: hands to the face are not on
    bent_up_max: float = -0.10  # the chest)
    bent_fwd_min: float = -0.08  # ... and not behind the back
    bent_elbow_up_max: float = -0.05  # ... and the elbows down (not raised)
    bent_hold_s: float = 0.12  # ... held this long, moving < chest_still (not arms passing through)
    bend_hysteresis_deg: float = 5.0
    max_gap_s: float = 2.0
    max_swings: int = 3
    min_swing: float = 0.08
    hysteresis: float = 0.02
    occlusion_hold_s: float = 0.5


class TransformDetector:
    """Both arms raised out to the sides, then bent so both hands rest (still) on the chest."""

    def __init__(self, p: TransformParams) -> None:
        self.p = p
        self.swings = _Swings(p.min_swing)
        self.reset()

    def reset(self) -> None:
        self.state = "idle"
        self.t_out = self.t_out_last = self.t_chest = self.t_seen = -math.inf
        self.out_margin = 0.0
        self.chest_at: tuple[float, ...] | None = None
        self.folded = False
        self.t_straight = -math.inf
        self.chest_zone = True
        self.swings.reset()

    def _is_out(self, w: Vec3, slack: float) -> bool:
        return bool(w[0] >= self.p.out_min - slack and abs(w[1]) <= self.p.out_up_abs + slack)

    def _on_chest(self, w: Vec3, slack: float) -> bool:
        p = self.p
        return bool(w[0] <= p.chest_out_max + slack and p.chest_up_min - slack <= w[1] <= p.chest_up_max + slack
                    and p.chest_fwd_min - slack <= w[2] <= p.chest_fwd_max + slack)

    def _bent_in(self, w: Vec3, e: Vec3, slack: float) -> bool:
        p = self.p
        return bool(w[0] <= p.bent_out_max + slack and p.bent_up_min - slack <= w[1] <= p.bent_up_max + slack
                    and w[2] >= p.bent_fwd_min - slack and e[1] <= p.bent_elbow_up_max + slack)

    def _in_zone(self, f: FrameFeatures, slack: float) -> bool:
        assert f.wrist_l is not None and f.wrist_r is not None
        return self._on_chest(f.wrist_l, slack) and self._on_chest(f.wrist_r, slack)

    def _hands_in(self, f: FrameFeatures, slack: float) -> bool:
        """Both hands brought onto the chest: both wrists in the chest zone, or (the arms having folded
        on their way in) both elbows bent with the wrists in front of the torso, below the face (what
        a single camera sees of hands on the chest; ``slack`` widens every bound, by ``slack`` H and
        ``bend_hysteresis_deg`` degrees)."""
        p = self.p
        wl, wr, el, er = f.wrist_l, f.wrist_r, f.elbow_l, f.elbow_r
        assert wl is not None and wr is not None
        if self._in_zone(f, slack):
            return True
        if p.bent_min_deg is None or not self.folded or el is None or er is None:
            return False
        deg = p.bend_hysteresis_deg if slack > 0.0 else 0.0
        return bool(0.5 * (f.bend_l + f.bend_r) >= p.bent_min_deg - deg
                    and min(f.bend_l, f.bend_r) >= p.bent_each_min_deg - deg
                    and self._bent_in(wl, el, slack) and self._bent_in(wr, er, slack))

    def update(self, f: FrameFeatures) -> Candidate | None:
        p = self.p
        if not _seen(self, f.t, f.ok and f.arm_l_ok and f.arm_r_ok, p.occlusion_hold_s):
            return None
        wl, wr = f.wrist_l, f.wrist_r
        assert wl is not None and wr is not None
        both_out = self._is_out(wl, 0.0) and self._is_out(wr, 0.0)
        still_out = self._is_out(wl, p.hysteresis) and self._is_out(wr, p.hysteresis)
        if self.state == "idle" and both_out:
            self.state, self.t_out, self.out_margin, self.folded = "out_pending", f.t, 0.0, False
            self.swings.reset()
        bend = 0.5 * (f.bend_l + f.bend_r)
        if self.state in ("out_pending", "out") and still_out and bend <= p.straight_max_deg:
            self.t_straight = f.t
        if self.state == "out_pending":
            if not still_out:
                self.state = "idle"
            else:
                self.swings.add(wl[0], wr[0])
                self.out_margin = max(self.out_margin, min(wl[0], wr[0]) - p.out_min)
                if f.t - self.t_out >= p.out_hold_s:
                    self.state, self.t_out_last = "out", f.t
        elif self.state == "out":
            self.swings.add(wl[0], wr[0])  # arms going in and out (waving) are not a transformation
            self.folded = self.folded or (bend >= p.fold_min_deg and 0.5 * (wl[0] + wr[0]) >= p.fold_out_min
                                          and f.t - self.t_straight <= p.fold_window_s)
            if still_out:
                self.t_out_last = f.t
            elif f.t - self.t_out_last > p.max_gap_s or self.swings.count > p.max_swings:
                log.debug("transform at %.2f s abandoned: %.2f s since arms out, %d swings", f.t,
                          f.t - self.t_out_last, self.swings.count)
                self.reset()
            elif self._hands_in(f, 0.0):
                self.state, self.t_chest, self.chest_at = "chest", f.t, wl + wr
                self.chest_zone = self._in_zone(f, 0.0)
        elif self.state == "chest":
            assert self.chest_at is not None
            if not self.chest_zone and self._in_zone(f, 0.0):  # the hands reached the zone: its (shorter) hold
                self.chest_zone, self.t_chest, self.chest_at = True, f.t, wl + wr
            moved = max(abs(a - b) for k, (a, b) in enumerate(zip(wl + wr, self.chest_at, strict=True))
                        if k % 3 != 2)  # out and up only: not the forward offsets (see chest_still)
            hold = p.chest_hold_s if self.chest_zone else p.bent_hold_s
            if not self._hands_in(f, p.hysteresis) or moved > p.chest_still:
                log.debug("transform at %.2f s: hands left the chest (moved %.3f H)", f.t, moved)
                self.state = "out" if f.t - self.t_out_last <= p.max_gap_s else "idle"
            elif f.t - self.t_chest >= hold:
                gap = self.t_chest - self.t_out_last
                cand = Candidate(self.t_out, self.t_chest,
                                 0.5 * clip01(self.out_margin / 0.12) + 0.5 * clip01(1.0 - gap / p.max_gap_s))
                self.reset()
                return cand
        return None
