"""Messages of the game client (``mocap/game/<id>/event`` and ``.../state``) and their wire codec.

``GameEvent`` and ``GameState`` are frozen dataclasses with a ``schema_version``, like the tracker's
messages in :mod:`protocol.wire.messages`. On the wire they follow :mod:`protocol.wire.codec`'s conventions
exactly: one msgpack map of the constructor fields plus ``"type"`` (``"game_event"`` /
``"game_state"``), float arrays as float32, every field required, unknown or duplicate keys and
other schema versions rejected, and :func:`decode_game` raising only
:class:`protocol.wire.codec.ProtocolError` whatever the bytes.

Importing this module registers both types with :func:`protocol.wire.codec.register_message`, so
:func:`protocol.wire.codec.encode` / :func:`~protocol.wire.codec.decode` handle them; :func:`encode_game` and
:func:`decode_game` are the same functions restricted to game messages.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from enum import StrEnum
from typing import Any, Final, TypeVar, overload

import numpy as np
from numpy.typing import NDArray

from protocol.wire import codec as codec
from protocol.wire.codec import ProtocolError
from protocol.wire.messages import SCHEMA_VERSION

__all__ = ["GAME_ROWS", "MAX_PROJECTILES", "PROJECTILE_KINDS", "GameEvent", "GameEventKind", "GamePhase",
           "GameState", "decode_game", "encode_game", "pack_projectiles", "unpack_projectiles"]

#: Rows of the projectile table in ``GameState`` (extra projectiles are not sent).
MAX_PROJECTILES: Final[int] = 16
#: Projectile kind codes in column 0 of ``GameState.projectiles`` (0 = empty row).
PROJECTILE_KINDS: Final[tuple[str, ...]] = ("", "high", "side", "strike", "fire_ring")
T = TypeVar("T")


class GameEventKind(StrEnum):
    """What a ``GameEvent`` reports."""

    GESTURE = "gesture"  # the recogniser saw a gesture (gesture, direction, times, confidence, latency)
    TRANSFORM = "transform"  # the player became a ninja: the fight starts
    ATTACK = "attack"  # the opponent winds up an attack (detail: high / side)
    DODGE = "dodge"  # an opponent's attack missed the player
    HIT = "hit"  # someone was hit (actor: who; detail: by what; value: health left)
    MISS = "miss"  # a player's shot left the arena
    SHOT = "shot"  # the player threw a strike or fire ring
    IGNORED = "ignored"  # a gesture that had no effect (e.g. a strike before the transformation)
    ROUND_END = "round_end"  # actor: winner (player / opponent / draw); detail: knockout / time


class GamePhase(StrEnum):
    """Phase of the round."""

    WAITING = "waiting"
    FIGHTING = "fighting"
    OVER = "over"


@dataclass(frozen=True)
class GameEvent:
    """One event of a game client.

    Attributes
    ----------
    game_id : str
        Id of the game client (also in the key expression).
    seq : int
        Event number, from 0, +1 per event.
    t : float
        Game time, seconds since the round's first pose.
    stream_ts : float
        ``capture_ts`` of the pose frame that caused it, seconds.
    kind : GameEventKind
    actor, detail : str
        Who and what (see :class:`GameEventKind`); may be empty.
    value : float
        Health left after a hit, health difference at the round's end, else 0.
    gesture, direction : str
        For ``gesture`` events: the gesture and the side-step's direction (``left``/``right``).
    start_s, end_s : float
        For ``gesture`` events: pose-stream times the gesture started and ended.
    confidence : float
        For ``gesture`` events, in [0, 1].
    latency_ms : float
        For ``gesture`` events: recognition time minus the gesture's end, milliseconds.
    schema_version : int
    """

    game_id: str
    seq: int
    t: float
    stream_ts: float
    kind: GameEventKind
    actor: str = ""
    detail: str = ""
    value: float = 0.0
    gesture: str = ""
    direction: str = ""
    start_s: float = 0.0
    end_s: float = 0.0
    confidence: float = 0.0
    latency_ms: float = 0.0
    schema_version: int = SCHEMA_VERSION

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", GameEventKind(self.kind))


@dataclass(frozen=True)
class GameState:
    """Snapshot of a game client's round, published a few times per second.

    Attributes
    ----------
    game_id : str
    seq : int
        State number, from 0.
    t : float
        Game time, seconds.
    stream_ts : float
        ``capture_ts`` of the latest pose frame, seconds.
    tick : int
        Fixed game steps so far.
    phase : GamePhase
    round_left_s : float
        Seconds left on the round clock (the full round before the transformation).
    player_health, opponent_health : float
        Health points, >= 0.
    player_x, opponent_x : float
        Arena x of the two fighters, metres.
    player_lane : int
        Lane index of the player (0 = the player's far left).
    player_stance : str
        ``standing`` or ``crouching``.
    telegraph : str
        Attack the opponent is winding up (``high``/``side``) or empty.
    projectiles : (MAX_PROJECTILES, 5) float32
        One row per flying projectile: kind code (:data:`PROJECTILE_KINDS`), x, y, radius and
        width (metres); unused rows are zero.
    n_projectiles : int
        Rows in use.
    winner, end_reason : str
        Set when the round is over.
    frames : int
        Pose frames processed.
    counters : dict[str, int]
        ``decode_errors``, ``bad_frames``, ``tracker_restarts``... all >= 0.
    schema_version : int
    """

    game_id: str
    seq: int
    t: float
    stream_ts: float
    tick: int
    phase: GamePhase
    round_left_s: float
    player_health: float
    opponent_health: float
    player_x: float
    player_lane: int
    player_stance: str
    opponent_x: float
    telegraph: str = ""
    projectiles: NDArray[np.float32] = field(default_factory=lambda: np.zeros((MAX_PROJECTILES, 5), np.float32))
    n_projectiles: int = 0
    winner: str = ""
    end_reason: str = ""
    frames: int = 0
    counters: dict[str, int] = field(default_factory=dict)
    schema_version: int = SCHEMA_VERSION

    def __post_init__(self) -> None:
        object.__setattr__(self, "phase", GamePhase(self.phase))
        arr = np.array(self.projectiles, dtype=np.float32, copy=True)
        if arr.shape != (MAX_PROJECTILES, 5):
            raise ValueError(f"projectiles must have shape ({MAX_PROJECTILES}, 5), got {arr.shape}")
        arr.setflags(write=False)
        object.__setattr__(self, "projectiles", arr)
        object.__setattr__(self, "counters", dict(self.counters))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, GameState):
            return NotImplemented
        return all(np.array_equal(getattr(self, f.name), getattr(other, f.name)) if f.name == "projectiles"
                   else getattr(self, f.name) == getattr(other, f.name) for f in fields(self))

    __hash__ = None  # type: ignore[assignment]


def pack_projectiles(items: list[tuple[str, float, float, float, float]]) -> tuple[NDArray[np.float32], int]:
    """Projectile table for ``GameState`` from ``(kind, x, y, radius, width)`` tuples (first 16 kept)."""
    arr = np.zeros((MAX_PROJECTILES, 5), dtype=np.float32)
    rows = items[:MAX_PROJECTILES]
    for i, (kind, x, y, r, w) in enumerate(rows):
        arr[i] = (PROJECTILE_KINDS.index(kind), x, y, r, w)
    return arr, len(rows)


def unpack_projectiles(state: GameState) -> list[tuple[str, float, float, float, float]]:
    """The ``(kind, x, y, radius, width)`` tuples of a state's projectile table."""
    out = []
    for row in state.projectiles[: state.n_projectiles]:
        code = int(row[0])
        kind = PROJECTILE_KINDS[code] if 0 <= code < len(PROJECTILE_KINDS) else ""
        out.append((kind, float(row[1]), float(row[2]), float(row[3]), float(row[4])))
    return out


# --- wire format (protocol.wire.codec's conventions and field checks) -----------------------------------
_ID = codec.str_check(pattern=codec.TRACKER_ID_PATTERN)
_OPT = codec.str_check(min_len=0)
_TIME = codec.float_check(0.0)
_NUM = codec.float_check()


def _projectiles(v: Any, where: str) -> NDArray[np.float32]:
    arr: NDArray[np.float32] = codec.array_check((MAX_PROJECTILES, 5))(v, where)
    if np.any((arr[:, 0] < 0) | (arr[:, 0] >= len(PROJECTILE_KINDS)) | (arr[:, 0] != np.round(arr[:, 0]))):
        codec.fail(where, f"column 0 must be a projectile kind code 0..{len(PROJECTILE_KINDS) - 1}", v)
    return arr


#: Wire name -> (dataclass, {field: check}), in :mod:`protocol.wire.codec`'s registry format.
GAME_ROWS: Final[dict[str, tuple[type[Any], dict[str, Any]]]] = {
    "game_event": (GameEvent, {
        "schema_version": codec.schema_version_check, "game_id": _ID, "seq": codec.int_check(0), "t": _TIME,
        "stream_ts": _TIME, "kind": codec.enum_check(GameEventKind), "actor": _OPT, "detail": _OPT, "value": _NUM,
        "gesture": _OPT, "direction": _OPT, "start_s": _NUM, "end_s": _NUM,
        "confidence": codec.float_check(0.0, 1.0), "latency_ms": _NUM,
    }),
    "game_state": (GameState, {
        "schema_version": codec.schema_version_check, "game_id": _ID, "seq": codec.int_check(0), "t": _TIME,
        "stream_ts": _TIME, "tick": codec.int_check(0), "phase": codec.enum_check(GamePhase), "round_left_s": _TIME,
        "player_health": _TIME, "opponent_health": _TIME, "player_x": _NUM, "player_lane": codec.int_check(0, 64),
        "player_stance": codec.str_check(), "opponent_x": _NUM, "telegraph": _OPT, "projectiles": _projectiles,
        "n_projectiles": codec.int_check(0, MAX_PROJECTILES), "winner": _OPT, "end_reason": _OPT,
        "frames": codec.int_check(0), "counters": codec.map_check(codec.int_check(0)),
    }),
}
for _name, (_cls, _checks) in GAME_ROWS.items():
    codec.register_message(_name, _cls, _checks)


def encode_game(msg: GameEvent | GameState) -> bytes:
    """Serialise a game message (:func:`protocol.wire.codec.encode`, which knows the game types).

    Raises
    ------
    ProtocolError
        If a field breaks a rule :func:`decode_game` enforces.
    TypeError
        If ``msg`` is not a game message.
    """
    if not isinstance(msg, GameEvent | GameState):
        raise TypeError(f"{type(msg).__name__} is not a game message type")
    return codec.encode(msg)


@overload
def decode_game(data: bytes | bytearray | memoryview, expected: type[T]) -> T: ...
@overload
def decode_game(data: bytes | bytearray | memoryview, expected: None = None) -> GameEvent | GameState: ...
def decode_game(data: bytes | bytearray | memoryview, expected: type[Any] | None = None) -> Any:
    """Parse and validate a game message; raises only :class:`ProtocolError` for bad input.

    Parameters
    ----------
    data : bytes-like
    expected : type, optional
        ``GameEvent`` or ``GameState``; another type in the bytes is an error.
    """
    if expected is not None and expected not in (GameEvent, GameState):
        raise TypeError(f"{getattr(expected, '__name__', expected)!r} is not a game message type")
    msg = codec.decode(data, expected)
    if not isinstance(msg, GameEvent | GameState):
        raise ProtocolError(f"expected a game message ({', '.join(GAME_ROWS)}), got {codec.message_type_name(msg)}")
    return msg
