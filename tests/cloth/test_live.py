"""Live over Zenoh on loopback: ``mocap-tracker replay`` process -> ``mocap-cloth run`` process.

The cloth client renders PNG frames and publishes its mesh; a subscriber in the test receives the
mesh messages; malformed payloads on the pose key are counted, never fatal; SIGTERM stops the
client cleanly within 2 s.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest

from protocol.net.session import build_config, free_tcp_endpoint, open_session
from protocol.wire.keys import cloth_mesh_key, pose_key

pytestmark = pytest.mark.zenoh
REPO = Path(__file__).resolve().parents[2]
CROUCH = REPO / "protocol" / "scripts" / "crouch.toml"

if importlib.util.find_spec("tracker_service.app.replay_daemon") is None:  # pragma: no cover
    pytest.skip("the replay publisher (tracker_service replay) is not available", allow_module_level=True)


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    return env


def _spawn(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", *args], cwd=REPO, env=_env(), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def _stop(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.wait(timeout=5)


def test_replay_to_cloth_client_produces_frames_and_meshes(tmp_path: Path) -> None:
    ep_replay, ep_cloth = free_tcp_endpoint(), free_tcp_endpoint()
    frames_dir = tmp_path / "frames"
    cloth = _spawn("cloth_client", "run", "--id", "live", "--garment", "cape", "--particles", "400",
                   "--frames-out", str(frames_dir), "--size", "96x96", "--publish-mesh", "--max-frames", "120",
                   "--duration", "40", "--connect", ep_replay, "--listen", ep_cloth, "--json")
    replay = _spawn("tracker_service", "replay", "--script", str(CROUCH), "--id", "live", "--listen", ep_replay,
                    "--loop", "--duration", "40", "--wait-for-subscriber", "20")
    meshes: list[dict] = []
    try:
        with open_session(build_config("subscriber", connect=[ep_cloth, ep_replay])) as session:
            sub = session.declare_subscriber(cloth_mesh_key("live"))
            bad = session.declare_publisher(pose_key("live"))
            deadline = time.monotonic() + 60
            while cloth.poll() is None and time.monotonic() < deadline:
                bad.put(b"\x93not a pose frame")  # malformed traffic on the pose key
                while (s := sub.try_recv()) is not None:
                    meshes.append(msgpack.unpackb(bytes(s.payload.to_bytes()), raw=False))
                time.sleep(0.05)
            sub.undeclare()
            bad.undeclare()
        out, err = cloth.communicate(timeout=10)
    finally:
        _stop(cloth)
        _stop(replay)
    assert cloth.returncode == 0, err[-2000:]
    result = json.loads(out.strip().splitlines()[-1])
    # (the first look brings the poses sent while the cape was built, up to MAX_BACKLOG_S of them)
    assert result["frames"] == 120 and result["reason"] == "max_frames", result
    assert result["malformed"] > 0
    assert result["body_updates"] >= 1 and result["max_strain"] < 0.10
    pngs = sorted(frames_dir.glob("frame_*.png"))  # the newest pose of each batch is drawn
    assert len(pngs) >= 10 and pngs[0].stat().st_size > 500
    assert len(meshes) >= 10
    first = meshes[0]
    assert first["type"] == "cloth_mesh" and first["garment"] == "cape" and "triangles" in first
    verts = np.frombuffer(first["vertices"], dtype="<f4").reshape(-1, 3)
    tris = np.frombuffer(first["triangles"], dtype="<u4").reshape(-1, 3)
    assert len(verts) == first["n_vertices"] and tris.max() < len(verts) and np.all(np.isfinite(verts))
    assert 0.2 < verts[:, 1].max() < 2.0


def test_cloth_client_stops_on_sigterm_without_a_tracker(tmp_path: Path) -> None:
    ep = free_tcp_endpoint()
    cloth = _spawn("cloth_client", "run", "--id", "nobody", "--connect", ep, "--json")
    try:
        time.sleep(3.0)  # it keeps asking for a body that never comes
        assert cloth.poll() is None
        t0 = time.monotonic()
        cloth.send_signal(signal.SIGTERM)
        out, _ = cloth.communicate(timeout=10)
        assert time.monotonic() - t0 < 2.0
    finally:
        _stop(cloth)
    assert cloth.returncode == 0
    result = json.loads(out.strip().splitlines()[-1])
    assert result["frames"] == 0 and result["reason"] == "signal"
