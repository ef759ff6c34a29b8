"""``mocap-tracker demo``: its options, the mosaic's pieces (ground truth, gesture score, skeleton
view, client frames, the video) and, marked slow, short whole-system runs over loopback Zenoh."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from protocol.formats.video import VideoWriter, video_info
from protocol.net.session import free_tcp_endpoint
from tracker_service.app.cli import build_parser
from tracker_service.app.commands.demo import DEFAULT_ROUND, SystemDemoOptions
from tracker_service.app.demo_mosaic import (
    TILE,
    ClientFrames,
    GestureSeen,
    MosaicInputs,
    PoseSeen,
    ground_truth,
    match_gestures,
    mpjpe_cm,
    percentile,
    performed_gestures,
    skeleton_view,
    write_mosaic,
)
from tracker_service.app.options import DemoOptions
from tracker_service.paths import REPO_ROOT

KEYS = {"gestures_performed", "gestures_recognised", "round", "latency_ms", "fps", "cloth_realtime_factor",
        "mpjpe_cm", "video"}


def _parse(argv: list[str]) -> DemoOptions:
    from tracker_service.app.commands import demo

    args = build_parser().parse_args(["demo", *argv])
    return demo.options_from_args(args)


def test_options() -> None:
    o = _parse([])
    assert isinstance(o, SystemDemoOptions) and not o.replay
    assert o.script == DEFAULT_ROUND and o.video and o.system_duration is None
    o = _parse(["--script", "s.toml", "--no-video", "--duration", "3", "--out", "x", "--json"])
    assert isinstance(o, SystemDemoOptions)
    assert (o.script, o.video, o.system_duration, o.out, o.json) == (Path("s.toml"), False, 3.0, Path("x"), True)
    assert _parse(["--replay"]) == DemoOptions(duration=6.0, replay=True)
    assert o.view_port is None
    assert _parse(["--view"]).view_port == 8080  # type: ignore[attr-defined]
    assert _parse(["--view", "9001"]).view_port == 9001  # type: ignore[attr-defined]


def test_performed_and_matched_gestures() -> None:
    labels = performed_gestures(DEFAULT_ROUND)
    assert labels is not None
    assert [g["gesture"] for g in labels] == ["transform", "crouch", "strike", "side_step", "fire_ring"]
    assert performed_gestures(Path("no_such_script.toml")) is None
    seen = [GestureSeen("transform", "", 2.1, 2.2, 0.5), GestureSeen("side_step", "left", 10.2, 10.3, 0.4),
            GestureSeen("strike", "", 7.9, 8.0, 0.4), GestureSeen("strike", "", 8.1, 8.2, 0.4)]
    hits = match_gestures(labels, seen, offset_s=0.5)
    assert hits == [True, False, True, False, False]  # a left side-step is not the right one; one strike counts once
    assert sum(hits) <= len(labels)


def test_ground_truth_and_mpjpe() -> None:
    fps, truth = ground_truth(REPO_ROOT / "game_client" / "scripts" / "strike.toml")
    assert fps == 30.0 and truth.shape[1:] == (24, 3) and np.isfinite(truth).all()
    assert 1.0 < truth[0, :, 1].max() < 2.1  # a standing person's head, metres above the floor

    def seen(k: int, joints: np.ndarray) -> PoseSeen:
        return PoseSeen(k, (k + 15) / fps, 0.0, 0.0, joints.astype(np.float32), 1.0)

    exact = [seen(k, truth[k]) for k in range(0, len(truth), 5)]
    assert mpjpe_cm(exact, fps, truth) == pytest.approx(0.0, abs=0.01)
    moved = [seen(k, truth[k] + 1.0) for k in range(3)]  # a translation: root-relative error 0
    assert mpjpe_cm(moved, fps, truth) == pytest.approx(0.0, abs=0.01)
    bent = truth[0].copy()
    bent[1:] += [0.1, 0.0, 0.0]
    assert mpjpe_cm([seen(0, bent)], fps, truth) == pytest.approx(100 * 0.1 * 23 / 24, abs=0.01)
    assert mpjpe_cm([], fps, truth) is None


def test_skeleton_view_and_percentile() -> None:
    _, truth = ground_truth(REPO_ROOT / "game_client" / "scripts" / "strike.toml")
    img = skeleton_view(truth[10], truth[12])
    assert img.shape == (TILE[1], TILE[0], 3) and img.dtype == np.uint8
    assert (img != 28).any(axis=2).sum() > 500  # bones were drawn
    assert skeleton_view(None).shape == img.shape
    assert percentile([], 50) is None and percentile([1.0, 2.0, 3.0], 50) == 2.0


def _png(folder: Path, k: int, colour: int, mtime: float) -> None:
    path = folder / f"frame_{k:05d}.png"
    cv2.imwrite(str(path), np.full((60, 80, 3), colour, np.uint8))
    os.utime(path, (mtime, mtime))


def test_client_frames_by_time(tmp_path: Path) -> None:
    for k, t in enumerate((100.0, 101.0, 102.0)):
        _png(tmp_path, k, 50 * (k + 1), t)
    frames = ClientFrames(tmp_path)
    assert len(frames) == 3
    assert frames.at(99.0) is None
    got = frames.at(101.5)
    assert got is not None and int(got[0, 0, 0]) == 100
    got = frames.at(1e9)
    assert got is not None and int(got[0, 0, 0]) == 150
    assert len(ClientFrames(tmp_path / "missing")) == 0 and len(ClientFrames(None)) == 0


def test_write_mosaic(tmp_path: Path) -> None:
    fps = 30.0
    overlay = tmp_path / "overlay.mp4"
    with VideoWriter(overlay, fps) as video:
        for i in range(20):
            video.write(np.full((240, 320, 3), 10 * i, np.uint8))
    _, truth = ground_truth(REPO_ROOT / "game_client" / "scripts" / "strike.toml")
    poses = [PoseSeen(i - 15, i / fps, 1000.0 + i / fps, 1000.01 + i / fps, truth[i - 15].astype(np.float32), 12.0)
             for i in range(15, 20)]
    (tmp_path / "game").mkdir()
    _png(tmp_path / "game", 0, 200, 1000.5)
    inputs = MosaicInputs(overlay=overlay, fps=fps, poses=poses, gestures=[GestureSeen("strike", "", 0.55, 0.6, 0.5)],
                          game=ClientFrames(tmp_path / "game"), cloth=ClientFrames(tmp_path / "cloth"), truth=truth)
    out = tmp_path / "demo.mp4"
    assert write_mosaic(inputs, out) == 20
    info = video_info(out)
    assert (info.codec, info.frames, info.width) == ("h264", 20, 2 * TILE[0])


# ------------------------------------------------------------------------- whole-system runs


def _run_demo(argv: list[str], timeout: float) -> tuple[subprocess.CompletedProcess[str], dict[str, object]]:
    proc = subprocess.run([sys.executable, "-m", "tracker_service", "demo", *argv], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO_ROOT)
    lines = proc.stdout.strip().splitlines()
    assert lines, proc.stderr[-3000:]
    return proc, json.loads(lines[-1])


@pytest.mark.slow
def test_whole_system_short_round(tmp_path: Path, small_db) -> None:  # type: ignore[no-untyped-def]
    """Tracker, game and cloth as three processes over a loopback router, on a 1.8 s script (one
    strike): ends by itself, exit 0, a consistent summary and an H.264 mosaic (on the tests' small
    database: the counts are checked for consistency, not for recognition)."""
    script = REPO_ROOT / "game_client" / "scripts" / "strike.toml"
    port = free_tcp_endpoint().rsplit(":", 1)[1]  # the live viewer runs beside them
    proc, summary = _run_demo(["--script", str(script), "--out", str(tmp_path), "--json", "--db", str(small_db[-1]),
                               "--view", port], timeout=150)
    why = [ln for ln in proc.stderr.splitlines() if ln.startswith("mocap-tracker demo:")]
    assert proc.returncode == 0, (why, proc.stderr[-2000:])
    assert KEYS <= set(summary) and summary["ok"] is True
    performed, recognised = summary["gestures_performed"], summary["gestures_recognised"]
    assert isinstance(performed, int) and isinstance(recognised, int) and 0 <= recognised <= performed <= 1
    fps = summary["fps"]
    assert isinstance(fps, dict) and all(fps[k] > 0 for k in ("tracker", "game", "cloth"))
    latency = summary["latency_ms"]
    assert isinstance(latency, dict) and 0 < latency["p50"] <= latency["p99"]
    assert isinstance(summary["mpjpe_cm"], float) and 0 < summary["mpjpe_cm"] < 30
    assert isinstance(summary["round"], str) and summary["round"]
    video = tmp_path / "demo.mp4"
    assert summary["video"] is not None and Path(str(summary["video"])).resolve() == video.resolve()
    info = video_info(video)
    assert info.codec == "h264" and info.frames > 15 and info.width == 2 * TILE[0]
    assert any((tmp_path / "game").glob("frame_*.png")) and any((tmp_path / "cloth").glob("frame_*.png"))


@pytest.mark.slow
def test_replay_check() -> None:
    """``mocap-tracker demo --replay`` (the quick check) still works."""
    proc, summary = _run_demo(["--replay", "--duration", "2", "--json"], timeout=60)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert summary["ok"] is True and int(str(summary["frames"])) > 0 and summary["in_order"] is True
