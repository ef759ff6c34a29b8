"""Streaming recogniser of the game's five gestures from 3D joints (pure; no clock, no I/O).

``GestureRecognizer.update(t, joints, visibility)`` takes one pose frame in stream time and returns
the gestures that completed on it. Inside, :class:`~game_client.features.FeatureExtractor` turns the
joints into body-normalised features and the state machines of :mod:`game_client.detectors` look
for the gestures; this module adds what concerns the stream as a whole:

* **gaps** longer than :attr:`RecognizerConfig.max_gap_s` (dropped frames, a paused tracker) and
  time going backwards (a restarted tracker) reset every state machine, so a gesture cannot be
  stitched together across a hole;
* **glitches**: a pelvis jump of more than :attr:`RecognizerConfig.glitch_h` body heights between
  two frames (a tracker re-initialising, a looped recording) also resets them;
* **arm gestures exclude each other**: after a transform, strike or fire ring every arm state
  machine starts over, so one arm movement yields one event;
* **in place**: the game's gestures are made standing in place, facing the screen; an arm gesture
  or crouch during which the body turned or travelled (a dance spin, a stylised walk) is dropped
  (:attr:`RecognizerConfig.still_max_turn_deg` and ``*_max_travel``; the turn limit is waived while
  the player faced the screen, :attr:`RecognizerConfig.still_screen`, because a single camera's
  heading wanders);
* **low-confidence frames** (:attr:`RecognizerConfig.min_confidence`) are not read;
* a **refractory** period per gesture suppresses a repeat of the same gesture for
  :attr:`RecognizerConfig.refractory_s`.

Event times
-----------
``end_s`` is when the gesture completed as defined in :mod:`game_client.detectors` (e.g. the
hands reaching the hips for a fire ring), ``t`` the stream time of the frame on which it was
reported and ``latency_ms = 1000 (t - end_s)`` the recogniser's own delay (its confirmation holds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .body_detectors import CrouchDetector, CrouchParams, SideStepDetector, SideStepParams
from .detectors import (
    Candidate,
    FireRingDetector,
    FireRingParams,
    StrikeDetector,
    StrikeParams,
    TransformDetector,
    TransformParams,
)
from .features import FeatureConfig, FeatureExtractor, FrameFeatures, ScreenFacing

__all__ = ["ARM_GESTURES", "Gesture", "GestureEvent", "GestureRecognizer", "RecognizerConfig", "recognize"]


class Gesture(StrEnum):
    """The five gestures of the game (paper §4, in its order)."""

    TRANSFORM = "transform"  # (1) arms out to the sides, then bent onto the chest
    CROUCH = "crouch"  # (2) dodge high attack
    SIDE_STEP = "side_step"  # (3) dodge sideways attack
    STRIKE = "strike"  # (4) hit 1: right arm up, then down quickly
    FIRE_RING = "fire_ring"  # (5) hit 2: both arms up, then down quickly


#: Gestures made with the arms; they reset each other's state machines.
ARM_GESTURES: frozenset[Gesture] = frozenset({Gesture.TRANSFORM, Gesture.STRIKE, Gesture.FIRE_RING})


@dataclass(frozen=True)
class GestureEvent:
    """One recognised gesture.

    Attributes
    ----------
    gesture : Gesture
    start_s, end_s : float
        Stream times (seconds) when the gesture started and completed.
    t : float
        Stream time of the frame on which it was recognised (>= ``end_s``).
    confidence : float
        In [0, 1]: how clearly the thresholds were passed, times the tracker's confidence.
    direction : str or None
        ``"left"`` or ``"right"`` (the player's own side) for a side-step, else ``None``.
    """

    gesture: Gesture
    start_s: float
    end_s: float
    t: float
    confidence: float
    direction: str | None = None

    @property
    def latency_ms(self) -> float:
        """Milliseconds from the gesture's end to its recognition (stream time)."""
        return 1000.0 * (self.t - self.end_s)

    def to_json(self) -> dict[str, Any]:
        """The record ``mocap-game recognize --json`` prints for this event."""
        return {"gesture": self.gesture.value, "start_s": round(self.start_s, 4), "end_s": round(self.end_s, 4),
                "confidence": round(self.confidence, 3), "latency_ms": round(self.latency_ms, 1),
                "direction": self.direction, "t": round(self.t, 4)}


@dataclass(frozen=True)
class RecognizerConfig:
    """All recogniser parameters (defaults tuned on the scripts and the shared recordings).

    Attributes
    ----------
    features : FeatureConfig
    transform, crouch, side_step, strike, fire_ring : parameter records of each detector
    max_gap_s : float
        A gap between frames longer than this resets the state machines.
    glitch_h : float
        A pelvis jump larger than this many body heights between consecutive frames is a glitch.
    refractory_s : float
        Minimum time between two events of the same gesture.
    still_max_turn_deg, still_max_travel, crouch_max_travel : float
        The game's gestures are made in place, facing the screen: an arm gesture or a crouch during
        which (from 0.2 s before its start to its end) the facing turned by more than
        ``still_max_turn_deg`` or the pelvis travelled more than ``still_max_travel`` body heights
        (``crouch_max_travel`` for a crouch) is part of some other movement (a dance spin, a
        stylised walk) and is dropped. 55 degrees: a single-camera tracker's heading wanders by
        +-25 degrees while both arms are up (tracked game scripts); the first real take to give a
        false gesture needs 61.6 (`bench_game_margins.py`).
    step_screen, still_screen : ScreenFacing or None
        Where the screen is (the player of the game faces it; a single camera's heading wanders, see
        :class:`~game_client.features.ScreenFacing`): the side-step is also measured along the
        screen's axes while the player faced it by ``step_screen``, and the in-place rule's turn
        limit does not apply while the player faced it by ``still_screen`` (the facing swings more
        while both arms are up: tracked fire rings are off by up to 19 degrees on average; no real
        take gives a false arm gesture or crouch even without the mean limit). ``None``: body
        frame and turn limit only.
    min_confidence : float
        Frames whose tracker confidence is below this are not read (counted as ``low_confidence``;
        a stretch of them longer than ``max_gap_s`` is a gap). The tracker reports < 0.05 when its
        pose is garbage (tracked game scripts: 21 cm mean joint error and the body thrown up to 1.7 m
        in depth for a frame or two, against 6-9 cm above 0.05), and one such frame in the middle of
        a step reset every state machine as a glitch.
    still_depth_weight : float
        Weight of the depth axis (world ``z``, the camera's viewing direction) in that travel: a
        single camera measures depth several times less precisely than sideways motion (tracked
        game scripts: a standing player's depth wanders by 14 cm while the arms are up).
    enabled : tuple of Gesture
        Gestures to look for.
    """

    features: FeatureConfig = field(default_factory=FeatureConfig)
    transform: TransformParams = field(default_factory=TransformParams)
    crouch: CrouchParams = field(default_factory=CrouchParams)
    side_step: SideStepParams = field(default_factory=SideStepParams)
    strike: StrikeParams = field(default_factory=StrikeParams)
    fire_ring: FireRingParams = field(default_factory=FireRingParams)
    max_gap_s: float = 0.5
    glitch_h: float = 0.35
    refractory_s: float = 0.3
    still_max_turn_deg: float = 55.0
    still_max_travel: float = 0.15
    crouch_max_travel: float = 0.25
    still_depth_weight: float = 0.5
    step_screen: ScreenFacing | None = field(default_factory=ScreenFacing)
    still_screen: ScreenFacing | None = field(default_factory=lambda: ScreenFacing(mean_deg=30.0))
    min_confidence: float = 0.05
    enabled: tuple[Gesture, ...] = tuple(Gesture)


class _MotionHistory:
    """Pelvis ground position and (unwrapped) facing over the last few seconds."""

    def __init__(self, seconds: float = 6.0, capacity: int = 2048) -> None:
        self.seconds = seconds
        self._buf = np.zeros((capacity, 4))  # t, x, z, yaw
        self._n = 0

    def clear(self) -> None:
        self._n = 0

    def add(self, t: float, xz: tuple[float, float], yaw: float) -> None:
        if self._n:
            prev = self._buf[self._n - 1, 3]
            yaw = prev + (yaw - prev + math.pi) % (2 * math.pi) - math.pi
        if self._n == len(self._buf) or (self._n and self._buf[0, 0] < t - 2 * self.seconds):
            keep = self._buf[: self._n]
            first = max(int(np.searchsorted(keep[:, 0], t - self.seconds)), 1)
            self._buf[: self._n - first] = keep[first:]
            self._n -= first
        self._buf[self._n] = (t, xz[0], xz[1], yaw)
        self._n += 1

    def motion(self, t0: float, t1: float, depth_weight: float = 1.0,
               screen: ScreenFacing | None = None) -> tuple[float, float, bool]:
        """Facing range (radians), largest pelvis distance from its position at ``t0`` (metres,
        the depth axis ``z`` scaled by ``depth_weight``) and whether the player faced ``screen``
        (false without one) over ``[t0, t1]``; zeros (and true) if no sample falls in the interval."""
        b = self._buf[: self._n]
        i0, i1 = int(np.searchsorted(b[:, 0], t0)), int(np.searchsorted(b[:, 0], t1, side="right"))
        if i1 <= i0:
            return 0.0, 0.0, True
        w = b[i0:i1]
        travel = float(np.hypot(w[:, 1] - w[0, 1], depth_weight * (w[:, 2] - w[0, 2])).max())
        faced = screen is not None and bool(screen.faced(w[:, 3])[0])
        return float(w[:, 3].max() - w[:, 3].min()), travel, faced


class GestureRecognizer:
    """Streaming gesture recogniser for one player.

    Parameters
    ----------
    config : RecognizerConfig, optional
    height_m : float, optional
        The player's height if known (``BodyInfo``); otherwise estimated from the joints.

    Attributes
    ----------
    counters : dict[str, int]
        ``frames``, ``gaps`` (resets after a gap), ``restarts`` (time went backwards),
        ``glitches``, ``unusable`` (torso not visible), ``duplicates`` (repeated time stamps),
        ``low_confidence`` (frames below :attr:`RecognizerConfig.min_confidence`, not read).
    """

    def __init__(self, config: RecognizerConfig | None = None, height_m: float | None = None) -> None:
        self.config = cfg = config or RecognizerConfig()
        self.features = FeatureExtractor(cfg.features, height_m)
        self._detectors: dict[Gesture, Any] = {
            Gesture.TRANSFORM: TransformDetector(cfg.transform),
            Gesture.CROUCH: CrouchDetector(cfg.crouch),
            Gesture.SIDE_STEP: SideStepDetector(cfg.side_step, cfg.step_screen),
            Gesture.STRIKE: StrikeDetector(cfg.strike),
            Gesture.FIRE_RING: FireRingDetector(cfg.fire_ring),
        }
        self.counters = dict.fromkeys(
            ("frames", "gaps", "restarts", "glitches", "unusable", "duplicates", "low_confidence"), 0)
        self._t_last: float | None = None
        self._pelvis_last: tuple[float, float] | None = None
        self._last_event: dict[Gesture, float] = {}
        self._history = _MotionHistory()

    def reset(self, keep_height: bool = True) -> None:
        """Start over (as after a tracker restart); the body height is kept unless told otherwise."""
        for det in self._detectors.values():
            det.reset()
        self.features.reset(keep_height=keep_height)
        self._t_last = None
        self._pelvis_last = None
        self._last_event.clear()
        self._history.clear()

    def _reset_detectors(self) -> None:
        for det in self._detectors.values():
            det.reset()
        self._history.clear()

    def update(self, t: float, joints: NDArray[np.floating], visibility: NDArray[np.floating] | None = None,
               confidence: float = 1.0) -> list[GestureEvent]:
        """Feed one frame; return the gestures recognised on it (usually none).

        Parameters
        ----------
        t : float
            Stream time of the frame (``PoseFrame.capture_ts``), seconds.
        joints : (24, 3) float
            World joint positions, metres, Y up.
        visibility : (15,) float, optional
            Visible fraction per body part (``PoseFrame.visibility``); default all visible.
        confidence : float
            ``PoseFrame.confidence``; scales the events' confidence.

        Returns
        -------
        list of GestureEvent
        """
        cfg = self.config
        if not math.isfinite(t):
            raise ValueError(f"frame time must be finite, got {t}")
        if self._t_last is not None:
            if t < self._t_last:
                self.counters["restarts"] += 1
                self.reset()
            elif t == self._t_last:
                self.counters["duplicates"] += 1
                return []
        if confidence < cfg.min_confidence:  # not read; the time since the last frame read keeps growing
            self.counters["low_confidence"] += 1
            return []
        if self._t_last is not None and t - self._t_last > cfg.max_gap_s:
            self.counters["gaps"] += 1
            self._reset_detectors()
            self.features.reset()
        self.counters["frames"] += 1
        f = self.features.update(t, joints, visibility, confidence)
        dt = 0.0 if self._t_last is None else t - self._t_last
        self._t_last = t
        if not f.ok:
            self.counters["unusable"] += 1
        elif f.pelvis_xz is not None:
            if self._pelvis_last is not None and dt > 0:
                (x, z), (x0, z0) = f.pelvis_xz, self._pelvis_last
                jump = math.hypot(x - x0, z - z0) / f.height
                if jump > cfg.glitch_h + 3.0 * dt:
                    self.counters["glitches"] += 1
                    self._reset_detectors()
            self._pelvis_last = f.pelvis_xz
            self._history.add(t, f.pelvis_xz, f.yaw)
        return self._run_detectors(f)

    def _in_place(self, gesture: Gesture, cand: Candidate, f: FrameFeatures) -> bool:
        """True if the body stayed in place while the (arm or crouch) gesture was made."""
        cfg = self.config
        if gesture == Gesture.SIDE_STEP:
            return True
        turn, travel, faced = self._history.motion(cand.start_s - 0.2, f.t, cfg.still_depth_weight,
                                                   cfg.still_screen)
        limit = cfg.crouch_max_travel if gesture == Gesture.CROUCH else cfg.still_max_travel
        return (turn <= math.radians(cfg.still_max_turn_deg) or faced) and travel <= limit * f.height

    def _run_detectors(self, f: FrameFeatures) -> list[GestureEvent]:
        cfg = self.config
        events: list[GestureEvent] = []
        for gesture, det in self._detectors.items():
            if gesture not in cfg.enabled:
                continue
            cand: Candidate | None = det.update(f)
            if cand is None:
                continue
            if f.t - self._last_event.get(gesture, -math.inf) < cfg.refractory_s:
                continue
            if not self._in_place(gesture, cand, f):
                continue
            if gesture in ARM_GESTURES and any(e.gesture in ARM_GESTURES for e in events):
                continue  # one arm movement, one event (earlier detectors in the dict win)
            self._last_event[gesture] = f.t
            conf = (0.6 + 0.4 * cand.score) * min(max(f.confidence, 0.0), 1.0)
            events.append(GestureEvent(gesture, float(cand.start_s), float(cand.end_s), float(f.t), float(conf),
                                       cand.direction))
        if any(e.gesture in ARM_GESTURES for e in events):
            for g in ARM_GESTURES:
                if g == Gesture.FIRE_RING:
                    self._detectors[g].reset(keep_seen=True)  # the arms were seen: no need to see them down again
                else:
                    self._detectors[g].reset()
        return events


def recognize(times: NDArray[np.floating], joints: NDArray[np.floating],
              visibility: NDArray[np.floating] | None = None, *, config: RecognizerConfig | None = None,
              height_m: float | None = None, confidence: NDArray[np.floating] | None = None) -> list[GestureEvent]:
    """Run a fresh recogniser over a whole sequence.

    Parameters
    ----------
    times : (N,) float
        Frame times, seconds.
    joints : (N, 24, 3) float
    visibility : (N, 15) float, optional
    config : RecognizerConfig, optional
    height_m : float, optional
    confidence : (N,) float, optional

    Returns
    -------
    list of GestureEvent
        In the order they were recognised.
    """
    rec = GestureRecognizer(config, height_m)
    out: list[GestureEvent] = []
    for k in range(len(times)):
        out += rec.update(float(times[k]), joints[k], None if visibility is None else visibility[k],
                          1.0 if confidence is None else float(confidence[k]))
    return out
