"""Whole rounds from scripts (offline), the round scripts' generation, the renderer and the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np
import pytest

from game_client.cli import main
from game_client.compose import ROUNDS, compose, round_segments
from game_client.game import GameConfig, Phase
from game_client.render import FrameWriter, Renderer
from game_client.round import GameRound
from game_client.variants import SCRIPTS_DIR, Variant, dump_script, load_labels, variant_motion, variant_text
from protocol.formats.gesture_script import parse_script
from protocol.kinematics import fk


def _play(name: str, restart_at: float | None = None) -> tuple[GameRound, list[dict]]:
    m = variant_motion(name, Variant(fps=30.0))
    j = fk(m.poses, m.body)
    rnd = GameRound()
    log: list[dict] = []
    for k, t in enumerate(m.times):
        ts = float(t) if restart_at is None or t < restart_at else float(t) - restart_at + 0.5  # tracker restarts
        log += rnd.feed(ts, j[k]).log
    return rnd, log


def test_scripted_round_is_won_by_knockout() -> None:
    rnd, log = _play("round_win")
    summary = rnd.summary()
    assert (summary["winner"], summary["reason"], summary["opponent_health"]) == ("player", "knockout", 0.0)
    gestures = [r["gesture"] for r in log if r["type"] == "gesture"]
    assert gestures == ["transform", "crouch", "strike", "side_step", "fire_ring"]
    game = [(r["kind"], r["detail"]) for r in log if r["type"] == "game" and r["kind"] in ("dodge", "hit")]
    assert game == [("dodge", "high"), ("hit", "strike"), ("dodge", "side"), ("hit", "fire_ring")]
    assert all(json.dumps(r) for r in log)  # every record is plain JSON


def test_scripted_losing_round() -> None:
    rnd, log = _play("round_lose")
    assert (rnd.summary()["winner"], rnd.summary()["reason"]) == ("opponent", "knockout")
    assert sum(1 for r in log if r["type"] == "game" and r["kind"] == "hit") == 4


def test_a_tracker_restart_does_not_end_the_round() -> None:
    rnd, log = _play("round_win", restart_at=6.0)  # capture_ts jumps back to 0.5 s at 6 s
    assert rnd.counters["stream_restarts"] == 1
    assert rnd.game.phase == Phase.OVER and rnd.game.winner == "player"
    ts = [r["t"] for r in log if r["type"] == "state"]
    assert ts == sorted(ts)  # game time keeps running forward


def test_round_scripts_are_what_compose_generates() -> None:
    labels = load_labels()
    for name, kind in ROUNDS.items():
        segs, duration = round_segments(kind)
        doc, lbs = compose(segs, duration, name)
        text = (SCRIPTS_DIR / f"{name}.toml").read_text(encoding="utf-8")
        body = "".join(line + "\n" for line in text.splitlines() if not line.startswith("#"))
        assert body == dump_script(doc), f"{name}.toml is stale: run python -m game_client.compose"
        assert lbs == labels[name]


def test_variants_rewrite_scripts_consistently() -> None:
    text = (SCRIPTS_DIR / "side_step_right.toml").read_text(encoding="utf-8")
    v = Variant(speed=2.0, amplitude=0.5, height_m=1.6, yaw_deg=90.0, noise_rot_deg=1.0, seed=4, fps=60.0)
    script = parse_script(variant_text(text, v))
    assert script.duration == pytest.approx(2 * 2.1) and script.fps == 60.0
    assert script.body == {"height_m": 1.6} and script.noise_seed == 4
    last = script.keys[-1]
    # -0.45 m along x (the player's right), halved and turned by 90 deg about +Y: now along +z
    assert last.root["x"] == pytest.approx(0.0, abs=1e-9) and last.root["z"] == pytest.approx(0.225)
    with pytest.raises(FileNotFoundError):
        variant_motion("no_such_script")


def test_frame_writer_holds_a_bounded_evenly_thinned_gif(tmp_path: Path) -> None:
    w = FrameWriter(tmp_path, fps=10.0, png_every=1000, gif_max_frames=4, mp4=False)
    for k in range(21):
        assert w.due(k * 0.1)
        w.add(k * 0.1, np.full((4, 4, 3), 10 * k, np.uint8))
    w.close()
    gif = iio.imread(tmp_path / "round.gif", index=None)
    assert gif.shape[0] == 3 and [int(f[0, 0, 0]) for f in gif] == [0, 80, 160]  # frames 0, 8, 16


def test_renderer_draws_every_element_and_writer_saves_png_gif_mp4(tmp_path: Path) -> None:
    rnd, _ = _play("round_win")
    r = Renderer(GameConfig())
    img = r.draw(rnd.game.snapshot(), rnd.last_joints, ["1.0 > transform", "2.0 hit"], {"opponent"})
    assert img.shape == (360, 480, 3) and img.dtype == np.uint8
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 20  # arena, fighters, panel, stick figure, text
    w = FrameWriter(tmp_path, fps=5.0)
    for k in range(6):
        if w.due(k * 0.1):
            w.add(k * 0.1, r.draw(rnd.game.snapshot(), rnd.last_joints, [f"frame {k}"]))
    files = w.close()
    assert sorted(p.name for p in tmp_path.glob("frame_*.png")) == ["frame_00000.png", "frame_00001.png",
                                                                      "frame_00002.png"]
    assert {p.name for p in files} == {"round.gif", "round.mp4"}
    assert iio.imread(tmp_path / "round.gif", index=None).shape[0] == 3
    cap = cv2.VideoCapture(str(tmp_path / "round.mp4"))
    assert cap.isOpened() and int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 3
    cap.release()


def test_cli_recognize_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["recognize", "--script", str(SCRIPTS_DIR / "strike.toml"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == 55
    (e,) = out["events"]
    assert e["gesture"] == "strike" and {"start_s", "end_s", "confidence", "latency_ms"} <= set(e)
    assert main(["recognize", "--script", str(SCRIPTS_DIR / "side_step_left.toml"), "--rate", "120"]) == 0
    assert "side_step left" in capsys.readouterr().out


def test_cli_play_writes_log_and_frames(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log, frames = tmp_path / "round.jsonl", tmp_path / "frames"
    assert main(["play", "--script", str(SCRIPTS_DIR / "round_win.toml"), "--log", str(log),
                 "--frames-out", str(frames), "--fps", "4", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert (summary["winner"], summary["reason"]) == ("player", "knockout")
    records = [json.loads(line) for line in log.read_text().splitlines()]
    assert records[-1]["type"] == "summary" and records[-1]["winner"] == "player"
    assert (frames / "round.gif").is_file() and (frames / "round.mp4").is_file()
    assert len(list(frames.glob("frame_*.png"))) >= 50


def test_cli_errors_are_one_line_and_exit_1(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["recognize", "--script", str(tmp_path / "missing.toml")]) == 1
    assert "not found" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 3\n[[key]]\nt = -1\n")
    assert main(["play", "--script", str(bad)]) == 1
    assert capsys.readouterr().err.count("\n") == 1
    with pytest.raises(SystemExit) as exc:
        main(["run", "--max-frames", "0"])
    assert exc.value.code == 2
