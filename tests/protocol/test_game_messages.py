"""GameEvent / GameState: construction, wire round trip, strict decoding and fuzzing.

:mod:`protocol.wire.codec` has no public registration function yet (see :mod:`protocol.wire.game_messages`),
so the game messages use :func:`encode_game` / :func:`decode_game`, built on the codec's checks.
"""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from protocol.wire.codec import ProtocolError, decode, encode
from protocol.wire.game_messages import (
    GAME_ROWS,
    MAX_PROJECTILES,
    GameEvent,
    GameEventKind,
    GamePhase,
    GameState,
    decode_game,
    encode_game,
    pack_projectiles,
    unpack_projectiles,
)
from protocol.wire.messages import SCHEMA_VERSION

FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
MSGPACK_INT = st.integers(-(2**63), 2**64 - 1)  # what msgpack can carry


def event(**kw: object) -> GameEvent:
    base: dict[str, object] = dict(game_id="arena-1", seq=7, t=12.5, stream_ts=1_000.25, kind="gesture", actor="player",
                                   gesture="side_step", direction="left", start_s=11.2, end_s=12.4, confidence=0.93,
                                   latency_ms=66.7)
    base.update(kw)
    return GameEvent(**base)  # type: ignore[arg-type]


def state(**kw: object) -> GameState:
    arr, n = pack_projectiles([("high", 4.0, 5.5, 0.15, 8.0), ("fire_ring", 3.9, 3.0, 0.55, 0.0)])
    base: dict[str, object] = dict(game_id="arena-1", seq=3, t=12.5, stream_ts=1_000.25, tick=1500, phase="fighting",
                                   round_left_s=47.5, player_health=75.0, opponent_health=40.0, player_x=2.5,
                                   player_lane=0, player_stance="crouching", opponent_x=4.6, telegraph="side",
                                   projectiles=arr, n_projectiles=n, frames=375,
                                   counters={"decode_errors": 2, "tracker_restarts": 1})
    base.update(kw)
    return GameState(**base)  # type: ignore[arg-type]


def test_round_trip_is_exact() -> None:
    for msg in (event(), event(kind="hit", gesture="", direction="", value=60.0), state(), state(phase="over",
                winner="player", end_reason="knockout", n_projectiles=0, projectiles=np.zeros((16, 5)))):
        data = encode_game(msg)
        back = decode_game(data)
        assert back == msg and type(back) is type(msg)
        assert encode_game(back) == data
    assert decode_game(encode_game(state()), GameState).phase is GamePhase.FIGHTING


def test_wire_form_follows_the_codec_conventions() -> None:
    raw = msgpack.unpackb(encode_game(state()), raw=False)
    assert raw["type"] == "game_state" and raw["schema_version"] == SCHEMA_VERSION
    assert set(raw) == {"type", *GAME_ROWS["game_state"][1]}
    assert raw["phase"] == "fighting" and len(raw["projectiles"]) == MAX_PROJECTILES
    assert msgpack.unpackb(encode_game(event()), raw=False)["kind"] == "gesture"


def test_projectile_table_packs_and_unpacks() -> None:
    items = [("side", 1.0, 2.0, 0.35, 0.0)] * 20
    arr, n = pack_projectiles(items)
    assert n == MAX_PROJECTILES and arr.shape == (MAX_PROJECTILES, 5) and arr.dtype == np.float32
    assert unpack_projectiles(state(projectiles=arr, n_projectiles=n))[0][0] == "side"
    with pytest.raises(ValueError, match="shape"):
        state(projectiles=np.zeros((3, 5)))


@pytest.mark.parametrize(("make", "key", "value", "why"), [
    (event, "game_id", "bad/id", "match"),
    (event, "seq", -1, "range"),
    (event, "t", math.nan, "finite"),
    (event, "confidence", 1.5, "range"),
    (state, "player_health", -1.0, "range"),
    (state, "player_stance", "", "length"),
    (state, "n_projectiles", 17, "range"),
    (state, "counters", {"x": -1}, "range"),
])
def test_encode_refuses_what_decode_would(make: object, key: str, value: object, why: str) -> None:
    with pytest.raises(ProtocolError, match=why):
        encode_game(make(**{key: value}))  # type: ignore[operator]


