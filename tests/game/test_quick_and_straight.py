"""Two rules a tester found missing: the fire ring's "bring them down quickly" bounds the whole
lowering (a two-second lowering is not a fire ring), and a strike is not a loop (an arm circle,
up in front and down at the side, is not a strike), on clean joints and on joints degraded like a
single-camera tracker's output."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.typing import NDArray

from game_client.detectors import FireRingParams, StrikeParams
from game_client.gestures import Gesture, RecognizerConfig, recognize
from game_client.variants import Variant, variant_motion
from protocol.kinematics import fk
from protocol.skeleton import JOINT_INDEX

HZ = 30.0
_ARM = [JOINT_INDEX[n] for n in ("l_elbow", "l_wrist", "l_hand_tip", "r_elbow", "r_wrist", "r_hand_tip")]
_HANDS = [JOINT_INDEX[n] for n in ("l_wrist", "l_hand_tip", "r_wrist", "r_hand_tip")]
_SHOULDERS = [JOINT_INDEX["l_shoulder"], JOINT_INDEX["r_shoulder"]]


def _clean(name: str, v: Variant | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    m = variant_motion(name, v or Variant(fps=HZ))
    return m.times, fk(m.poses, m.body)


def _hide_pointing(j: NDArray[np.float64], max_cos: float) -> NDArray[np.float64]:
    """Each arm held where it was last seen while it points at (or away from) the camera: the
    shoulder-wrist direction's depth component above ``max_cos`` (a foreshortened arm the tracker
    cannot place; it snaps to the right place when the arm comes out of line)."""
    out = j.copy()
    for names in (("l_shoulder", "l_elbow", "l_wrist", "l_hand_tip"),
                  ("r_shoulder", "r_elbow", "r_wrist", "r_hand_tip")):
        sh, *arm = (JOINT_INDEX[n] for n in names)
        d = j[:, arm[1]] - j[:, sh]
        hidden = np.abs(d[:, 2]) > max_cos * np.linalg.norm(d, axis=1)
        for k in np.flatnonzero(hidden):
            if k > 0:  # the arm as last reported, carried along with the shoulder
                out[k, arm] = out[k - 1, arm] - out[k - 1, sh] + j[k, sh]
    return out


def tracker_like(t: NDArray[np.float64], j: NDArray[np.float64], seed: int, *, jitter_m: float = 0.015,
                 hand_depth_m: float = 0.04, hand_forward_m: float = 0.0, depth_scale: float = 0.6,
                 hide_cos: float | None = 0.8, drop_p: float = 0.05
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Joints degraded as the tracker degrades them (player facing the camera, depth = world Z).

    * an arm pointing at the camera (``hide_cos``, see :func:`_hide_pointing`) is not seen to move:
      the tracker reports the arm circle's raise in front late, as a snap from hanging to overhead;
    * every joint jitters by ``jitter_m`` (s.d. per coordinate and frame);
    * the arms' reach towards or away from the camera is underestimated: each elbow's and hand's
      depth offset from the shoulders is scaled by ``depth_scale`` (the tracked arm circle's raise
      in front reads 0.19 H forward where it is 0.31 H: ``bench/bench_game_tracked.py``);
    * the hands' depth is wrong by a few cm: a slow error of ``hand_depth_m`` amplitude plus as
      much again as per-frame noise, and ``hand_forward_m`` towards the camera (the tracked arm
      circle comes down 0.05-0.15 H further forward than it is: a chop in front);
    * ``drop_p`` of the frames are lost.
    """
    rng = np.random.default_rng(seed)
    out = np.array(j, dtype=np.float64)
    if hide_cos is not None:
        out = _hide_pointing(out, hide_cos)
    shoulders_z = out[:, _SHOULDERS, 2].mean(axis=1, keepdims=True)
    out[:, _ARM, 2] = shoulders_z + depth_scale * (out[:, _ARM, 2] - shoulders_z)
    phase = rng.uniform(0.0, 2 * math.pi, 2)
    slow = hand_depth_m * np.sin(2 * math.pi * 0.7 * t[:, None] + phase[None, :])  # one per hand
    slow = np.repeat(slow, 2, axis=1)  # wrist and hand tip of the same hand move together
    out[:, _HANDS, 2] += hand_forward_m + slow + rng.normal(0.0, hand_depth_m, (len(t), len(_HANDS)))
    out += rng.normal(0.0, jitter_m, out.shape)
    keep = rng.random(len(t)) >= drop_p
    keep[[0, -1]] = True
    return t[keep], out[keep]


