"""The recogniser on every shared recording: the Bandai fire-ring takes are fire rings, the
non-gesture motions give no false gestures."""

from __future__ import annotations

import numpy as np
import pytest

from game_client.evaluation import allowed_gestures, expected_gestures, recording
from game_client.gestures import recognize
from protocol.formats.mocap_data import IndexEntry


@pytest.fixture(scope="module")
def results(mocap_index: list[IndexEntry]) -> dict[str, tuple[IndexEntry, list]]:
    out = {}
    for entry in mocap_index:
        t, j, _h = recording(entry.path)
        out[entry.path] = (entry, recognize(t, j))
    return out


def test_fire_ring_takes_are_recognised(results: dict) -> None:
    takes = [(e, ev) for e, ev in results.values() if "firering_like" in e.tags]
    assert len(takes) == 14
    for entry, events in takes:
        assert [x.gesture.value for x in events] == list(expected_gestures(entry.tags)), entry.path


def test_no_false_gestures_on_other_motion(results: dict) -> None:
    false = {}
    for path, (entry, events) in results.items():
        extra = [e for e in events if e.gesture.value not in allowed_gestures(entry.tags)]
        if extra:
            false[path] = [(e.gesture.value, round(e.t, 2)) for e in extra]
    assert false == {}


def test_strike_like_takes_yield_only_strikes(results: dict) -> None:
    takes = [(e, ev) for e, ev in results.values() if "strike_like" in e.tags]
    assert takes
    found = sum(1 for _, ev in takes if ev)
    assert all(x.gesture.value == "strike" for _, ev in takes for x in ev)
    assert found >= len(takes) // 2  # most fast right-arm drops are strikes (see docs/GAME.md)


def test_fire_ring_takes_survive_rate_noise_and_turning(mocap_index: list[IndexEntry]) -> None:
    rng = np.random.default_rng(5)
    takes = [e for e in mocap_index if "firering_like" in e.tags][::3]
    for entry, hz in zip(takes, (15.0, 60.0, 120.0, 30.0, 45.0), strict=False):
        t, j, _ = recording(entry.path, fps=hz)
        yaw = rng.uniform(-np.pi, np.pi)
        c, s = np.cos(yaw), np.sin(yaw)
        rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        j = (j @ rot.T) * 1.1 + rng.normal(0.0, 0.008, j.shape)
        assert [x.gesture.value for x in recognize(t, j)] == ["fire_ring"], (entry.path, hz)