def _raw(msg: GameEvent | GameState) -> dict[str, object]:
    out: dict[str, object] = msgpack.unpackb(encode_game(msg), raw=False)
    return out


@pytest.mark.parametrize(("mutate", "why"), [
    (lambda d: d.update(extra=1), "unknown key"),
    (lambda d: d.pop("seq"), "missing key"),
    (lambda d: d.update(schema_version=SCHEMA_VERSION + 1), "schema_version"),
    (lambda d: d.update(type="pose_frame"), "pose_frame"),
    (lambda d: d.update(kind="teleport"), "expected one of"),
    (lambda d: d.update(stream_ts=-5.0), "range"),
])
def test_decode_rejects_bad_event_maps(mutate: object, why: str) -> None:
    d = _raw(event())
    mutate(d)  # type: ignore[operator]
    with pytest.raises(ProtocolError, match=why):
        decode_game(msgpack.packb(d))


def test_decode_rejects_bad_projectile_codes_and_wrong_types() -> None:
    d = _raw(state())
    d["projectiles"][0][0] = 9.0  # type: ignore[index]
    with pytest.raises(ProtocolError, match="kind code"):
        decode_game(msgpack.packb(d, use_single_float=True))
    with pytest.raises(ProtocolError, match="expected a game_event"):
        decode_game(encode_game(state()), GameEvent)
    with pytest.raises(TypeError):
        decode_game(encode_game(state()), dict)
    with pytest.raises(TypeError):
        encode_game("not a message")  # type: ignore[arg-type]
    with pytest.raises(ProtocolError):
        decode_game("text")  # type: ignore[call-overload]


def test_game_types_are_registered_with_the_shared_codec() -> None:
    assert decode(encode_game(event())) == event()  # protocol.wire.codec knows the game messages
    assert decode_game(encode(event()), GameEvent) == event()
    from protocol.wire.messages import TrackerState, TrackerStatus

    status = TrackerStatus(tracker_id="t", state=TrackerState.TRACKING, ts=1.0, uptime_s=1.0, fps=30.0, frames=3)
    with pytest.raises(ProtocolError):
        decode_game(encode(status))


@FUZZ
@given(st.binary(max_size=2048))
def test_fuzz_random_bytes_only_raise_protocol_error(data: bytes) -> None:
    try:
        decode_game(data)
    except ProtocolError:
        pass


@FUZZ
@given(st.sampled_from(["event", "state"]), st.data())
def test_fuzz_mutated_messages_decode_or_raise_protocol_error(which: str, data: st.DataObject) -> None:
    raw = bytearray(encode_game(event() if which == "event" else state()))
    for _ in range(data.draw(st.integers(1, 8))):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] = data.draw(st.integers(0, 255))
    try:
        msg = decode_game(bytes(raw))
    except ProtocolError:
        return
    assert encode_game(msg)  # whatever decodes is a valid message that encodes again


@FUZZ
@given(st.dictionaries(st.sampled_from([*sorted(GAME_ROWS["game_event"][1]), "type", "junk"]),
                       st.one_of(st.none(), st.booleans(), MSGPACK_INT, st.floats(allow_nan=True),
                                 st.text(max_size=300), st.lists(MSGPACK_INT, max_size=3)), max_size=20))
def test_fuzz_arbitrary_maps(d: dict) -> None:
    try:
        decode_game(msgpack.packb(d))
    except ProtocolError:
        pass


@FUZZ
@given(seq=st.integers(0, 2**62), t=st.floats(0, 1e7), conf=st.floats(0, 1),
       kind=st.sampled_from(list(GameEventKind)), text=st.text(max_size=40))
def test_fuzz_valid_events_round_trip(seq: int, t: float, conf: float, kind: GameEventKind, text: str) -> None:
    msg = event(seq=seq, t=t, confidence=conf, kind=kind, detail=text)
    assert decode_game(encode_game(msg)) == msg