def _gestures(t: NDArray[np.float64], j: NDArray[np.float64], config: RecognizerConfig | None = None
              ) -> list[Gesture]:
    return [e.gesture for e in recognize(t, j, config=config)]


# the two-second lowering is the tester's case: the script (3 s) at speed 2/3
LOWERED = [("neg_fire_ring_lowered", Variant(fps=HZ)), ("neg_fire_ring_lowered", Variant(speed=2 / 3, fps=HZ)),
           ("neg_fire_ring_slow", Variant(fps=HZ))]


@pytest.mark.parametrize(("name", "v"), LOWERED)
def test_slow_lowering_is_not_a_fire_ring(name: str, v: Variant) -> None:
    t, j = _clean(name, v)
    assert _gestures(t, j) == []
    for seed in range(5):
        assert _gestures(*tracker_like(t, j, seed)) == [], seed


def test_two_second_lowering_is_rejected_by_the_lowering_bound() -> None:
    """Without the bound the two-second lowering is a fire ring: its last part (shoulders to hips)
    is as quick as a real throw's, only the whole lowering is slow."""
    t, j = _clean("neg_fire_ring_lowered", Variant(speed=2 / 3, fps=HZ))
    assert _gestures(t, j, RecognizerConfig(fire_ring=FireRingParams(max_lower_s=None))) == [Gesture.FIRE_RING]
    # a steady lowering over 1.5 s is quick enough (the bound is 1 s from the top; the slowest real
    # fire ring takes 0.72 s)
    t, j = _clean("neg_fire_ring_lowered", Variant(speed=0.5, fps=HZ))
    assert _gestures(t, j) == [Gesture.FIRE_RING]


@pytest.mark.parametrize("speed", [0.8, 1.0, 1.25])
@pytest.mark.parametrize("forward_m", [0.0, 0.25])
def test_arm_circle_is_not_a_strike(speed: float, forward_m: float) -> None:
    """Also with the hands placed 25 cm (0.15 H) towards the camera, where the "in front" rule
    alone takes the circle's way down for a chop in front (as on tracked video)."""
    t, j = _clean("neg_arm_circle", Variant(speed=speed, fps=HZ))
    assert _gestures(t, j) == []
    for seed in range(5):
        assert _gestures(*tracker_like(t, j, seed, hand_forward_m=forward_m)) == [], seed


def test_arm_circle_is_rejected_by_the_loop_rule_alone() -> None:
    """With the "in front" rule off the loop rule still rejects the circle (whose forward offset is
    what a single camera gets wrong); with both off it is a strike."""
    t, j = _clean("neg_arm_circle")
    no_front = StrikeParams(min_drop_fwd=-math.inf)
    assert _gestures(t, j, RecognizerConfig(strike=no_front)) == []
    for seed in range(5):
        assert _gestures(*tracker_like(t, j, seed), RecognizerConfig(strike=no_front)) == [], seed
    loose = RecognizerConfig(strike=StrikeParams(min_drop_fwd=-math.inf, max_loop_out=None))
    assert _gestures(t, j, loose) == [Gesture.STRIKE]


@pytest.mark.parametrize(("name", "gesture"), [("strike", Gesture.STRIKE), ("fire_ring", Gesture.FIRE_RING)])
@pytest.mark.parametrize("speed", [0.7, 1.0, 1.4])
@pytest.mark.parametrize("forward_m", [0.0, 0.25])
def test_quick_straight_gestures_still_fire(name: str, gesture: Gesture, speed: float, forward_m: float) -> None:
    t, j = _clean(name, Variant(speed=speed, fps=HZ))
    assert _gestures(t, j) == [gesture]
    for seed in range(5):
        assert _gestures(*tracker_like(t, j, seed, hand_forward_m=forward_m)) == [gesture], seed


def test_whole_round_keeps_its_strike_and_fire_ring() -> None:
    t, j = _clean("round_win")
    for seed in range(3):
        got = _gestures(*tracker_like(t, j, seed))
        assert got.count(Gesture.STRIKE) == 1 and got.count(Gesture.FIRE_RING) == 1, (seed, got)
