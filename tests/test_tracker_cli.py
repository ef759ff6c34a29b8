"""`mocap-tracker build-db --scripts DIR`: which files of a folder are gesture scripts."""

from pathlib import Path

import pytest

from tracker_service.tracker_cli import _gesture_scripts

REPO = Path(__file__).resolve().parents[1]


def test_game_scripts_folder_skips_the_label_file(capsys: pytest.CaptureFixture[str]) -> None:
    files = _gesture_scripts([str(REPO / "game_client" / "scripts")])
    names = {p.name for p in files}
    assert {"strike.toml", "fire_ring.toml", "transform.toml", "crouch.toml"} <= names
    assert "labels.toml" not in names
    assert "labels.toml" in capsys.readouterr().err


def test_broken_toml_is_kept_for_the_reader_to_report(tmp_path: Path) -> None:
    (tmp_path / "bad.toml").write_text("[[key]\nt = ")
    (tmp_path / "ok.toml").write_text("[[key]]\nt = 0.0\n")
    (tmp_path / "other.toml").write_text("title = 'not a script'\n")
    assert [p.name for p in _gesture_scripts([str(tmp_path)])] == ["bad.toml", "ok.toml"]


def test_tracker_options_build_the_config() -> None:
    import argparse
    import math

    from tracker_service.tracker_cli import _config

    def ns(**kw: object) -> argparse.Namespace:
        base = {"body": "auto", "distance": "xor", "no_occlusion": False, "max_heading": None, "no_skin": False,
                "no_smoothing": False, "pose": "mean", "measurements": None, "no_shoes": False}
        return argparse.Namespace(**(base | kw))

    cfg = _config(ns())
    assert cfg.filter.max_heading is None and cfg.skin is not None and cfg.smoothing is not None
    assert cfg.use_mean_pose and cfg.filter.mean_temperature > 1.0
    assert not _config(ns(pose="map")).use_mean_pose
    cfg = _config(ns(max_heading=35.0, no_skin=True, no_smoothing=True, body="wTY"))
    assert cfg.filter.max_heading == pytest.approx(math.radians(35.0))
    assert cfg.skin is None and cfg.smoothing is None and cfg.body_candidates == ("wTY",)
    assert cfg.shoes is not None and _config(ns(no_shoes=True)).shoes is None
    for bad in ({"max_heading": 0.0}, {"max_heading": 400.0}, {"body": "nobody"}):
        with pytest.raises(ValueError):
            _config(ns(**bad))
    # the user's measurements build the body; no selection
    cfg = _config(ns(measurements="height=1.83,group=men,leg=1.04"))
    assert cfg.body_candidates == () and cfg.body is not None
    assert cfg.body.height == pytest.approx(1.83)
    assert _config(ns(measurements="subject", measurements_subject=True)).body is None  # eval: with the scene
    for bad in ({"measurements": "subject"}, {"measurements": "subject:leg"},  # run: not the scene's person
                {"measurements": "subjectively", "measurements_subject": True},
                {"measurements": "subject:inseam", "measurements_subject": True}):
        with pytest.raises(ValueError):
            _config(ns(**bad))
    with pytest.raises(ValueError, match="not both"):
        _config(ns(measurements="height=1.7", body="mMA"))
    with pytest.raises(ValueError, match="leg"):
        _config(ns(measurements="height=1.7,leg=2"))
    from tracker_service.tracker_cli import _subject_keys

    assert _subject_keys(None) == () and _subject_keys("height=1.7") == () and _subject_keys("subjects") == ()
    assert _subject_keys("subject:height,leg") == ("height", "leg") and "arm" in _subject_keys("subject")
    with pytest.raises(ValueError):
        _subject_keys("subject:inseam")
