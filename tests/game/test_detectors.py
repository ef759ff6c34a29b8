"""The arm state machines on hand-made feature streams: the rules that need the raise to be seen."""

from __future__ import annotations

import numpy as np

from game_client.detectors import Candidate, FireRingDetector, FireRingParams, StrikeDetector, StrikeParams
from game_client.features import FrameFeatures

HZ = 30.0


def _frames(t0: float, t1: float, up0: float, up1: float, out: float = 0.2, fwd: float = 0.05,
            right_only: bool = False) -> list[FrameFeatures]:
    """Both wrists (or only the right one, the left hanging down) moving linearly in height."""
    ts = np.arange(t0, t1, 1.0 / HZ)
    ups = np.linspace(up0, up1, len(ts))
    return [FrameFeatures(t=float(t), ok=True, height=1.7, wrist_l=(out, -0.32 if right_only else float(u), fwd),
                          wrist_r=(out, float(u), fwd), arm_l_ok=True, arm_r_ok=True)
            for t, u in zip(ts, ups, strict=True)]


def _run(det: FireRingDetector | StrikeDetector, frames: list[FrameFeatures]) -> list[Candidate]:
    return [c for f in frames if (c := det.update(f)) is not None]


def _throw(t0: float, start_up: float = -0.3) -> list[FrameFeatures]:
    """Arms raised from ``start_up`` in 0.3 s, held 0.7 s, dropped in 0.15 s, then rest 0.5 s."""
    return (_frames(t0, t0 + 0.3, start_up, 0.25) + _frames(t0 + 0.3, t0 + 1.0, 0.25, 0.25)
            + _frames(t0 + 1.0, t0 + 1.15, 0.25, -0.3) + _frames(t0 + 1.15, t0 + 1.65, -0.3, -0.3))


def test_fire_ring_needs_the_raise_to_be_seen() -> None:
    det = FireRingDetector(FireRingParams())
    joined = _frames(0.0, 1.0, 0.25, 0.25) + _frames(1.0, 1.15, 0.25, -0.3) + _frames(1.15, 2.0, -0.3, -0.3)
    assert _run(det, joined) == []  # arms already up when the stream started
    (c,) = _run(det, _throw(2.0))  # the next throw, raised from below, counts
    assert 2.0 < c.start_s < c.end_s < 3.3
    det = FireRingDetector(FireRingParams(raise_seen=False))
    assert len(_run(det, joined)) == 1  # the rule is what rejects it


def test_fire_ring_keeps_the_seen_arms_across_a_restart_after_another_gesture() -> None:
    # hands resting on the chest at the end of a transformation (-0.09 H: above the "down" level)
    chest = _frames(0.0, 0.5, -0.3, -0.09) + _frames(0.5, 1.0, -0.09, -0.09)
    det = FireRingDetector(FireRingParams())
    _run(det, chest)
    det.reset(keep_seen=True)  # the recogniser restarts the arm detectors after an arm event
    assert len(_run(det, _throw(1.0, start_up=-0.09))) == 1
    det = FireRingDetector(FireRingParams())
    _run(det, chest)
    det.reset()  # a hard reset (gap, glitch): the arms must be seen down again
    assert _run(det, _throw(1.0, start_up=-0.09)) == []


def test_strike_must_come_down_in_front() -> None:
    def chop(fwd: float) -> list[FrameFeatures]:
        return (_frames(0.0, 0.5, -0.3, -0.3, right_only=True) + _frames(0.5, 0.9, -0.3, 0.3, right_only=True)
                + _frames(0.9, 1.0, 0.3, -0.3, fwd=fwd, right_only=True)
                + _frames(1.0, 1.5, -0.3, -0.3, right_only=True))
    assert len(_run(StrikeDetector(StrikeParams()), chop(0.15))) == 1
    assert _run(StrikeDetector(StrikeParams()), chop(-0.1)) == []


def test_arms_passing_in_from_a_t_pose_are_not_raised() -> None:
    """Arms raised to a T (too wide to count as raised), then brought in towards the chest: the one
    frame in which they pass inside 0.36 H at shoulder height is not a raise, and the drop that
    follows is not a fire ring (tracked `transform` x0.8 seed 51 was reported as one)."""
    t_pose = _frames(0.3, 0.6, -0.3, 0.0, out=0.42) + _frames(0.6, 1.2, 0.0, 0.0, out=0.42)
    passing = [FrameFeatures(t=1.2, ok=True, height=1.7, wrist_l=(0.33, -0.05, 0.1), wrist_r=(0.33, -0.05, 0.1),
                             arm_l_ok=True, arm_r_ok=True)]
    frames = _frames(0.0, 0.3, -0.3, -0.3) + t_pose + passing + _frames(1.2 + 1 / HZ, 1.8, -0.28, -0.28, out=0.15)
    assert _run(FireRingDetector(FireRingParams()), frames) == []
    assert len(_run(FireRingDetector(FireRingParams(upright_s=0.0)), frames)) == 1
    assert len(_run(FireRingDetector(FireRingParams()), _throw(0.0))) == 1  # arms held up: still a throw
