"""The ``mocap-tracker`` command line: each command's arguments become its frozen options, ``--version``,
the start-up SIGTERM hook, and the app layer's import structure (no entry <-> cli cycle; nothing
below the parser imports argparse)."""

from __future__ import annotations

import ast
import dataclasses
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from tracker_service.app import cli
from tracker_service.app.options import (
    BuildDbOptions,
    DemoOptions,
    EvalCommandOptions,
    RenderOptions,
    ReplayCommandOptions,
    RunCommandOptions,
    TrainAppearanceOptions,
)
from tracker_service.app.resources import default_script_dirs

APP = Path(cli.__file__).resolve().parent
REPO = APP.parents[1]


def parse(argv: list[str]) -> Any:
    args = cli.build_parser().parse_args(argv)
    (command,) = [c for c in cli.COMMANDS if c.NAME == args.command]
    return command.options_from_args(args)


def test_every_command_is_registered_once_in_help_order() -> None:
    assert [c.NAME for c in cli.COMMANDS] == ["replay", "demo", "build-db", "train-appearance", "run", "eval",
                                              "render", "record", "calibrate", "list",
                                              "bench"]


def test_run_arguments_become_run_options() -> None:
    o = parse(["run", "--source", "frames:/data/clip", "--wait-for-subscriber", "5", "--as-fast-as-possible",
               "--id", "cam1", "--frames", "9", "--duration", "2.5", "--seed", "3", "--no-refine", "--no-skin",
               "--max-heading", "35", "--appearance", "off", "--pose", "map", "--listen", "tcp/127.0.0.1:7999"])
    assert isinstance(o, RunCommandOptions)
    assert (o.source, o.seed) == ("frames:/data/clip", 3)
    d = o.daemon
    assert (d.tracker_id, d.max_frames, d.duration, d.realtime, d.wait_for_subscriber) == ("cam1", 9, 2.5, False, 5.0)
    t = o.tracker
    assert not t.refine and not t.skin and t.shoes and t.smoothing and t.proportions and t.reading_filter
    assert (t.max_heading_deg, t.appearance, t.pose, t.subject_allowed) == (35.0, "off", "map", False)
    assert (o.zenoh.role, o.zenoh.listen, o.zenoh.connect, o.zenoh.mode) == ("publisher", ("tcp/127.0.0.1:7999",),
                                                                              None, None)
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.source = "camera"  # type: ignore[misc]
    defaults = parse(["run"])
    assert defaults.daemon.realtime and defaults.daemon.tracker_id == "default" and defaults.tracker.db is None
    assert defaults.fps is None and parse(["run", "--fps", "60"]).fps == 60.0
    assert not defaults.prerender and parse(["run", "--prerender"]).prerender
    for bad in ("0", "-30", "nan", "241", "1e9"):  # a frame rate, not millions of frames of a motion
        with pytest.raises(SystemExit):
            parse(["run", "--fps", bad])


def test_eval_arguments_become_eval_options() -> None:
    o = parse(["eval", "--script", "wave.toml", "--json", "--frames", "40", "--seed", "2",
               "--force-loss-every", "1.5", "--measurements", "subject:leg", "--db", "db/x", "--no-occlusion"])
    assert isinstance(o, EvalCommandOptions)
    assert (o.motion, o.json) == ("wave.toml", True)
    assert (o.evaluation.frames, o.evaluation.seed, o.evaluation.force_loss_every_s) == (40, 2, 1.5)
    assert o.tracker.subject_allowed and o.tracker.measurements == "subject:leg" and o.tracker.db == "db/x"
    assert not o.tracker.occlusion
    assert parse(["eval", "--bvh", "take.bvh"]).motion == "take.bvh"


