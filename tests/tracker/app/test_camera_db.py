"""Templates follow the camera: --camera / the shorthands pick (or build, once) the database rendered
for the requested camera; the same camera, also at another frame size of the same aspect, reuses."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import pytest

from tracker_service.app import resources
from tracker_service.app.options import BuildDbOptions, RunCommandOptions, TrackerOptions
from tracker_service.camera import default_camera, placed_camera, same_camera, save_camera_file
from tracker_service.templates.database import DatabaseError, camera_db_dir, db_camera, default_db_dir, load_db

TINY = BuildDbOptions(takes=1, max_poses=60, scripts=())


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """out/ in a temporary folder holding a tiny default database (out/db/mMA)."""
    monkeypatch.setenv("MOCAP_CACHE", str(tmp_path))
    resources.build_database("mMA", default_db_dir("mMA"), TINY)
    return tmp_path


def _no_build(*_a: Any, **_k: Any) -> None:
    raise AssertionError("no database should be built")


def test_the_same_camera_reuses_the_database(cache: Path, monkeypatch: pytest.MonkeyPatch,
                                             caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setattr(resources, "build_database", _no_build)
    base = default_db_dir("mMA")
    assert base == cache / "db" / "mMA"
    with caplog.at_level(logging.INFO):
        assert resources.resolve_db(None, default_camera()) == base
        assert resources.resolve_db(None, placed_camera(1.2, 0.0, 62.7)) == base  # within half a pixel
        # 640x480 frames of the same camera are scaled to 320x240: the same templates
        assert resources.resolve_db(None, default_camera(640, 480)) == base
    assert "640x480 frames are scaled to the database's working size 320x240" in caplog.text
    assert resources.ensure_db(None, camera=default_camera(640, 480)).path == base


def test_another_camera_builds_its_database_once(cache: Path, monkeypatch: pytest.MonkeyPatch,
                                                 caplog: pytest.LogCaptureFixture) -> None:
    tilted = placed_camera(1.5, 12.0, width=640, height=480)
    work = tilted.fitted((320, 240))
    target = camera_db_dir("mMA", work)
    assert target == cache / "db" / f"mMA-cam{work.digest()}"
    with pytest.raises(DatabaseError, match=r"rendered for camera 320x240 f=262\.5/262\.5 px .* none for camera"):
        resources.resolve_db(None, tilted, build_if_missing=False)
    with caplog.at_level(logging.INFO):
        got = resources.resolve_db(None, tilted, build_options=TINY)
    assert got == target
    assert (f"the database at {default_db_dir('mMA')} was rendered for camera 320x240 f=262.5/262.5 px "
            f"c=(159.5, 119.5), 1.20 m high, tilt +0.0 deg") in caplog.text
    assert "building one for camera 320x240 f=262.5/262.5 px c=(159.5, 119.5), 1.50 m high, tilt +12.0 deg" \
           in caplog.text and f"at {target} (a few minutes, cached)" in caplog.text
    loaded = load_db(target)
    assert same_camera(loaded.camera, work, tol_px=1e-6) and loaded.body.name == "mMA"
    man = json.loads((target / "manifest.json").read_text())
    assert man["camera_digest"] == work.digest() and man["camera_opencv"]["image_size"] == [320, 240]
    cam, body = db_camera(target)
    assert body == "mMA" and cam.digest() == work.digest()
    # cached: the second time (also through --db naming the default database, or the file) builds nothing
    monkeypatch.setattr(resources, "build_database", _no_build)
    caplog.clear()
    with caplog.at_level(logging.INFO):
        assert resources.resolve_db(None, tilted) == target
        assert resources.resolve_db(str(default_db_dir("mMA")), tilted) == target
    assert "using the database rendered for this camera" in caplog.text
    f = save_camera_file(tilted, cache / "camera.json")
    assert resources.ensure_db(None, camera=resources.requested_camera(TrackerOptions(camera_file=str(f)))).path \
        == target
    # run: --db is pointed at the camera's database; without a camera option nothing changes
    from tracker_service.app.commands.run import with_camera_db

    plain = RunCommandOptions(source="frames:x")
    assert with_camera_db(plain) is plain
    opts = with_camera_db(RunCommandOptions(source="frames:x", tracker=TrackerOptions(camera_file=str(f))))
    assert opts.tracker.db == str(target)


def test_an_unreadable_named_database_is_reported(tmp_path: Path) -> None:
    with pytest.raises(DatabaseError, match="no template database at"):
        resources.resolve_db(str(tmp_path / "nothing"), placed_camera(1.5, 12.0))


def test_a_cached_database_follows_the_bundled_scripts(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                      caplog: pytest.LogCaptureFixture) -> None:
    """The default database built from the bundled gesture scripts is rebuilt, with the options it
    was built with, once those scripts change; one built from other folders is left alone."""
    import shutil

    monkeypatch.setenv("MOCAP_CACHE", str(tmp_path / "cache"))
    bundled = tmp_path / "scripts"
    bundled.mkdir()
    shutil.copy(resources.DEFAULT_SCRIPT, bundled / "crouch.toml")
    monkeypatch.setattr(resources, "DEFAULT_SCRIPT_DIRS", (bundled,))
    base = default_db_dir("mMA")
    resources.build_database("mMA", base, BuildDbOptions(takes=1, max_poses=60, scripts=(str(bundled),)))
    assert resources._stale_reason(base) is None
    real_build = resources.build_database
    monkeypatch.setattr(resources, "build_database", _no_build)
    assert resources.ensure_db(None).path == base

    (bundled / "crouch.toml").write_text((bundled / "crouch.toml").read_text() + "\n# edited\n")
    assert resources._stale_reason(base) == "the bundled gesture scripts changed since it was built"
    with caplog.at_level(logging.WARNING):
        assert resources.ensure_db(None, build_if_missing=False).path == base  # warns, builds nothing
    assert "is out of date (the bundled gesture scripts changed since it was built); rebuild it" in caplog.text
    calls: list[BuildDbOptions] = []

    def build(body: str, out: Path, options: BuildDbOptions, camera: Any = None) -> Any:
        calls.append(options)
        return real_build(body, out, options, camera)

    monkeypatch.setattr(resources, "build_database", build)
    resources.ensure_db(None)
    assert [(c.takes, c.max_poses) for c in calls] == [(1, 60)]
    assert resources._stale_reason(base) is None
    resources.ensure_db(None)
    assert len(calls) == 1  # current again: loaded as it is

    # built before digests were recorded: compared by the scripts' names
    man = json.loads((base / "manifest.json").read_text())
    for k in ("scripts_digest", "options"):
        man["meta"].pop(k)
    (base / "manifest.json").write_text(json.dumps(man))
    assert resources._stale_reason(base) is None
    shutil.copy(resources.DEFAULT_SCRIPT, bundled / "crouch_again.toml")
    assert resources._stale_reason(base) == "it was built from 1 bundled gesture scripts, the package now has 2"

    # built from other folders: never taken for stale
    resources.build_database("mMA", base, TINY)
    (bundled / "crouch.toml").unlink()
    assert resources._stale_reason(base) is None
