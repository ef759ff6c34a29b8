"""Live over Zenoh: replay process -> game client process, on loopback ports only.

Two scenarios run side by side to keep the wall time down:

* a whole scripted round (``round_win.toml``) replayed by ``mocap-tracker replay``: the game client
  recognises the five gestures in order, publishes them as ``GameEvent``s, and its log ends with
  the player winning by knockout;
* a robustness run: a replay, then malformed payloads on the pose key, then a second replay (a
  tracker restart: ``seq`` starts again at 0), then SIGTERM: the client counts the bad messages and
  the restart, keeps playing, and exits cleanly within 2 s.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import pytest

from game_client.variants import SCRIPTS_DIR
from protocol.net.session import build_config, free_tcp_endpoint, open_session
from protocol.wire.codec import encode
from protocol.wire.game_messages import GameEvent, GameEventKind, decode_game
from protocol.wire.keys import game_event_key, pose_key
from protocol.wire.messages import TrackerState, TrackerStatus

pytestmark = pytest.mark.zenoh
REPO = Path(__file__).resolve().parents[2]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    return env


def _spawn(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", *args], cwd=REPO, env=_env(), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _replay(script: str, tid: str, ep: str) -> subprocess.Popen[str]:
    return _spawn("tracker_service", "replay", "--script", str(SCRIPTS_DIR / script), "--id", tid, "--listen", ep,
                  "--wait-for-subscriber", "15", "-q")


def _records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def test_live_round_and_robustness(tmp_path: Path) -> None:
    ep_a, ep_b, ep_t = free_tcp_endpoint(), free_tcp_endpoint(), free_tcp_endpoint()
    log_a, log_b = tmp_path / "a.jsonl", tmp_path / "b.jsonl"
    procs: list[subprocess.Popen[str]] = []
    try:
        client_a = _spawn("game_client", "run", "--id", "ga", "--tracker", "ta", "--connect", ep_a, "--log",
                          str(log_a), "--exit-when-over", "--duration", "45", "--json", "-q")
        client_b = _spawn("game_client", "run", "--id", "gb", "--tracker", "tb", "--connect", ep_b, "--connect",
                          ep_t, "--log", str(log_b), "--duration", "45", "-q")
        procs += [client_a, client_b]
        with open_session(build_config("publisher", listen=[ep_t])) as session:
            events_sub = session.declare_subscriber(game_event_key("gb"))
            try:
                replay_a = _replay("round_win.toml", "ta", ep_a)
                replay_b1 = _replay("transform.toml", "tb", ep_b)
                procs += [replay_a, replay_b1]
                assert replay_b1.wait(timeout=30) == 0, replay_b1.stderr.read() if replay_b1.stderr else ""
                # malformed payloads on the pose key: garbage, truncated msgpack, a valid message of the wrong type
                garbage = [b"", b"\xc1", b"\x92\x01", msgpack.packb({"type": "pose_frame", "seq": -1}), b"x" * 300,
                           encode(TrackerStatus("tb", TrackerState.TRACKING, 1.0, 1.0, 30.0, 1))]
                pub = session.declare_publisher(pose_key("tb"))
                for payload in garbage:
                    pub.put(payload)
                time.sleep(0.5)
                replay_b2 = _replay("fire_ring.toml", "tb", ep_b)  # a restarted tracker: seq from 0 again
                procs.append(replay_b2)
                assert replay_b2.wait(timeout=30) == 0
                time.sleep(0.5)
                t0 = time.monotonic()
                client_b.send_signal(signal.SIGTERM)
                assert client_b.wait(timeout=5) == 0
                assert time.monotonic() - t0 < 2.0
                received = []
                while (s := events_sub.try_recv()) is not None:
                    received.append(decode_game(s.payload.to_bytes(), GameEvent))
                pub.undeclare()
            finally:
                events_sub.undeclare()
        assert client_a.wait(timeout=40) == 0
        assert replay_a.wait(timeout=10) == 0
        out_a = json.loads(client_a.stdout.read() if client_a.stdout else "{}")
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(timeout=5)

    # the whole round: right gestures, in order, no extras; the player wins by knockout
    rec_a = _records(log_a)
    assert [r["gesture"] for r in rec_a if r["type"] == "gesture"] == [
        "transform", "crouch", "strike", "side_step", "fire_ring"]
    assert rec_a[-1]["type"] == "summary" and (rec_a[-1]["winner"], rec_a[-1]["reason"]) == ("player", "knockout")
    assert out_a["reason"] == "over" and out_a["counters"]["decode_errors"] == 0

    # robustness: bad payloads counted, restart counted, the round went on, events published
    rec_b = _records(log_b)
    assert [r["gesture"] for r in rec_b if r["type"] == "gesture"] == ["transform", "fire_ring"]
    assert any(r["type"] == "game" and r["kind"] == "shot" and r["detail"] == "fire_ring" for r in rec_b)
    summary = rec_b[-1]
    assert summary["type"] == "summary"
    assert summary["counters"]["decode_errors"] == len(garbage)
    assert summary["counters"]["tracker_restarts"] == 1
    kinds = [(e.kind, e.gesture) for e in received if e.kind == GameEventKind.GESTURE]
    assert kinds == [(GameEventKind.GESTURE, "transform"), (GameEventKind.GESTURE, "fire_ring")]
    assert [e.seq for e in received] == list(range(len(received)))
