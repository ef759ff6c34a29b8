"""End to end on a short synthetic clip (fixture database): ``eval --video`` and ``run --video`` write
the overlay of every frame as H.264; ``eval`` without ``--json`` prints the summary, progress goes to
stderr; ``record`` subscribed to ``run`` writes the session and stops cleanly on SIGINT."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from protocol.formats.video import video_info
from protocol.net.session import free_tcp_endpoint
from tracker_service.app.record import read_recording_bvh

REPO = Path(__file__).resolve().parents[3]
SCRIPT = REPO / "protocol" / "scripts" / "crouch.toml"
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}


def test_eval_video_summary_and_progress(small_db, weak_appearance_net, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    video = tmp_path / "eval.mp4"
    base = [sys.executable, "-m", "tracker_service", "eval", "--script", str(SCRIPT), "--db", str(small_db[4]),
            "--body", "mMA", "--frames", "20", "--appearance", str(weak_appearance_net), "--smooth-cutoff", "4"]
    r = subprocess.run([*base, "--video", str(video)], cwd=REPO, capture_output=True, text=True, timeout=240, env=ENV)
    assert r.returncode == 0, r.stderr
    assert "MPJPE" in r.stdout and "within 10 cm" in r.stdout and not r.stdout.lstrip().startswith("{")
    assert "20/32 frames" in r.stderr or "32/32 frames" in r.stderr
    assert "OpenGL_accelerate" not in r.stderr
    info = video_info(video)
    assert (info.codec, info.pix_fmt, info.frames) == ("h264", "yuv420p", 32)  # 12 empty-room frames + 20
    j = subprocess.run([*base, "--json"], cwd=REPO, capture_output=True, text=True, timeout=240, env=ENV)
    assert j.returncode == 0, j.stderr
    assert isinstance(json.loads(j.stdout), dict) and "frames" in j.stderr  # only JSON on stdout


@pytest.mark.zenoh
def test_run_video_and_record_until_sigint(small_db, weak_appearance_net, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    ep = free_tcp_endpoint()
    video, bvh, jsonl = tmp_path / "run.mp4", tmp_path / "run.bvh", tmp_path / "run.jsonl"
    tracker = subprocess.Popen(
        [sys.executable, "-m", "tracker_service", "run", "--source", f"synthetic:{SCRIPT}", "--db", str(small_db[4]),
         "--body", "mMA", "--id", "vid", "--frames", "45", "--listen", ep, "--wait-for-subscriber", "30",
         "--as-fast-as-possible", "--appearance", str(weak_appearance_net), "--video", str(video), "-q"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    recorder = subprocess.Popen(
        [sys.executable, "-m", "tracker_service", "record", "--id", "vid", "--connect", ep, "--bvh", str(bvh),
         "--jsonl", str(jsonl)], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    try:
        _, t_err = tracker.communicate(timeout=240)
        assert tracker.returncode == 0, t_err
        recorder.send_signal(signal.SIGINT)
        r_out, r_err = recorder.communicate(timeout=30)
    finally:
        for p in (tracker, recorder):
            if p.poll() is None:
                p.kill()
    assert recorder.returncode == 0, r_err
    info = video_info(video)
    assert (info.codec, info.frames, info.width, info.height) == ("h264", 45, 320, 240)
    lines = [json.loads(x) for x in jsonl.read_text().splitlines()]
    assert len(lines) >= 10 and f"recorded {len(lines)} poses" in r_out
    published = np.array([x["joints"] for x in lines])
    assert np.abs(read_recording_bvh(bvh) - published).max() < 1e-4  # the tracked body's skeleton
