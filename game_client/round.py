"""A round of the game driven by a pose stream: gesture recogniser + game, in pose-stream time.

Pure (no clock, no I/O): :meth:`GameRound.feed` takes one pose frame, runs the recogniser on it,
hands the recognised gestures to the game and advances the game's fixed-step clock up to the
frame's time. The same frames therefore always give the same round.

Clocks
------
The recogniser sees the tracker's ``capture_ts`` unchanged (its events carry pose-stream times).
The game's clock starts at 0 on the first frame and follows the stream; when the stream jumps
back (a tracker restart) or pauses for longer than ``max_gap_s``, the game clock simply continues
from where it was, so a round survives a tracker restart. The game only advances when frames
arrive: without poses the world waits.

Log records
-----------
:meth:`GameRound.feed` also returns the JSON-lines records of the round log (plain dicts):
``{"type": "gesture", ...}`` per recognised gesture, ``{"type": "game", ...}`` per game event,
``{"type": "state", ...}`` every ``state_interval_s`` of game time, and :meth:`summary` gives
``{"type": "summary", ...}``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .game import Game, GameConfig, GameRecord, GameSnapshot, Phase, PlayerInput
from .gestures import GestureEvent, GestureRecognizer, RecognizerConfig

__all__ = ["FrameResult", "GameRound", "game_record", "gesture_record", "state_record"]


@dataclass
class FrameResult:
    """What one pose frame caused: recognised gestures, game events and log records."""

    game_t: float
    gestures: list[GestureEvent] = field(default_factory=list)
    events: list[GameRecord] = field(default_factory=list)
    log: list[dict[str, Any]] = field(default_factory=list)


def gesture_record(e: GestureEvent, game_t: float) -> dict[str, Any]:
    """Log record of a recognised gesture."""
    return {"type": "gesture", "t": round(game_t, 4), **e.to_json()}


def game_record(r: GameRecord, stream_ts: float) -> dict[str, Any]:
    """Log record of a game event."""
    return {"type": "game", "t": round(r.t, 4), "stream_ts": round(stream_ts, 4), "kind": r.kind,
            "actor": r.actor, "detail": r.detail, "value": round(r.value, 3)}


def state_record(s: GameSnapshot, stream_ts: float) -> dict[str, Any]:
    """Log record of a state snapshot."""
    return {"type": "state", "t": round(s.t, 4), "stream_ts": round(stream_ts, 4), "phase": s.phase.value,
            "round_left_s": round(s.round_left_s, 2), "player_health": s.player_health,
            "opponent_health": s.opponent_health, "player_lane": s.player_lane, "crouching": s.crouching,
            "telegraph": s.telegraph, "projectiles": len(s.projectiles)}


class GameRound:
    """Recogniser and game for one player.

    Parameters
    ----------
    game_config : GameConfig, optional
    recognizer_config : RecognizerConfig, optional
    height_m : float, optional
        The player's height if known (from ``BodyInfo``).
    max_gap_s : float
        A stream pause longer than this is not played as game time.
    state_interval_s : float
        Game time between two ``state`` log records.
    """

    def __init__(self, game_config: GameConfig | None = None, recognizer_config: RecognizerConfig | None = None,
                 height_m: float | None = None, max_gap_s: float = 1.0, state_interval_s: float = 0.5) -> None:
        self.game = Game(game_config or GameConfig())
        self.recognizer = GestureRecognizer(recognizer_config, height_m)
        self.max_gap_s = max_gap_s
        self.state_interval_s = state_interval_s
        self.frames = 0
        self.gesture_counts: dict[str, int] = {}
        self.counters = {"stream_restarts": 0, "stream_gaps": 0}
        self.last_joints: NDArray[np.float64] | None = None
        self.last_gesture: GestureEvent | None = None
        self.last_gesture_game_t = -math.inf
        self._offset: float | None = None
        self._last_ts = -math.inf
        self._game_t = 0.0
        self._next_state = 0.0

    @property
    def over(self) -> bool:
        """True once the round has ended (knockout or time)."""
        return self.game.phase == Phase.OVER

    def feed(self, capture_ts: float, joints: NDArray[np.floating], visibility: NDArray[np.floating] | None = None,
             confidence: float = 1.0) -> FrameResult:
        """Process one pose frame.

        Parameters
        ----------
        capture_ts : float
            ``PoseFrame.capture_ts``, seconds.
        joints : (24, 3) float
            World joint positions, metres.
        visibility : (15,) float, optional
        confidence : float

        Returns
        -------
        FrameResult
        """
        if not math.isfinite(capture_ts):
            raise ValueError(f"capture_ts must be finite, got {capture_ts}")
        dt_step = self.game.config.dt
        if self._offset is None:
            self._offset = capture_ts - self._game_t - (dt_step if self.frames else 0.0)
        elif capture_ts < self._last_ts or capture_ts - self._last_ts > self.max_gap_s:
            self.counters["stream_restarts" if capture_ts < self._last_ts else "stream_gaps"] += 1
            self._offset = capture_ts - (self._game_t + dt_step)  # continue the game clock
        self._last_ts = capture_ts
        self._game_t = max(self._game_t, capture_ts - self._offset)
        self.frames += 1
        self.last_joints = np.asarray(joints, dtype=np.float64)
        res = FrameResult(self._game_t)
        res.gestures = self.recognizer.update(capture_ts, joints, visibility, confidence)
        inputs = [PlayerInput(e.gesture.value, e.direction, e.confidence) for e in res.gestures]
        for e in res.gestures:
            self.gesture_counts[e.gesture.value] = self.gesture_counts.get(e.gesture.value, 0) + 1
            self.last_gesture, self.last_gesture_game_t = e, self._game_t
            res.log.append(gesture_record(e, self._game_t))
        steps = max(0, int((self._game_t - self.game.t) / dt_step + 1e-9))
        for k in range(steps):  # catch up to the frame; its gestures act on the last step (no earlier)
            recs = self.game.step(inputs if k == steps - 1 else [])
            res.events += recs
            res.log += [game_record(r, capture_ts) for r in recs]
        if steps:
            inputs = []
        if inputs:  # the frame came before the next game step is due: apply on that step
            recs = self.game.step(inputs)
            res.events += recs
            res.log += [game_record(r, capture_ts) for r in recs]
        if self.game.t >= self._next_state:
            res.log.append(state_record(self.game.snapshot(), capture_ts))
            self._next_state = self.game.t + self.state_interval_s
        return res

    def restart_stream(self) -> None:
        """A new pose stream begins (tracker restart): the recogniser starts over (keeping the body
        height) and the game clock continues from where it is with the next frame, whatever its time."""
        self.recognizer.reset(keep_height=True)
        if self._offset is not None:
            self.counters["stream_restarts"] += 1
        self._offset = None
        self._last_ts = -math.inf

    def summary(self) -> dict[str, Any]:
        """The ``summary`` log record: outcome, healths, counts."""
        s = self.game.snapshot()
        return {"type": "summary", "t": round(s.t, 4), "phase": s.phase.value, "winner": s.winner,
                "reason": s.end_reason, "player_health": s.player_health, "opponent_health": s.opponent_health,
                "frames": self.frames, "gestures": dict(sorted(self.gesture_counts.items())),
                "counters": {**self.counters, **self.recognizer.counters}}
