"""The recogniser on what a single-camera tracker really outputs: the heading wanders while the
player faces the camera, a frame or two of garbage with near-zero confidence, hands on the chest
reported low and wide (measured on tracked synthetic video, ``bench/bench_game_tracked.py``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import NDArray

from game_client.body_detectors import SideStepDetector, SideStepParams
from game_client.detectors import Candidate, TransformDetector, TransformParams
from game_client.evaluation import turn_in_place
from game_client.features import FrameFeatures, ScreenFacing
from game_client.gestures import Gesture, GestureRecognizer, RecognizerConfig, recognize
from game_client.variants import Variant, variant_motion
from protocol.kinematics import fk

HZ = 30.0


def _script(name: str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    m = variant_motion(name, Variant(fps=HZ))
    return m.times, fk(m.poses, m.body)


def _bump(t: NDArray[np.float64], t0: float, t1: float, amp: float) -> NDArray[np.float64]:
    """0 before ``t0``, up to ``amp`` and back to 0 at ``t1`` (a heading excursion)."""
    return amp * np.sin(np.pi * np.clip((t - t0) / (t1 - t0), 0.0, 1.0))


def test_screen_facing_tells_a_wander_from_a_turned_player() -> None:
    s = ScreenFacing()
    # facing the screen, then a 30-degree swing both ways and back (as tracked while stepping)
    wander = np.radians(np.r_[np.zeros(20), 30.0 * np.sin(np.linspace(0.0, 2 * np.pi, 20))])
    assert s.faced(wander)[0]  # over the whole history: on average 9.5 degrees off
    turned = np.radians(np.full(40, 35.0))  # within max_deg, but turned away the whole time
    assert not s.faced(turned).any()
    beyond = np.radians(np.r_[np.zeros(30), np.full(10, 45.0)])  # ends facing 45 degrees away
    assert not s.faced(beyond).any()
    assert s.faced(beyond[:30]).all()
    # the screen can be anywhere: the same wander around 90 degrees
    assert ScreenFacing(yaw_deg=90.0).faced(wander + np.pi / 2)[0]
    assert not ScreenFacing(yaw_deg=90.0).faced(wander)[0]


@pytest.mark.parametrize(("name", "side"), [("side_step_left", "left"), ("side_step_right", "right")])
@pytest.mark.parametrize("amp", [30.0, -30.0])
def test_side_step_survives_a_heading_wander(name: str, side: str, amp: float) -> None:
    """The tracked facing swings to 30 degrees and back during the step, the ground path is right:
    the screen frame finds the step, the body frame alone does not (turn > 20 degrees)."""
    t, j = _script(name)
    wandered = turn_in_place(j, _bump(t, 0.4, 1.3, amp))
    assert [(e.gesture, e.direction) for e in recognize(t, wandered)] == [(Gesture.SIDE_STEP, side)]
    assert recognize(t, wandered, config=RecognizerConfig(step_screen=None)) == []


@pytest.mark.parametrize("yaw", [35.0, -35.0])
def test_walking_along_the_screen_while_turned_away_is_not_a_side_step(yaw: float) -> None:
    """A player turned 35 degrees who moves along the screen moves diagonally for their own body
    (the Bandai sideways walks): neither frame accepts it."""
    t, j = _script("side_step_left")
    assert recognize(t, turn_in_place(j, yaw)) == []


def test_in_place_rule_allows_a_wander_but_not_a_turn() -> None:
    t, j = _script("fire_ring")
    swing = turn_in_place(j, 35.0 * np.sin(2 * np.pi * t))  # 70 degrees of range around the screen
    assert [e.gesture for e in recognize(t, swing)] == [Gesture.FIRE_RING]
    assert recognize(t, swing, config=RecognizerConfig(still_screen=None)) == []
    off_screen = turn_in_place(j, 25.0 + 35.0 * np.sin(2 * np.pi * t))  # the same swing, up to 60 off
    assert recognize(t, off_screen) == []
    spin = turn_in_place(j, 60.0 * np.clip(t - 0.2, 0.0, None))  # a real turn while throwing
    assert recognize(t, spin) == []


def test_low_confidence_garbage_frames_are_not_read() -> None:
    """Three frames in the middle of a step with the body thrown 1.7 m in depth at confidence 0.01
    (as the tracker reports when it loses the pose): skipped, not a glitch that resets the step."""
    t, j = _script("side_step_right")
    bad = np.flatnonzero((t >= 0.9) & (t < 1.0))
    assert len(bad) == 3
    j = j.copy()
    j[bad, :, 2] -= 1.7
    conf = np.ones(len(t))
    conf[bad] = 0.01
    events = recognize(t, j, confidence=conf)
    assert [(e.gesture, e.direction) for e in events] == [(Gesture.SIDE_STEP, "right")]
    assert recognize(t, j, confidence=conf, config=RecognizerConfig(min_confidence=0.0)) == []
    rec = GestureRecognizer()
    for k in range(len(t)):
        rec.update(float(t[k]), j[k], confidence=float(conf[k]))
    assert rec.counters["low_confidence"] == 3 and rec.counters["glitches"] == 0


def _transform_frames(chest: tuple[float, float, float]) -> list[FrameFeatures]:
    """Arms out to the sides for 0.5 s, then both wrists moved to ``chest`` in 0.3 s and held 0.4 s."""
    out: list[FrameFeatures] = []
    start = np.array([0.43, 0.0, 0.0])
    for t in np.arange(0.0, 1.2, 1.0 / HZ):
        a = float(np.clip((t - 0.5) / 0.3, 0.0, 1.0))
        x, y, z = ((1 - a) * start + a * np.asarray(chest)).tolist()
        out.append(FrameFeatures(t=float(t), ok=True, height=1.7, wrist_l=(x, y, z), wrist_r=(x, y, z),
                                 arm_l_ok=True, arm_r_ok=True))
    return out


def _run(det: TransformDetector, frames: list[FrameFeatures]) -> list[Candidate]:
    return [c for f in frames if (c := det.update(f)) is not None]


def test_transform_accepts_the_hands_where_the_tracker_puts_them_on_the_chest() -> None:
    """Hands on the chest are tracked lower and wider than they are (median 0.20 H below the
    shoulders, up to 0.12 H out); hands hanging at the sides (0.16 H out, 0.31 H down) are not on it."""
    tracked_chest = (0.12, -0.25, 0.10)
    assert len(_run(TransformDetector(TransformParams()), _transform_frames(tracked_chest))) == 1
    old = TransformParams(chest_out_max=0.10, chest_up_min=-0.24)
    assert _run(TransformDetector(old), _transform_frames(tracked_chest)) == []
    for hanging in ((0.16, -0.31, 0.03), (0.12, -0.30, 0.03)):
        assert _run(TransformDetector(TransformParams()), _transform_frames(hanging)) == []


def _step_frames(trail_m: float) -> list[FrameFeatures]:
    """Facing +Z, pelvis 0.35 m and left foot 0.45 m to the player's left (+X) in 0.6 s, the right
    foot ``trail_m``; then 0.6 s at rest."""
    out = []
    for t in np.arange(0.0, 1.8, 1.0 / HZ):
        a = float(np.clip((t - 0.4) / 0.6, 0.0, 1.0))
        out.append(FrameFeatures(t=float(t), ok=True, height=1.7, yaw=0.0, left_xz=(1.0, 0.0),
                                 pelvis_xz=(0.35 * a, 0.0), ankle_l_xz=(0.1 + 0.45 * a, 0.0),
                                 ankle_r_xz=(-0.1 + trail_m * a, 0.0), legs_ok=True))
    return out


def test_side_step_needs_the_trailing_foot_to_follow() -> None:
    """A dance lunge (pelvis and leading foot sideways, the other foot planted) is not a step; on
    rotated real dance takes it was the one false side-step of the screen frame."""
    def run(trail_m: float, p: SideStepParams) -> list[Candidate]:
        det = SideStepDetector(p, ScreenFacing())
        return [c for f in _step_frames(trail_m) if (c := det.update(f)) is not None]
    (c,) = run(0.25, SideStepParams())
    assert c.direction == "left"
    assert run(0.0, SideStepParams()) == []
    assert len(run(0.0, SideStepParams(trail_min=-1.0))) == 1


Key = tuple[float, tuple[float, float, float], tuple[float, float, float], float]
_T_POSE: tuple[tuple[float, float, float], tuple[float, float, float]] = ((0.43, 0.0, 0.03), (0.28, 0.0, 0.01))
_FOLDING = ((0.26, -0.18, 0.05), (0.22, -0.12, -0.03))  # on the way in, the wrists still well out
_TRACKED_CHEST = ((0.14, -0.29, 0.06), (0.15, -0.17, -0.05))  # hands on the chest as tracked: low, elbows bent


def _arm_frames(keys: list[Key], end_s: float = 1.4) -> list[FrameFeatures]:
    """Both arms alike, linearly between keys ``(t, wrist, elbow, bend_deg)`` (features in H)."""
    kt = [k[0] for k in keys]
    table = np.array([[*k[1], *k[2], k[3]] for k in keys])
    out = []
    for t in np.arange(0.0, end_s, 1.0 / HZ):
        v = [float(np.interp(t, kt, table[:, i])) for i in range(7)]
        wrist, elbow = (v[0], v[1], v[2]), (v[3], v[4], v[5])
        out.append(FrameFeatures(t=float(t), ok=True, height=1.7, wrist_l=wrist, wrist_r=wrist, elbow_l=elbow,
                                 elbow_r=elbow, bend_l=v[6], bend_r=v[6], arm_l_ok=True, arm_r_ok=True))
    return out


def _transform_keys(t_bend: float = 10.0, fold_bend: float = 70.0,
                    chest: tuple[tuple[float, float, float], tuple[float, float, float]] = _TRACKED_CHEST,
                    chest_bend: float = 60.0) -> list[Key]:
    """Arms out to the sides (elbow bend ``t_bend``) for 0.5 s, folded on the way in, resting at ``chest``."""
    return [(0.0, *_T_POSE, t_bend), (0.5, *_T_POSE, t_bend), (0.6, *_FOLDING, fold_bend),
            (0.7, *chest, chest_bend)]


def test_transform_from_bent_elbows_where_the_tracker_loses_the_hands() -> None:
    """The tracker reports hands resting on the chest low and at the sides' width (0.14 H out, 0.29 H
    down, like hanging hands; `round_win` seed 0, `transform` x0.8 seed 21) but with the elbows bent
    50-90 degrees, and the arms fold while still out (a hanging arm is tracked bent < 35 degrees)."""
    frames = _arm_frames(_transform_keys())
    (c,) = _run(TransformDetector(TransformParams()), frames)
    assert c.end_s == pytest.approx(0.7, abs=0.05)
    assert _run(TransformDetector(TransformParams(bent_min_deg=None)), frames) == []  # the chest zone misses it


def test_arms_lowered_straight_then_tracked_bent_are_not_a_transform() -> None:
    """Arms lowered straight from the T (`neg_arms_out_down`), the tracker bending the hanging arms
    only once they are down (seed 42), or a little on the way down (seeds 71-72): they did not fold
    on the way in."""
    keys: list[Key] = [(0.0, *_T_POSE, 10.0), (0.5, *_T_POSE, 10.0), (0.6, *_FOLDING, 25.0),
                       (0.7, *_TRACKED_CHEST, 25.0), (0.8, *_TRACKED_CHEST, 70.0)]
    assert _run(TransformDetector(TransformParams()), _arm_frames(keys)) == []
    assert len(_run(TransformDetector(TransformParams(fold_out_min=0.0)), _arm_frames(keys))) == 1
    # person 71: the straight arms are tracked folding to 52 degrees on the way down, hanging bent 42
    keys = [(0.0, *_T_POSE, 10.0), (0.5, *_T_POSE, 10.0), (0.6, *_FOLDING, 52.0), (0.7, *_TRACKED_CHEST, 42.0)]
    assert _run(TransformDetector(TransformParams()), _arm_frames(keys)) == []
    assert len(_run(TransformDetector(TransformParams(fold_min_deg=50.0)), _arm_frames(keys))) == 1


def test_bent_arms_out_then_lowered_are_not_a_transform() -> None:
    """Both hands waved with the elbows bent 35 degrees at the sides, then lowered with bent elbows
    (`wave-both-hands_masculine_001`): the arms were never straight in the T."""
    frames = _arm_frames(_transform_keys(t_bend=35.0))
    assert _run(TransformDetector(TransformParams()), frames) == []
    assert len(_run(TransformDetector(TransformParams(straight_max_deg=40.0)), frames)) == 1


def test_hands_to_the_face_are_not_on_the_chest() -> None:
    """Arms out, then folded with the hands at the mouth (`call_normal_002`): the bent path stops
    0.10 H below the shoulders."""
    face = ((0.15, -0.03, 0.18), (0.22, -0.12, 0.08))
    frames = _arm_frames(_transform_keys(chest=face, chest_bend=110.0))
    assert _run(TransformDetector(TransformParams(chest_out_max=0.10)), frames) == []
    assert len(_run(TransformDetector(TransformParams(chest_out_max=0.10, bent_up_max=0.0)), frames)) == 1


def test_bent_hands_passing_through_do_not_rest_on_the_chest() -> None:
    """Folded arms that keep going down (1 H/s) through the bent zone are not resting on the chest."""
    low = ((0.14, -0.55, 0.06), (0.15, -0.30, -0.05))
    keys = [*_transform_keys(chest=((0.14, -0.12, 0.06), (0.15, -0.10, -0.05))), (1.13, *low, 60.0)]
    p = TransformParams(chest_out_max=0.10)  # keep the chest zone out of it
    assert _run(TransformDetector(p), _arm_frames(keys)) == []
    assert len(_run(TransformDetector(TransformParams(chest_out_max=0.10, bent_hold_s=0.0)), _arm_frames(keys))) == 1


def test_hands_resting_on_the_chest_may_jump_in_depth() -> None:
    """The tracker's depth of a hand on the chest jumps by 0.1-0.2 H between frames (`transform`
    x1.25 seed 72: one wrist from 0.09 H in front of the shoulders to 0.08 H behind); the hands rest if
    they stay put across and along the screen (out, up), not if they move there."""
    def jitter(axis: int, amp: float) -> list[FrameFeatures]:
        out = []
        for k, f in enumerate(_transform_frames((0.10, -0.20, 0.04))):
            if f.t > 0.8 and f.wrist_l is not None:
                w = list(f.wrist_l)
                w[axis] += amp * (k % 2)
                f = replace(f, wrist_l=(w[0], w[1], w[2]))
            out.append(f)
        return out

    assert len(_run(TransformDetector(TransformParams()), jitter(2, 0.15))) == 1  # depth: 0.04 <-> 0.19
    assert _run(TransformDetector(TransformParams()), jitter(1, 0.09)) == []  # up and down: not resting
