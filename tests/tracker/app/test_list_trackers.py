"""``mocap-tracker list``: the trackers alive on the network, two at once, each with its status."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.net.session import free_tcp_endpoint

REPO = Path(__file__).resolve().parents[3]


@pytest.mark.zenoh
def test_list_shows_every_tracker_alive() -> None:
    ep = free_tcp_endpoint()
    mk = [sys.executable, "-m", "tracker_service", "replay", "--synthetic-wave", "--loop", "-q"]
    first = subprocess.Popen([*mk, "--id", "alpha", "--listen", ep], cwd=REPO)
    second = subprocess.Popen([*mk, "--id", "beta", "--connect", ep], cwd=REPO)
    try:
        rows: dict[str, dict[str, object]] = {}
        for _ in range(6):  # the replays take a few seconds to start
            out = subprocess.run([sys.executable, "-m", "tracker_service", "list", "--connect", ep, "--wait", "2.5",
                                  "--json"], capture_output=True, text=True, timeout=60, cwd=REPO)
            assert out.returncode == 0, out.stderr
            rows = {r["id"]: r for r in map(json.loads, out.stdout.splitlines())}
            if set(rows) == {"alpha", "beta"} and all(r["fps"] for r in rows.values()):
                break
        assert set(rows) == {"alpha", "beta"}, out.stdout
        assert all(isinstance(r["fps"], float) and r["fps"] > 0 for r in rows.values()), rows
    finally:
        for p in (first, second):
            p.terminate()
            p.wait(timeout=10)
