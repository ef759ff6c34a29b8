"""``mocap-tracker render``: parsed as cli.py parses it, run through its Options."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from protocol.formats.mocap_data import mocap_root
from protocol.skeleton import JOINT_NAMES, N_PARTS, POSE_SIZE
from tracker_service.app.commands import render as render_command
from tracker_service.app.render import label_palette

SCRIPT = Path(__file__).resolve().parents[3] / "protocol" / "scripts" / "crouch.toml"


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="mocap-tracker")
    render_command.add_parser(parser.add_subparsers(dest="command", required=True), ())
    return parser.parse_args(argv)


def run_render(args: argparse.Namespace) -> int:
    """What ``mocap-tracker`` does with parsed arguments: Options from them, then the command."""
    return render_command.main(render_command.options_from_args(args))


def test_render_to_a_folder_with_truth_and_masks(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "crouch"
    args = _parse(["render", "--script", str(SCRIPT), "--out", str(out), "--frames", "6", "--empty-prefix", "2",
                   "--seed", "4", "--masks", "--json"])
    assert run_render(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == 6
    frames = sorted((out / "frames").glob("*.png"))
    assert [f.name for f in frames] == [f"{i:06d}.png" for i in range(6)]
    img = np.asarray(cv2.imread(str(frames[3])))
    assert img.shape == (240, 320, 3)
    records = [json.loads(line) for line in (out / "truth.jsonl").read_text().splitlines()]
    assert [r["index"] for r in records] == list(range(6))
    assert [r["present"] for r in records] == [False, False, True, True, True, True]
    rec = records[4]
    assert len(rec["pose"]) == POSE_SIZE and len(rec["joints"]) == len(JOINT_NAMES) == len(rec["joints_2d"])
    assert len(rec["part_pixels"]) == N_PARTS and rec["silhouette_area"] == sum(rec["part_pixels"])
    sil = np.asarray(cv2.imread(str(out / "silhouettes" / "000004.png"), cv2.IMREAD_GRAYSCALE)) > 0
    assert sil.sum() == rec["silhouette_area"]
    x0, y0, x1, y1 = rec["bbox"]
    assert sil[y0:y1, x0:x1].sum() == sil.sum()
    labels = np.asarray(cv2.imread(str(out / "labels" / "000004.png")))
    assert (labels.sum(axis=2) > 0).sum() == sil.sum()
    meta = json.loads((out / "scene.json").read_text())
    assert meta["seed"] == 4 and meta["camera"]["width"] == 320 and len(meta["parts"]) == N_PARTS


def test_render_to_a_video(tmp_path: Path) -> None:
    out = tmp_path / "bye.mp4"
    bvh = mocap_root() / "bandai/dataset-1_bye_normal_001.bvh"
    assert run_render(_parse(["render", "--bvh", str(bvh), "--out", str(out), "--frames", "5"])) == 0
    cap = cv2.VideoCapture(str(out))
    n = 0
    while cap.read()[0]:
        n += 1
    assert n == 5
    assert len((tmp_path / "bye.truth.jsonl").read_text().splitlines()) == 5


def test_bad_input_gives_one_line_and_status_1(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert run_render(_parse(["render", "--bvh", str(tmp_path / "missing.bvh"), "--out", str(tmp_path / "o")])) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("mocap-tracker render:") and "\n" not in err
    assert run_render(_parse(["render", "--script", str(SCRIPT), "--out", str(tmp_path / "x.gif")])) == 1
    with pytest.raises(SystemExit):
        _parse(["render", "--script", str(SCRIPT), "--out", "o", "--frames", "0"])


def test_palette_has_a_colour_per_part() -> None:
    pal = label_palette()
    assert pal.shape == (N_PARTS + 1, 3) and np.all(pal[-1] == 0)
    assert len({tuple(c) for c in pal[:-1]}) == N_PARTS
