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