def test_build_db_and_train_appearance_options() -> None:
    o = parse(["build-db", "--bodies", "mMA,wTY", "--out", "dbs", "--max-poses", "50", "--takes", "2"])
    assert o == BuildDbOptions(bodies=("mMA", "wTY"), scripts=default_script_dirs(), out="dbs", max_poses=50,
                               takes=2)
    assert parse(["build-db", "--no-scripts", "--scripts", "a"]).scripts == ()  # --no-scripts wins
    assert parse(["build-db", "--scripts", "a", "--scripts", "b"]).scripts == ("a", "b")
    t = parse(["train-appearance", "--no-posture", "--passes", "1:2;3:4", "--jobs", "3", "--width", "8"])
    assert isinstance(t, TrainAppearanceOptions)
    assert t.posture_passes == () and t.passes == (((1, 2),), ((3, 4),)) and (t.jobs, t.width) == (3, 8)
    assert t.scripts == default_script_dirs() and t.out is None
    t = parse(["train-appearance", "--posture-passes", "9:60", "--no-scripts"])
    assert t.posture_passes == (((9, 60),),) and t.scripts == ()
    assert parse(["train-appearance"]).posture_passes is None  # the defaults
    assert parse(["train-appearance"]).vary_passes is None
    t = parse(["train-appearance", "--no-vary"])
    assert t.vary_passes == () and t.posture_passes is None
    assert parse(["train-appearance", "--vary-passes", "9:3;10:3"]).vary_passes == (((9, 3),), ((10, 3),))


