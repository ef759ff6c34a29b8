"""`mocap-tracker build-db --scripts DIR`: which files of a folder are gesture scripts; the tracker
options; `train-appearance`."""

import argparse
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from tracker_service.app.commands.train_appearance import parse_passes
from tracker_service.app.gesture_files import gesture_scripts
from tracker_service.app.options import TrackerOptions
from tracker_service.app.tracker_config import subject_keys, tracker_config

REPO = Path(__file__).resolve().parents[3]


def test_game_scripts_folder_skips_the_label_file(capsys: pytest.CaptureFixture[str]) -> None:
    files = gesture_scripts([str(REPO / "game_client" / "scripts")])
    names = {p.name for p in files}
    assert {"strike.toml", "fire_ring.toml", "transform.toml", "crouch.toml"} <= names
    assert "labels.toml" not in names
    assert "labels.toml" in capsys.readouterr().err


def test_broken_toml_is_kept_for_the_reader_to_report(tmp_path: Path) -> None:
    (tmp_path / "bad.toml").write_text("[[key]\nt = ")
    (tmp_path / "ok.toml").write_text("[[key]]\nt = 0.0\n")
    (tmp_path / "other.toml").write_text("title = 'not a script'\n")
    assert [p.name for p in gesture_scripts([str(tmp_path)])] == ["bad.toml", "ok.toml"]


def opts(**kw: Any) -> TrackerOptions:
    """The tracker options of ``run`` / ``eval`` with their defaults, overridden by ``kw`` (no
    appearance network unless given: the tests do not depend on a trained one)."""
    return replace(TrackerOptions(appearance="off"), **kw)


def test_tracker_options_build_the_config() -> None:
    import math

    cfg = tracker_config(opts())
    assert cfg.filter.max_heading is None and cfg.skin is not None and cfg.smoothing is not None
    assert cfg.use_mean_pose and cfg.filter.mean_temperature > 1.0
    assert not tracker_config(opts(pose="map")).use_mean_pose
    cfg = tracker_config(opts(max_heading_deg=35.0, skin=False, smoothing=False, body="wTY"))
    assert cfg.filter.max_heading == pytest.approx(math.radians(35.0))
    assert cfg.skin is None and cfg.smoothing is None and cfg.body_candidates == ("wTY",)
    assert cfg.shoes is not None and tracker_config(opts(shoes=False)).shoes is None
    assert cfg.refine is not None and tracker_config(opts(refine=False)).refine is None
    assert cfg.proportions is not None and tracker_config(opts(proportions=False)).proportions is None
    assert cfg.reading_filter is not None and tracker_config(opts(reading_filter=False)).reading_filter is None
    for bad in ({"max_heading_deg": 0.0}, {"max_heading_deg": 400.0}, {"body": "nobody"}):
        with pytest.raises(ValueError):
            tracker_config(opts(**bad))
    # the user's measurements build the body; no selection
    cfg = tracker_config(opts(measurements="height=1.83,group=men,leg=1.04"))
    assert cfg.body_candidates == () and cfg.body is not None
    assert cfg.body.height == pytest.approx(1.83)
    assert tracker_config(opts(measurements="subject", subject_allowed=True)).body is None  # eval: with the scene
    for bad in ({"measurements": "subject"}, {"measurements": "subject:leg"},  # run: not the scene's person
                {"measurements": "subjectively", "subject_allowed": True},
                {"measurements": "subject:inseam", "subject_allowed": True}):
        with pytest.raises(ValueError):
            tracker_config(opts(**bad))
    with pytest.raises(ValueError, match="not both"):
        tracker_config(opts(measurements="height=1.7", body="mMA"))
    with pytest.raises(ValueError, match="leg"):
        tracker_config(opts(measurements="height=1.7,leg=2"))
    assert subject_keys(None) == () and subject_keys("height=1.7") == () and subject_keys("subjects") == ()
    assert subject_keys("subject:height,leg") == ("height", "leg") and "arm" in subject_keys("subject")
    with pytest.raises(ValueError):
        subject_keys("subject:inseam")


def test_the_appearance_option(tmp_path: Path, weak_appearance_net: Path) -> None:
    from tracker_service.cues.appearance import AppearanceError

    assert tracker_config(opts()).appearance is None
    net = tracker_config(opts(appearance=str(weak_appearance_net))).appearance
    assert net is not None and net.meta == {"fixture": "standing"}
    with pytest.raises(AppearanceError, match="train-appearance"):  # a named file must exist
        tracker_config(opts(appearance=str(tmp_path / "none.npz")))
    (tmp_path / "junk.npz").write_text("not a network")
    with pytest.raises(AppearanceError, match="corrupt"):
        tracker_config(opts(appearance=str(tmp_path / "junk.npz")))
    assert parse_passes("1000:3,2000:2") == (((1000, 3), (2000, 2)),)
    assert parse_passes("1000:3,2000:2;5000:2") == (((1000, 3), (2000, 2)), ((5000, 2),))  # one list per network
    for bad in ("", "1000", "a:b", "5:0", "1000:3;", ";1000:3"):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_passes(bad)


