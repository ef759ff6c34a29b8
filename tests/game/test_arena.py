"""The pymunk game: gating by the transformation, dodges, hits, knockout, time-out, determinism."""

from __future__ import annotations

import inspect

import pymunk
import pytest

from game_client.game import Game, GameConfig, GameRecord, Phase, PlayerInput

CFG = GameConfig()


def _play(script: dict[float, list[PlayerInput]], seconds: float,
          config: GameConfig = CFG) -> tuple[Game, list[GameRecord]]:
    """Run the game with inputs at given times (rounded to steps)."""
    g = Game(config)
    at = {round(t / config.dt): inp for t, inp in script.items()}
    out: list[GameRecord] = []
    for k in range(round(seconds / config.dt)):
        out += g.step(at.get(k, []))
    return g, out


def _kinds(records: list[GameRecord], kind: str) -> list[GameRecord]:
    return [r for r in records if r.kind == kind]


def test_pymunk_7_collision_api_is_used() -> None:
    assert pymunk.version.startswith("7.")
    assert "begin" in inspect.signature(pymunk.Space.on_collision).parameters
    assert not hasattr(pymunk.Space, "add_collision_handler")


def test_nothing_attacks_before_the_transformation_and_shots_are_ignored() -> None:
    g, recs = _play({1.0: [PlayerInput("strike")], 2.0: [PlayerInput("fire_ring")]}, 15.0)
    assert g.phase == Phase.WAITING
    assert [r.kind for r in recs] == ["ignored", "ignored"]
    assert g.snapshot().round_left_s == CFG.round_time_s


def test_standing_still_is_hit_by_every_attack_until_knockout() -> None:
    g, recs = _play({0.5: [PlayerInput("transform")]}, 30.0)
    attacks = _kinds(recs, "attack")
    assert [a.detail for a in attacks[:4]] == ["high", "side", "high", "side"]
    assert attacks[0].t == pytest.approx(0.5 + CFG.first_attack_s, abs=CFG.dt)
    hits = _kinds(recs, "hit")
    assert [h.actor for h in hits] == ["player"] * 4 and hits[-1].value == 0.0
    end, = _kinds(recs, "round_end")
    assert (end.actor, end.detail) == ("opponent", "knockout")
    assert g.phase == Phase.OVER and g.snapshot().winner == "opponent"


def test_crouch_dodges_high_but_not_side_and_side_step_dodges_side() -> None:
    t0 = 0.5 + CFG.first_attack_s  # first attack (high) wind-up starts here
    t1 = t0 + CFG.attack_period_s  # second (side)
    _, recs = _play({0.5: [PlayerInput("transform")], t0 + 1.0: [PlayerInput("crouch")],
                     t1 + 1.0: [PlayerInput("crouch")]}, t1 + 3.0)
    assert [(r.kind, r.detail) for r in recs if r.kind in ("dodge", "hit")] == [("dodge", "high"), ("hit", "side")]
    _, recs = _play({0.5: [PlayerInput("transform")], t0 + 1.0: [PlayerInput("side_step", "left")],
                     t1 + 1.0: [PlayerInput("side_step", "right")]}, t1 + 3.0)
    assert [(r.kind, r.detail) for r in recs if r.kind in ("dodge", "hit")] == [("hit", "high"), ("dodge", "side")]


def test_side_steps_move_between_lanes_and_stop_at_the_wall() -> None:
    g, _ = _play({0.2: [PlayerInput("side_step", "left")], 0.8: [PlayerInput("side_step", "left")]}, 1.5)
    assert g.lane == 0 and g.player_x == pytest.approx(CFG.lanes[0])
    g, _ = _play({0.2: [PlayerInput("side_step", "right")]}, 1.0)
    assert g.lane == 2 and g.snapshot().player_x == pytest.approx(CFG.lanes[2])


def test_strike_and_fire_ring_fly_and_hit_for_their_damage() -> None:
    g, recs = _play({0.5: [PlayerInput("transform")], 1.0: [PlayerInput("strike")], 1.3: [PlayerInput("strike")],
                     2.0: [PlayerInput("fire_ring")]}, 3.5)
    shots = _kinds(recs, "shot")
    assert [s.detail for s in shots] == ["strike", "fire_ring"]  # the second strike came during the cooldown
    assert [r.kind for r in recs if r.t > 1.2 and r.t < 1.4] == ["ignored"]
    hits = _kinds(recs, "hit")
    assert [(h.actor, h.detail) for h in hits] == [("opponent", "strike"), ("opponent", "fire_ring")]
    assert hits[0].t - shots[0].t == pytest.approx(6.3 / CFG.strike_speed, abs=0.15)  # physical flight time
    end, = _kinds(recs, "round_end")
    assert (end.actor, end.detail) == ("player", "knockout")
    assert g.opponent_health == 0.0


def test_round_ends_on_time_with_the_healthier_fighter_winning() -> None:
    cfg = GameConfig(round_time_s=4.0)
    g, recs = _play({0.5: [PlayerInput("transform")], 1.0: [PlayerInput("strike")]}, 6.0, cfg)
    end, = _kinds(recs, "round_end")
    assert (end.actor, end.detail) == ("player", "time") and end.t == pytest.approx(4.5, abs=cfg.dt)
    assert g.snapshot().round_left_s == 0.0
    g, recs = _play({0.5: [PlayerInput("transform")]}, 6.0, GameConfig(round_time_s=1.0))
    assert _kinds(recs, "round_end")[0].actor == "draw"


def test_projectiles_are_visible_in_the_snapshot() -> None:
    g, _ = _play({0.5: [PlayerInput("transform")]}, 0.5 + CFG.first_attack_s + CFG.windup_s + 0.3)
    snap = g.snapshot()
    (blade,) = snap.projectiles
    assert blade.kind == "high" and blade.width == CFG.width
    assert CFG.player_y < blade.y < CFG.opponent_y
    assert snap.telegraph == "" and snap.phase == Phase.FIGHTING


def test_same_inputs_give_the_same_round() -> None:
    script = {0.3: [PlayerInput("transform")], 3.1: [PlayerInput("crouch")], 4.0: [PlayerInput("strike")],
              7.3: [PlayerInput("side_step", "right")], 8.0: [PlayerInput("fire_ring")]}
    a = _play(script, 12.0)
    b = _play(script, 12.0)
    assert a[1] == b[1]
    assert a[0].snapshot() == b[0].snapshot()


def test_unknown_gesture_is_ignored_not_fatal() -> None:
    _, recs = _play({0.1: [PlayerInput("moonwalk")]}, 0.3)
    assert [(r.kind, r.detail) for r in recs] == [("ignored", "moonwalk")]