def test_replay_render_and_demo_options() -> None:
    r = parse(["replay", "--synthetic-wave", "--rate", "60", "--loop", "--id", "w1", "--frames", "5"])
    assert isinstance(r, ReplayCommandOptions) and r.synthetic_wave and r.motion is None
    assert (r.publish.tracker_id, r.publish.rate, r.publish.loop, r.publish.max_frames) == ("w1", 60.0, True, 5)
    assert parse(["replay", "--bvh", "a.bvh"]).motion == "a.bvh"
    o = parse(["render", "--script", "s.toml", "--out", "o.mp4", "--no-noise", "--jitter", "1.5", "--masks"])
    assert o == RenderOptions(motion="s.toml", out="o.mp4", noise=False, jitter_px=1.5, masks=True)
    assert parse(["demo", "--replay", "--duration", "2"]) == DemoOptions(duration=2.0, replay=True)


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["--version"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out == f"mocap-tracker {cli.version()}\n" and cli.version()[0].isdigit()


def test_default_sigterm_hook_only_for_commands_without_a_clean_stop(tmp_path: Path) -> None:
    calls: list[str] = []
    assert cli.main(["replay", "--bvh", str(tmp_path / "none.bvh")], default_sigterm=lambda: calls.append("x")) == 1
    assert calls == []  # replay installs its own handlers
    assert cli.main(["eval", "--bvh", str(tmp_path / "none.bvh")], default_sigterm=lambda: calls.append("x")) == 1
    assert calls == ["x"]


def test_entry_hands_the_cli_its_sigterm_hook(monkeypatch: pytest.MonkeyPatch) -> None:
    import signal

    from tracker_service.app import entry

    seen: dict[str, Any] = {}
    monkeypatch.setattr(cli, "main", lambda argv, **kw: seen.update(kw, argv=argv) or 0)
    before = signal.getsignal(signal.SIGTERM)
    try:
        assert entry.main(["eval", "--bvh", "x"]) == 0
    finally:
        signal.signal(signal.SIGTERM, before)
    assert seen == {"argv": ["eval", "--bvh", "x"], "default_sigterm": entry.default_sigterm}


def _imports(path: Path, top_level_only: bool) -> set[str]:
    tree = ast.parse(path.read_text(), str(path))
    nodes = tree.body if top_level_only else list(ast.walk(tree))
    out: set[str] = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
    return out


def test_entry_imports_only_the_standard_library_and_nothing_imports_entry() -> None:
    top = _imports(APP / "entry.py", top_level_only=True)
    assert {m.split(".")[0] for m in top} <= set(sys.stdlib_module_names) | {"__future__"}, top
    for path in APP.rglob("*.py"):
        if path.name != "entry.py":
            assert "tracker_service.app.entry" not in _imports(path, top_level_only=False), path
    r = subprocess.run([sys.executable, "-c", "import sys, tracker_service.app.entry; "
                        "print(sorted(m for m in sys.modules if m.startswith(('tracker_service.app.cli', 'numpy'))))"],
                       cwd=REPO, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == "[]", r.stderr


@pytest.mark.parametrize("name", ["daemon.py", "replay_daemon.py", "evaluate.py", "replay.py", "render.py",
                                  "resources.py", "tracker_config.py", "appearance_training.py", "options.py",
                                  "record.py"])
def test_nothing_below_the_parser_imports_argparse(name: str) -> None:
    assert "argparse" not in _imports(APP / name, top_level_only=False)


def test_smoothing_and_video_options() -> None:
    o = parse(["run", "--smooth-cutoff", "2.5", "--smooth-beta", "0.7", "--video", "out/run.mp4"])
    assert (o.tracker.smooth_cutoff, o.tracker.smooth_beta, o.video) == (2.5, 0.7, "out/run.mp4")
    e = parse(["eval", "--bvh", "t.bvh", "--smooth-cutoff", "3", "--video", "e.mp4", "--json", "-q"])
    assert (e.tracker.smooth_cutoff, e.tracker.smooth_beta, e.video, e.json, e.progress) == (3.0, None, "e.mp4",
                                                                                            True, False)
    assert parse(["eval", "--bvh", "t.bvh", "--json"]).progress  # progress on stderr also with --json
    d = parse(["run"])
    assert (d.tracker.smooth_cutoff, d.tracker.smooth_beta, d.video) == (None, None, None)
    for bad in (["--smooth-cutoff", "0"], ["--smooth-beta", "-1"], ["--no-smoothing", "--smooth-beta", "1"]):
        with pytest.raises(SystemExit):
            cli.main(["run", *bad])


def test_smoothing_flags_set_the_one_euro_parameters_of_joints_and_root() -> None:
    from tracker_service.app.options import TrackerOptions
    from tracker_service.app.tracker_config import tracker_config
    from tracker_service.pipeline.smoothing import OneEuroParams

    base = OneEuroParams()
    sm = tracker_config(TrackerOptions(appearance="off", smooth_cutoff=2.0, smooth_beta=0.25)).smoothing
    assert sm is not None
    assert (sm.min_cutoff_rot, sm.min_cutoff_root, sm.beta_rot, sm.beta_root) == (2.0, 2.0, 0.25, 0.25)
    assert (sm.min_cutoff_pos, sm.beta_pos, sm.d_cutoff) == (base.min_cutoff_pos, base.beta_pos, base.d_cutoff)
    assert tracker_config(TrackerOptions(appearance="off", smooth_beta=3.0)).smoothing == OneEuroParams(
        beta_rot=3.0, beta_root=3.0)
    assert tracker_config(TrackerOptions(appearance="off")).smoothing == base


def test_opengl_accelerate_info_is_quiet_by_default() -> None:
    import logging

    cli._setup_logging(0, False)
    assert not logging.getLogger("OpenGL.acceleratesupport").isEnabledFor(logging.INFO)
    cli._setup_logging(2, False)
    assert logging.getLogger("OpenGL.acceleratesupport").isEnabledFor(logging.DEBUG)
    cli._setup_logging(0, False)


def test_eval_summary_is_aligned_lines() -> None:
    from tracker_service.app.commands.eval import summary_lines

    result = {"motion": "wave", "frames": 40, "tracked_frames": 30, "mpjpe_cm": 6.234, "root_error_cm": 3.0,
              "mpjpe_2d_px": 4.5, "frames_within_10cm": 0.9, "accel_error_cm": 1.2, "fps": 45.1,
              "ms_per_frame": {"total": {"min": 10.0, "avg": 22.2, "max": 40.0}}, "body_selected": "mMA",
              "subject_height_m": 1.71, "forced_losses": 0, "reinitialisations": 0}
    lines = summary_lines(result, (("video", "e.mp4"),))
    text = "\n".join(lines)
    assert "MPJPE" in text and "6.23 cm" in text and "90.0 % of frames" in text and "45.1" in text and "mMA" in text
    assert lines[-1].split() == ["video", "e.mp4"]
    starts = {len(line) - len(line.split("  ", 1)[1].lstrip()) for line in lines}
    assert len(starts) == 1  # the values start in one column