@pytest.mark.slow
def test_train_appearance_command_end_to_end(tmp_path: Path) -> None:
    """``mocap-tracker train-appearance`` on two takes and a folder of one gesture script, one short
    pass, one posture-varied pass and one randomised-scene pass per network, one epoch: an ensemble
    of two networks in one file the tracker loads, and its rendered views cached beside it (the script's by name)."""
    import shutil
    import subprocess
    import sys

    from tracker_service.cues.appearance import load_appearance

    out = tmp_path / "app" / "net.npz"
    scripts = tmp_path / "gestures" / "scripts"
    scripts.mkdir(parents=True)
    shutil.copy(REPO / "game_client" / "scripts" / "crouch.toml", scripts)
    (scripts / "labels.toml").write_text("title = 'not a script'\n")
    r = subprocess.run([sys.executable, "-m", "tracker_service", "train-appearance", "--takes", "2", "--passes",
                        "7:60;8:60", "--posture-passes", "9:60;10:60", "--vary-passes", "11:60;12:60",
                        "--epochs", "1", "--width", "8", "--jobs", "1",
                        "--scripts", str(scripts), "--out", str(out)],
                       cwd=REPO, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "appearance network 2:" in r.stdout and "1 gesture scripts" in r.stdout and out.is_file()
    net = load_appearance(out)
    assert net.size == 64 and net.meta["training_takes"] == 2 and len(net.networks) == 2
    assert [Path(p).name for p in net.meta["scripts"]] == ["crouch.toml"]
    assert [m["config"]["passes"] for m in net.meta["members"]] == [[[7, 60]], [[8, 60]]]
    assert [m["config"]["posture_passes"] for m in net.meta["members"]] == [[[9, 60]], [[10, 60]]]
    assert [m["config"]["vary_passes"] for m in net.meta["members"]] == [[[11, 60]], [[12, 60]]]
    assert [m["config"]["seed"] for m in net.meta["members"]] == [0, 1]
    assert [m["config"]["width"] for m in net.meta["members"]] == [8, 8]
    assert net.networks[0][0].weight.shape[0] == 8  # the first convolution's channels
    for folder in ("7_60_64_sub1", "8_60_64_sub1"):  # the tracker's silhouettes (--masks subtracted), cached apart
        names = sorted(p.name for p in (out.parent / "data" / folder).glob("*.npz"))
        assert len(names) == 3 and names[-1].startswith("script_crouch_900_")
    for folder in ("9_60_64_posture1_s0.5t25k70_sub1", "10_60_64_posture1_s0.5t25k70_sub1"):  # posture passes
        assert len(list((out.parent / "data" / folder).glob("*.npz"))) == 3
    for folder in ("11_60_64_vary1_sub1", "12_60_64_vary1_sub1"):  # randomised-scene passes, cached apart
        assert len(list((out.parent / "data" / folder).glob("*.npz"))) == 3
    r = subprocess.run([sys.executable, "-m", "tracker_service", "train-appearance", "--members", "3", "--out",
                        str(tmp_path / "never.npz")], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "--passes" in r.stderr and "Traceback" not in r.stderr
    for flags in (["--no-posture", "--posture-passes", "9:60"], ["--no-vary", "--vary-passes", "9:60"],
                  ["--no-scripts", "--scripts", str(scripts)]):
        r = subprocess.run([sys.executable, "-m", "tracker_service", "train-appearance", *flags, "--out",
                            str(tmp_path / "never.npz")], cwd=REPO, capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and "not allowed with" in r.stderr  # contradictory flags are refused
    r = subprocess.run([sys.executable, "-m", "tracker_service", "train-appearance", "--passes", "7:60",
                        "--posture-passes", "9:60;10:60", "--out", str(tmp_path / "never.npz")],
                       cwd=REPO, capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "posture pass list" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "-m", "tracker_service", "train-appearance", "--passes", "7:0"],
                       cwd=REPO, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "EVERY" in r.stderr
    for flag in ("--epochs", "--takes", "--jobs", "--members", "--width"):  # 0 is an error, not "the default"
        r = subprocess.run([sys.executable, "-m", "tracker_service", "train-appearance", flag, "0", "--out",
                            str(tmp_path / "never.npz")], cwd=REPO, capture_output=True, text=True, timeout=60)
        assert r.returncode != 0 and f"{flag} must be >= 1" in r.stderr and "Traceback" not in r.stderr
        assert not (tmp_path / "never.npz").exists()
