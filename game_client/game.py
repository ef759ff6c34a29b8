"""The ninja game of Okada & Stenger §4 as a deterministic 2D physics simulation (pymunk 7).

Pure: no clock, no I/O. :meth:`Game.step` advances the world by one fixed time step with the
player's inputs (recognised gestures); the same inputs at the same steps always give the same
world, events and outcome.

The arena (seen from above, metres)
-----------------------------------
The player (a ninja avatar) stands near ``y = player_y`` in one of three lanes ``x = lanes``; the
opponent faces them near ``y = opponent_y`` and sways slowly left and right. The player's left is
-x (screen left), like a mirror.

* The round starts in the ``waiting`` phase: the player is still human and nothing attacks.
  The **transform** gesture turns the avatar into a ninja and starts the fight (and the round
  clock); strikes and fire rings before that are ignored.
* The opponent **attacks on a schedule**: every ``attack_period_s`` (first one ``first_attack_s``
  after the transformation) it winds up for ``windup_s`` and throws either a **high** attack (a
  blade as wide as the arena at head height; only a **crouch** avoids it: while crouched the
  player's hitbox no longer collides with high attacks) or a **sideways** attack (a fireball aimed
  at the player's lane at release; a **side-step** to another lane avoids it).
* The player's **strike** throws a fast small blade and the **fire ring** a large slow ring, both
  aimed at the opponent's position at release; physics (pymunk sensors and collision callbacks
  registered with ``space.on_collision``) decides whether they hit.
* Hits take health; the round ends on a **knockout** (health 0) or when the round clock runs out
  (**time**; the healthier fighter wins).

A sideways attack is aimed at the lane the player stood in when the opponent *started* winding
up (the telegraph), so a side-step any time during the wind-up or the flight avoids it; a crouch
protects for ``crouch_s`` after it is recognised.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
import pymunk

__all__ = ["Game", "GameConfig", "GameRecord", "GameSnapshot", "Phase", "PlayerInput", "Projectile"]


class Phase(StrEnum):
    """Where the round is."""

    WAITING = "waiting"  # human form, waiting for the transformation
    FIGHTING = "fighting"
    OVER = "over"


# collision types and filter categories
_PLAYER, _OPPONENT, _HIGH, _SIDE, _STRIKE, _RING, _WALL = 1, 2, 3, 4, 5, 6, 7
_CAT_PLAYER, _CAT_OPPONENT, _CAT_HIGH, _CAT_SIDE, _CAT_OWN, _CAT_WALL = 1, 2, 4, 8, 16, 32
_KIND_OF = {_HIGH: "high", _SIDE: "side", _STRIKE: "strike", _RING: "fire_ring"}


@dataclass(frozen=True)
class GameConfig:
    """Rules and arena of the game (SI units; a strike and a fire ring knock the opponent out, four
    hits knock the player out)."""

    dt: float = 1.0 / 120.0
    round_time_s: float = 60.0
    width: float = 8.0
    depth: float = 10.0
    lanes: tuple[float, ...] = (2.5, 4.0, 5.5)
    player_y: float = 1.5
    opponent_y: float = 8.5
    player_radius: float = 0.4
    opponent_radius: float = 0.5
    health: float = 100.0
    first_attack_s: float = 2.0
    attack_period_s: float = 5.0
    windup_s: float = 0.8
    attack_pattern: tuple[str, ...] = ("high", "side")
    attack_speed: float = 6.0
    attack_damage: float = 25.0
    strike_speed: float = 12.0
    strike_radius: float = 0.2
    strike_damage: float = 40.0
    ring_speed: float = 7.0
    ring_radius: float = 0.55
    ring_damage: float = 60.0
    crouch_s: float = 1.0
    step_s: float = 0.25
    shot_cooldown_s: float = 0.4
    sway_amplitude: float = 1.0
    sway_period_s: float = 7.0


@dataclass(frozen=True)
class PlayerInput:
    """A recognised gesture handed to the game (``direction`` for side-steps)."""

    gesture: str
    direction: str | None = None
    confidence: float = 1.0


@dataclass(frozen=True)
class GameRecord:
    """Something that happened in the game.

    ``kind`` is one of ``transform``, ``attack``, ``dodge``, ``hit``, ``miss``, ``shot``,
    ``ignored``, ``round_end``; ``actor`` who did it (``player``/``opponent``; for ``hit`` the
    one hit; for ``round_end`` the winner or ``draw``); ``detail`` the attack or gesture kind (or
    the end reason); ``value`` damage or health where it applies.
    """

    t: float
    kind: str
    actor: str = ""
    detail: str = ""
    value: float = 0.0


@dataclass(frozen=True)
class Projectile:
    """A flying attack: kind (``high``/``side``/``strike``/``fire_ring``), position and size."""

    kind: str
    x: float
    y: float
    radius: float
    width: float = 0.0  # full width of a high blade


@dataclass(frozen=True)
class GameSnapshot:
    """The world at one step."""

    tick: int
    t: float
    phase: Phase
    round_left_s: float
    player_health: float
    opponent_health: float
    player_x: float
    player_lane: int
    crouching: bool
    opponent_x: float
    telegraph: str  # attack being wound up ("" if none)
    projectiles: tuple[Projectile, ...]
    winner: str = ""
    end_reason: str = ""
    telegraph_left_s: float = 0.0  # until the attack being wound up is thrown


@dataclass
class _Shot:
    kind: str
    body: pymunk.Body
    shape: pymunk.Shape
    width: float = 0.0
    done: bool = False


@dataclass
class Game:
    """One round of the game. Drive it with :meth:`step`; read it with :meth:`snapshot`."""

    config: GameConfig = field(default_factory=GameConfig)

    def __post_init__(self) -> None:
        c = self.config
        self.tick = 0
        self.t = 0.0
        self.phase = Phase.WAITING
        self.fight_start = math.inf
        self.player_health = self.opponent_health = c.health
        self.lane = len(c.lanes) // 2
        self.player_x = c.lanes[self.lane]
        self.crouch_until = -math.inf
        self.next_shot = 0.0
        self.winner = self.end_reason = ""
        self.end_t = math.inf
        self._attack_index = 0
        self._telegraph: tuple[float, str, float] | None = None  # release time, kind, aim x
        self._shots: list[_Shot] = []
        self._contacts: list[tuple[int, pymunk.Shape]] = []
        self.space = pymunk.Space()
        self.space.gravity = (0.0, 0.0)
        self._player = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        self._player.position = (self.player_x, c.player_y)
        self._player_shape = pymunk.Circle(self._player, c.player_radius)
        self._player_shape.collision_type, self._player_shape.sensor = _PLAYER, True
        self._opponent = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        self._opponent.position = (c.width / 2, c.opponent_y)
        opp = pymunk.Circle(self._opponent, c.opponent_radius)
        opp.collision_type, opp.sensor = _OPPONENT, True
        opp.filter = pymunk.ShapeFilter(categories=_CAT_OPPONENT)
        self._set_crouch(False)
        walls = [pymunk.Segment(self.space.static_body, a, b, 0.05) for a, b in (
            ((0, -0.5), (c.width, -0.5)), ((0, c.depth + 0.5), (c.width, c.depth + 0.5)),
            ((-0.5, 0), (-0.5, c.depth)), ((c.width + 0.5, 0), (c.width + 0.5, c.depth)))]
        for w in walls:
            w.collision_type, w.sensor = _WALL, True
            w.filter = pymunk.ShapeFilter(categories=_CAT_WALL)
        self.space.add(self._player, self._player_shape, self._opponent, opp, *walls)
        for kind in (_HIGH, _SIDE):
            self.space.on_collision(kind, _PLAYER, begin=self._on_contact)
            self.space.on_collision(kind, _WALL, begin=self._on_contact)
        for kind in (_STRIKE, _RING):
            self.space.on_collision(kind, _OPPONENT, begin=self._on_contact)
            self.space.on_collision(kind, _WALL, begin=self._on_contact)

    # ------------------------------------------------------------------ physics helpers
    def _on_contact(self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: Any) -> None:
        a, b = arbiter.shapes
        self._contacts.append((b.collision_type, a))  # (what it touched, the projectile's shape)

    def _set_crouch(self, crouched: bool) -> None:
        mask = pymunk.ShapeFilter.ALL_MASKS() ^ (_CAT_HIGH if crouched else 0)
        self._player_shape.filter = pymunk.ShapeFilter(categories=_CAT_PLAYER, mask=mask)

    def _launch(self, kind: str, start: tuple[float, float], target: tuple[float, float], speed: float) -> None:
        c = self.config
        body = pymunk.Body(1.0, math.inf)
        body.position = start
        dx, dy = target[0] - start[0], target[1] - start[1]
        norm = math.hypot(dx, dy) or 1.0
        body.velocity = (speed * dx / norm, speed * dy / norm)
        width = 0.0
        shape: pymunk.Shape
        if kind == "high":
            width = c.width
            shape = pymunk.Segment(body, (-c.width / 2, 0.0), (c.width / 2, 0.0), 0.15)
            ctype, cat = _HIGH, _CAT_HIGH
        else:
            radius = {"side": 0.35, "strike": c.strike_radius, "fire_ring": c.ring_radius}[kind]
            shape = pymunk.Circle(body, radius)
            ctype, cat = {"side": (_SIDE, _CAT_SIDE), "strike": (_STRIKE, _CAT_OWN),
                          "fire_ring": (_RING, _CAT_OWN)}[kind]
        shape.collision_type, shape.sensor = ctype, True
        shape.filter = pymunk.ShapeFilter(categories=cat)
        self.space.add(body, shape)
        self._shots.append(_Shot(kind, body, shape, width))

    # ------------------------------------------------------------------ the step
    def step(self, inputs: list[PlayerInput] | tuple[PlayerInput, ...] = ()) -> list[GameRecord]:
        """Advance the world by ``config.dt`` after applying the player's inputs.

        Returns
        -------
        list of GameRecord
            What happened during this step, in order.
        """
        c = self.config
        out: list[GameRecord] = []
        if self.phase != Phase.OVER:
            for inp in inputs:
                out += self._apply(inp)
        self.tick += 1
        self.t = self.tick * c.dt
        if self.phase == Phase.FIGHTING:
            out += self._opponent_ai()
        # kinematics: the player's lane change and the opponent's sway
        target = c.lanes[self.lane]
        move = (c.lanes[1] - c.lanes[0]) / c.step_s * c.dt
        self.player_x += max(-move, min(move, target - self.player_x))
        self._player.position = (self.player_x, c.player_y)
        if self.phase == Phase.FIGHTING:
            self._opponent.position = self._opponent_at(self.t)
        self._set_crouch(self.t < self.crouch_until)
        self._contacts.clear()
        self.space.step(c.dt)
        out += self._resolve_contacts()
        if self.phase == Phase.FIGHTING:
            out += self._check_end()
        return out

    def _apply(self, inp: PlayerInput) -> list[GameRecord]:
        c, t = self.config, self.t
        g = inp.gesture
        if g == "transform":
            if self.phase == Phase.WAITING:
                self.phase, self.fight_start = Phase.FIGHTING, t
                return [GameRecord(t, "transform", "player", "ninja")]
            return [GameRecord(t, "ignored", "player", "transform", 0.0)]
        if g == "crouch":
            self.crouch_until = t + c.crouch_s
            return []
        if g == "side_step":
            step = -1 if inp.direction == "left" else 1 if inp.direction == "right" else 0
            self.lane = min(max(self.lane + step, 0), len(c.lanes) - 1)
            return []
        if g in ("strike", "fire_ring"):
            if self.phase != Phase.FIGHTING or t < self.next_shot:
                return [GameRecord(t, "ignored", "player", g)]
            self.next_shot = t + c.shot_cooldown_s
            speed = c.strike_speed if g == "strike" else c.ring_speed
            start = (self.player_x, c.player_y + c.player_radius + 0.3)
            self._launch(g, start, self._lead(start, speed), speed)
            return [GameRecord(t, "shot", "player", g)]
        return [GameRecord(t, "ignored", "player", g)]

    def _opponent_at(self, t: float) -> tuple[float, float]:
        c = self.config
        sway = c.sway_amplitude * math.sin(2 * math.pi * (t - self.fight_start) / c.sway_period_s)
        return c.width / 2 + sway, c.opponent_y

    def _lead(self, start: tuple[float, float], speed: float) -> tuple[float, float]:
        """Where to aim so a shot at ``speed`` meets the swaying opponent (a few fixed-point steps)."""
        t_hit = 0.0
        for _ in range(4):
            x, y = self._opponent_at(self.t + t_hit)
            t_hit = math.hypot(x - start[0], y - start[1]) / speed
        return self._opponent_at(self.t + t_hit)

    def _opponent_ai(self) -> list[GameRecord]:
        c, t = self.config, self.t
        out = []
        due = self.fight_start + c.first_attack_s + self._attack_index * c.attack_period_s
        if self._telegraph is None and t >= due:
            kind = c.attack_pattern[self._attack_index % len(c.attack_pattern)]
            self._telegraph = (t + c.windup_s, kind, self.player_x)
            self._attack_index += 1
            out.append(GameRecord(t, "attack", "opponent", kind))
        if self._telegraph is not None and t >= self._telegraph[0]:
            kind = self._telegraph[1]
            start = (float(self._opponent.position.x), c.opponent_y - c.opponent_radius - 0.3)
            if kind == "high":
                self._launch("high", (c.width / 2, start[1]), (c.width / 2, c.player_y), c.attack_speed)
            else:
                self._launch("side", start, (self._telegraph[2], c.player_y), c.attack_speed)
            self._telegraph = None
        return out

    def _resolve_contacts(self) -> list[GameRecord]:
        c, t = self.config, self.t
        out = []
        for touched, shape in self._contacts:
            shot = next((s for s in self._shots if s.shape is shape and not s.done), None)
            if shot is None:
                continue
            shot.done = True
            if touched == _PLAYER:
                self.player_health = max(0.0, self.player_health - c.attack_damage)
                out.append(GameRecord(t, "hit", "player", shot.kind, self.player_health))
            elif touched == _OPPONENT:
                dmg = c.strike_damage if shot.kind == "strike" else c.ring_damage
                self.opponent_health = max(0.0, self.opponent_health - dmg)
                out.append(GameRecord(t, "hit", "opponent", shot.kind, self.opponent_health))
            elif shot.kind in ("high", "side"):
                out.append(GameRecord(t, "dodge", "player", shot.kind))
            else:
                out.append(GameRecord(t, "miss", "player", shot.kind))
        for s in [s for s in self._shots if s.done]:
            self.space.remove(s.body, s.shape)
        self._shots = [s for s in self._shots if not s.done]
        return out

    def _check_end(self) -> list[GameRecord]:
        c = self.config
        reason = ""
        if self.player_health <= 0 or self.opponent_health <= 0:
            reason = "knockout"
        elif self.t - self.fight_start >= c.round_time_s:
            reason = "time"
        if not reason:
            return []
        self.phase, self.end_reason, self.end_t = Phase.OVER, reason, self.t
        if self.player_health == self.opponent_health:
            self.winner = "draw"
        else:
            self.winner = "player" if self.player_health > self.opponent_health else "opponent"
        return [GameRecord(self.t, "round_end", self.winner, reason, self.player_health - self.opponent_health)]

    def snapshot(self) -> GameSnapshot:
        """The current state of the world."""
        c = self.config
        shots = tuple(Projectile(s.kind, float(s.body.position.x), float(s.body.position.y),
                                 0.15 if s.kind == "high" else float(getattr(s.shape, "radius", 0.0)), s.width)
                      for s in self._shots)
        now = min(self.t, self.end_t)
        left = c.round_time_s if self.phase == Phase.WAITING else max(0.0, c.round_time_s - (now - self.fight_start))
        return GameSnapshot(
            tick=self.tick, t=self.t, phase=self.phase, round_left_s=left,
            player_health=self.player_health, opponent_health=self.opponent_health,
            player_x=self.player_x, player_lane=self.lane, crouching=self.t < self.crouch_until,
            opponent_x=float(self._opponent.position.x),
            telegraph=self._telegraph[1] if self._telegraph else "",
            projectiles=shots, winner=self.winner, end_reason=self.end_reason,
            telegraph_left_s=max(0.0, self._telegraph[0] - self.t) if self._telegraph else 0.0,
        )

    def lane_of(self, x: float) -> int:
        """Index of the lane nearest to ``x``."""
        return int(np.argmin([abs(x - lx) for lx in self.config.lanes]))
