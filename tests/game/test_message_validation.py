"""The live game client's message handling against hostile or odd input, in-process (no Zenoh):
``GameClient`` is fed encoded payloads directly, with a synthetic local clock.

Cases measured on loopback before the fix: two frames with seq = 2^63 - 1 stopped GameState
publishing for good (the dropped-frame counter left the codec's range); out-of-order, far-future
and 1e30-valued frames suppressed every real gesture while they lasted; a tracker restart was
followed only after ~4.5 s; body-message warnings were not rate-limited.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
import pytest

from game_client.app import AppOptions, GameClient
from game_client.game import GameConfig
from game_client.variants import variant_motion
from protocol.kinematics import fk
from protocol.wire.codec import encode
from protocol.wire.game_messages import GameEvent, GameEventKind, GameState, decode_game
from protocol.wire.messages import BodyInfo, PoseFrame, body_info_from_body
from protocol.wire.validate import COUNT_MAX

FPS = 30.0


class _Out:
    def __init__(self) -> None:
        self.events: list[GameEvent] = []
        self.states: list[GameState] = []

    def event(self, data: bytes) -> None:
        self.events.append(decode_game(data, GameEvent))

    def state(self, data: bytes) -> None:
        self.states.append(decode_game(data, GameState))

    def gestures(self) -> list[str]:
        return [e.gesture for e in self.events if e.kind == GameEventKind.GESTURE]


def _client() -> tuple[GameClient, _Out]:
    out = _Out()
    return GameClient("g", AppOptions(), GameConfig(), out.event, out.state), out


def _frames(name: str, seq0: int = 0, t0: float = 0.0) -> list[PoseFrame]:
    m = variant_motion(name)
    joints = fk(m.poses, m.body)
    return [PoseFrame("t", seq0 + k, t0 + k / FPS, 0.0, 0.0, m.poses[k], joints[k], np.ones(15), 1.0, "replay",
                      m.body.name)
            for k in range(len(m.poses))]


def _play(client: GameClient, frames: list[PoseFrame], now0: float) -> float:
    now = now0
    for k, f in enumerate(frames):
        now = now0 + k / FPS
        client.on_pose(encode(f), now)
    return now


def test_max_seq_frames_do_not_stop_state_publishing() -> None:
    client, out = _client()
    frames = _frames("transform")
    half = len(frames) // 2
    now = _play(client, frames[:half], 0.0)
    for k in range(2):
        bad = dataclasses.replace(frames[half], seq=2**63 - 1)
        client.on_pose(encode(bad), now + (k + 1) * 0.01)
    n_states = len(out.states)
    _play(client, frames[half:], now + 0.05)
    assert len(out.states) > n_states + 3  # still publishing after them
    assert client.c["publish_errors"] == 0
    assert client.c["invalid_seq_jump"] == 2
    assert all(0 <= v <= COUNT_MAX for s in out.states for v in s.counters.values())
    assert client.c["dropped_frames"] == 0
    assert out.gestures() == ["transform"]


@pytest.mark.parametrize("kind", ["out_of_order", "future", "huge"])
def test_hostile_frames_do_not_suppress_real_gestures(kind: str) -> None:
    clean, out_clean = _client()
    _play(clean, _frames("fire_ring"), 0.0)
    client, out = _client()
    frames = _frames("fire_ring")
    for k, f in enumerate(frames):
        now = k / FPS
        client.on_pose(encode(f), now)
        if k % 3 == 1:  # one hostile frame after every third real one
            if kind == "out_of_order":
                bad = frames[max(k - 5, 0)]
            elif kind == "future":
                bad = dataclasses.replace(f, seq=f.seq + 1, capture_ts=f.capture_ts + 1e6)
            else:
                bad = dataclasses.replace(f, seq=f.seq + 1, joints=np.full((24, 3), 1e30, dtype=np.float32))
            client.on_pose(encode(bad), now + 0.001)
    assert out_clean.gestures() == ["fire_ring"]
    assert out.gestures() == out_clean.gestures()
    assert client.c["invalid_pose"] >= len(frames) // 3 - 1
    assert client.c["tracker_restarts"] == 0


def test_tracker_restart_followed_within_two_seconds() -> None:
    client, out = _client()
    assert client.want_body  # the app asks the tracker's queryable at the start
    client.want_body = False
    now = _play(client, _frames("transform"), 0.0)  # a few seconds of stream; then the tracker restarts
    assert not client.want_body
    restart_now = now + 0.5
    second = _frames("fire_ring")  # seq and time from 0 again
    fresh, out_fresh = _client()
    _play(fresh, second, 0.0)
    frames_before = client.result.frames
    accepted_at = None
    for k, f in enumerate(second):
        client.on_pose(encode(f), restart_now + k / FPS)
        if accepted_at is None and client.result.frames > frames_before:
            accepted_at = k / FPS
    assert accepted_at is not None and accepted_at <= 2.0
    assert client.c["tracker_restarts"] == 1
    assert client.want_body  # ... and again for the new stream
    assert out.gestures() == ["transform", "fire_ring"]
    # recognised on the same stream frame as on a fresh client (no extra delay)
    assert [e.stream_ts for e in out.events if e.kind == GameEventKind.GESTURE][-1] == pytest.approx(
        [e.stream_ts for e in out_fresh.events if e.kind == GameEventKind.GESTURE][-1])
    assert [s.seq for s in out.states] == list(range(len(out.states)))


def test_bad_body_is_dropped_and_its_warnings_rate_limited(caplog: pytest.LogCaptureFixture) -> None:
    client, _ = _client()
    m = variant_motion("transform")
    good = body_info_from_body(m.body, "t")
    client.on_body(encode(good))
    height = client.height
    assert height is not None and 1.0 < height < 2.3
    giant = dataclasses.replace(good, offsets=good.offsets * 100, capsule_radii=good.capsule_radii * 100,
                                measurements={**good.measurements, "height_m": 100 * height})
    tiny = dataclasses.replace(good, offsets=good.offsets / 1000, capsule_radii=good.capsule_radii / 1000,
                               measurements={**good.measurements, "height_m": height / 1000})
    t = [0.0]
    client.warn.clock = lambda: t[0]
    with caplog.at_level(logging.WARNING, logger="game_client.app"):
        for k in range(1845):  # the tester's 60 s burst
            t[0] = k * 60.0 / 1845
            client.on_body(encode(giant if k % 2 else tiny))
    assert client.height == height
    assert client.c["invalid_body"] == 1845
    assert len(caplog.records) <= 60 / 5 + 2
    assert math.isfinite(client.rnd.recognizer.features.height or 1.0)


def test_body_with_max_values_is_never_fatal() -> None:
    client, out = _client()
    m = variant_motion("transform")
    info = body_info_from_body(m.body, "t")
    off = np.full_like(info.offsets, 1e20)
    client.on_body(encode(BodyInfo("t", "x", {"height_m": 1e20}, off, info.capsule_radii)))
    assert client.c["invalid_body"] == 1 and client.height is None
    _play(client, _frames("transform"), 0.0)
    assert out.gestures() == ["transform"]


def test_every_cli_answers_version() -> None:
    import subprocess
    import sys

    clis = (("game_client", "mocap-game"), ("cloth_client", "mocap-cloth"), ("tracker_service", "mocap-tracker"))
    for module, prog in clis:
        out = subprocess.run([sys.executable, "-m", module, "--version"], capture_output=True, text=True, timeout=60)
        assert out.returncode == 0 and out.stdout.startswith(f"{prog} "), (module, out.stdout, out.stderr)
