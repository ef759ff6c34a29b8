"""``mocap-tracker bench``: its options, and a tiny run (2 estimators, 6 frames, 2 repeats) that writes
the table and the plots."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tracker_service.app import cli
from tracker_service.app.estimator_bench import ESTIMATOR_NAMES, PLOTS, BenchOptions, cost_mean, spread_per_frame
from tracker_service.estimators import ESTIMATORS


def test_bench_arguments_become_bench_options() -> None:
    args = cli.build_parser().parse_args(["bench", "--estimators", "tree,srs", "--bvh", "a.bvh", "b.bvh",
                                          "--frames", "6", "--repeats", "2", "--out", "o"])
    (command,) = [c for c in cli.COMMANDS if c.NAME == "bench"]
    o = command.options_from_args(args)
    assert o == BenchOptions(estimators=("tree", "srs"), out="o", bvh=("a.bvh", "b.bvh"), frames=6, repeats=2)
    assert set(ESTIMATORS) <= set(ESTIMATOR_NAMES)
    for bad in (["--estimators", "tree,nope"], ["--estimators", "tree,tree"], ["--repeats", "0"], []):
        with pytest.raises(SystemExit):
            cli.main(["bench", *bad] + ([] if not bad else ["--out", "o"]))


def test_a_tiny_run_writes_the_table_and_the_plots(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "bench"
    assert cli.main(["bench", "--estimators", "tree,drs", "--frames", "6", "--repeats", "2", "--out", str(out),
                     "-q"]) == 0
    assert "| drs |" in capsys.readouterr().out
    table = (out / "table.md").read_text()
    assert "| tree |" in table and "| drs |" in table
    report = json.loads((out / "table.json").read_text())
    tree, drs = report["results"]["tree"], report["results"]["drs"]
    assert tree["time_vs_tree"] == 1.0 and drs["error_vs_tree"] > 0
    assert len(drs["per_frame_cm"]) == 6 and len(drs["per_joint_mean_cm"]) == len(report["meta"]["joint_names"])
    assert drs["evals_per_frame"] > 0 and 0.0 <= drs["within_10cm"] <= 1.0
    assert [r["seed"] for r in report["repeats"]["drs"]] == [0, 1]
    assert all(len(r["cost_per_frame"]) == 6 and min(r["cost_per_frame"]) >= 0 for r in report["repeats"]["drs"])
    assert "2D cost" in table and "spread over the seeds" in table
    for r in (tree, drs):  # a forced loss in the middle of every clip
        assert r["losses"] >= 1 and 0 <= r["recovered"] <= r["losses"]
        assert r["recovered"] == 0 or 1 <= r["recovery_frames_avg"] <= r["recovery_frames_max"]
    assert "back after a forced loss" in table
    for name in PLOTS:
        png = (out / name).read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000


def test_run_to_run_spread_is_the_std_over_runs_per_frame_averaged() -> None:
    runs = [{"joint_angle_deg": [0.0, 10.0], "cost_per_frame": [0.01, 0.03]},
            {"joint_angle_deg": [2.0, 10.0], "cost_per_frame": [0.01, 0.01]}]
    assert spread_per_frame(runs) == 0.5  # std 1 on the first frame, 0 on the second
    assert abs(spread_per_frame(runs, "cost_per_frame") - 0.005) < 1e-12
    assert abs(cost_mean(runs) - 0.015) < 1e-12
