"""Tracker benchmarks: accuracy from pixels on held-out takes (distances and dynamic models
compared on the same frames), re-acquisition, speed per stage, the pyramid's speed-up and the
database's memory.

Usage::

    .venv/bin/python bench/bench_tracker.py [--takes N] [--frames N] [--seed S] [--configs ROWS] [--json]

``--takes 51`` evaluates every held-out take; fewer are spread evenly over the list (the 8-take
sample is the development set of TRACKER.md).

Needs the default database (``mocap-tracker build-db``; built on first use). Held-out takes are
the recordings whose INDEX.tsv row is divisible by 5 (never in the database). Every configuration
runs on the same rendered frames (same seeds). Not a test: it takes minutes.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import replace
from typing import Any

import numpy as np
from _host import held_out_spread, host_probe  # bench/ is the script's folder
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from protocol import fk
from protocol.formats.load import load_motion
from protocol.formats.mocap_data import index_entries, mocap_root
from protocol.motion import ground
from tracker_service.app.evaluate import EvalOptions, evaluate_motion
from tracker_service.app.resources import ensure_appearance, ensure_db
from tracker_service.body.family import BODY_MODELS
from tracker_service.body.raster import render_silhouette, silhouette_runs_batch
from tracker_service.build.database import is_held_out
from tracker_service.camera import default_camera
from tracker_service.estimators.base import Observation
from tracker_service.estimators.tree_filter.filter import FilterDB, FilterParams, initial_state, step
from tracker_service.pipeline.process import TrackerConfig
from tracker_service.pipeline.warmup import warm_up
from tracker_service.silhouette.background import BackgroundParams
from tracker_service.silhouette.distance import RunSet
from tracker_service.silhouette.features import preprocess
from tracker_service.silhouette.placement import observed_placement
from tracker_service.templates.database import default_db_dir, load_db


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return float(line.split()[1]) / 1024.0
    return float("nan")


def _no_pyramid(db: FilterDB, body: Any) -> FilterDB:
    """The same tree with every level evaluated at 320x240 (prototype silhouettes re-rendered from
    the pose of the leaf each prototype belongs to)."""
    cam = default_camera()
    runs = []
    for lvl in range(db.tree.n_levels):
        leaves = db.tree.template_leaf[db.tree.node_template[lvl]]
        joints = fk(db.leaf_poses[leaves].astype(np.float64), body)
        data, ptr = silhouette_runs_batch(joints, body.capsule_radii, cam)
        runs.append(RunSet(data=data, ptr=ptr))
    return replace(db, level_runs=tuple(runs), level_scale=(1.0,) * db.tree.n_levels)


def pyramid_speedup(loaded: Any, n_frames: int = 60) -> dict[str, float]:
    """Filter time per frame with and without the pyramid on the same capsule silhouettes."""
    db_full = _no_pyramid(loaded.db, loaded.body)
    for rs in (*loaded.db.level_runs, *db_full.level_runs):  # the XOR kernel's rectangles, outside the timing
        rs.rectangles()
    cam = loaded.camera
    entry = [e for i, e in enumerate(index_entries()) if is_held_out(i)][6]
    subject = BODY_MODELS[7].body
    m = load_motion(mocap_root() / entry.path, body=subject, fps=30)
    truth = fk(ground(m.poses, subject), subject)[:n_frames]
    times = {}
    for name, db, sizes in (("pyramid", loaded.db, None), ("full_resolution", db_full, ((320, 240),) * 3)):
        st = initial_state()
        t_sum = 0.0
        for j in truth:
            mask = render_silhouette(j, subject.capsule_radii, cam)
            obs = observed_placement(mask, cam)
            t0 = time.perf_counter()
            feats = preprocess(mask, "xor") if sizes is None else preprocess(mask, "xor", sizes=sizes)
            st, _ = step(st, db, Observation(feats, obs), FilterParams())
            t_sum += time.perf_counter() - t0
        times[name] = 1000 * t_sum / len(truth)
    return {"pyramid_ms": round(times["pyramid"], 2), "full_resolution_ms": round(times["full_resolution"], 2),
            "speedup": round(times["full_resolution"] / times["pyramid"], 2)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--takes", type=int, default=10,
                    help="held-out takes to evaluate, spread over the list (51: all of them)")
    ap.add_argument("--frames", type=int, default=150, help="frames per take")
    ap.add_argument("--seed", type=int, default=7, help="synthetic scene seed (the subject; 7: a woman 1.64 m tall)")
    ap.add_argument("--configs", help="comma-separated rows to run (default: all; e.g. xor_dm2 for the main row "
                                      "alone on another subject)")
    ap.add_argument("--no-pyramid", action="store_true", help="skip the pyramid speed-up measurement")
    ap.add_argument("--cpu", type=int, default=0,
                    help="pin the benchmark to this one CPU (the targets are per core; -1: do not pin)")
    ap.add_argument("--appearance", metavar="PATH|off",
                    help="the appearance cue's network (default: the one shipped in the package, as "
                         "`mocap-tracker run`; off: no cue)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    threadpool_limits(1, user_api="blas")  # one core per frame, as mocap-tracker runs (tracker_service/app/entry.py)
    if args.cpu >= 0:
        if args.cpu not in os.sched_getaffinity(0):
            raise SystemExit(f"--cpu {args.cpu}: not one of this process's CPUs {sorted(os.sched_getaffinity(0))}")
        os.sched_setaffinity(0, {args.cpu})
    loaded = ensure_db(None)  # also compiles the kernels, so the next figure is the arrays alone
    rss0 = _rss_mb()
    full = load_db(default_db_dir(), verify=False, mmap=False)
    res: dict[str, Any] = {"machine": f"{platform.node()} {platform.machine()}", "python": platform.python_version(),
                           "host_probe_s": host_probe(), "pinned_cpu": args.cpu if args.cpu >= 0 else None,
                           "db_rss_mb": round(_rss_mb() - rss0, 1), "templates": loaded.db.n_leaves,
                           "tree_levels": loaded.db.tree.level_sizes}
    rss1 = _rss_mb()
    for rs in loaded.db.level_runs:  # the distance kernel's rectangles, built on first use (warm-up)
        rs.rectangles()
    res["rectangles_rss_mb"] = round(_rss_mb() - rss1, 1)
    del full
    net = ensure_appearance(args.appearance, train_if_missing=True)
    res["appearance_net"] = None if net is None else [
        {k: m[k] for k in ("samples", "val_rms_x", "val_rms_y", "val_rms_z") if k in m}
        for m in (net.meta.get("members") or [net.meta])]  # one entry per network of the ensemble
    pick = held_out_spread(args.takes)
    configs = {
        "xor_dm2": TrackerConfig(distance="xor"),
        "cwxor_dm2": TrackerConfig(distance="cwxor"),
        "nwxor_dm2": TrackerConfig(distance="nwxor"),
        "xor_dm1": TrackerConfig(distance="xor", occlusion=False),
        # the paper's observation model: silhouettes only, the raw per-frame MAP estimate, feet on the floor
        "xor_silhouette_only": TrackerConfig(distance="xor", skin=None, smoothing=None, use_mean_pose=False,
                                             filter=FilterParams(height_hypothesis=False)),
        "xor_no_smoothing": TrackerConfig(distance="xor", smoothing=None),
        "xor_no_shoes": TrackerConfig(distance="xor", shoes=None),
        # the shoe cue only re-weighting the published legs, not in the filter's leaf likelihood
        "xor_shoes_publish_only": TrackerConfig(distance="xor", filter=FilterParams(shoe_weight=0.0)),
        "xor_map_pose": TrackerConfig(distance="xor", use_mean_pose=False),
        "xor_no_height_hypothesis": TrackerConfig(distance="xor", filter=FilterParams(height_hypothesis=False)),
        # twice as many level-0 likelihood-driven proposals as the default
        "xor_proposals_48_96": TrackerConfig(distance="xor", filter=FilterParams(keep_likelihood=(48, 96))),
        # the likelihood-driven proposals of the tracker before the appearance cue
        "xor_proposals_96_192": TrackerConfig(distance="xor", filter=FilterParams(keep_likelihood=(96, 192))),
        # every node on its whole placement grid (no screening)
        "xor_exhaustive": TrackerConfig(distance="xor", filter=FilterParams(screen=())),
        # no selection: the person's own measurements given (the user enters them; --measurements)
        "xor_given_height": TrackerConfig(distance="xor"),
        "xor_given_measurements": TrackerConfig(distance="xor"),
        # no appearance cue (a fresh install without the network)
        "xor_no_appearance": TrackerConfig(distance="xor"),
        # the appearance cue in the filter only: the published pose not refined toward its joints
        "xor_no_refine": TrackerConfig(distance="xor", refine=None),
        # a foot the refinement put through the floor left there
        "xor_no_floor": TrackerConfig(distance="xor", floor=None),
        # the network reads the crop once, not also mirrored
        "xor_no_mirror": TrackerConfig(distance="xor", appearance_mirror=False),
        # the selected model's bone proportions kept (no proportions from the cue)
        "xor_no_proportions": TrackerConfig(distance="xor", proportions=None),
        # the refinement toward each frame's raw reading, not the Kalman-filtered one
        "xor_no_reading_filter": TrackerConfig(distance="xor", reading_filter=None),
        # the ensemble's first network alone, everything else as the default
        "xor_one_network": TrackerConfig(distance="xor"),
        # the opening alone: no thin limb brought back by reconstruction
        "xor_no_reconstruct": TrackerConfig(distance="xor", background=BackgroundParams(reconstruct=False)),
        # half as many appearance proposals
        "xor_proposals_16": TrackerConfig(distance="xor", filter=FilterParams(appearance_proposals=16)),
        # the tree filter's estimate refined to the nearest silhouette likelihood mode (ELMO §3.2-3.3)
        "xor_tree_elmo": TrackerConfig(distance="xor", estimator="tree-elmo"),
        "xor_tree_elmo_no_appearance": TrackerConfig(distance="xor", estimator="tree-elmo"),
    }
    # the product's default carries the appearance cue; the paper's observation model and the row without it do not
    no_cue = ("xor_silhouette_only", "xor_no_appearance", "xor_tree_elmo_no_appearance")
    configs = {k: (c if k in no_cue else replace(c, appearance=net)) for k, c in configs.items()}
    if net is not None:
        configs["xor_one_network"] = replace(configs["xor_one_network"], appearance=replace(net, members=()))
    given = {"xor_given_height": ("height",),
             "xor_given_measurements": ("height", "group", "chest", "waist", "hip", "shoulder", "arm", "leg")}
    if args.configs:
        wanted = args.configs.split(",")
        unknown = sorted(set(wanted) - set(configs))
        if unknown:
            raise SystemExit(f"unknown --configs {unknown}; choose from {sorted(configs)}")
        configs = {k: v for k, v in configs.items() if k in wanted}
    bodies = tuple(m.name for m in BODY_MODELS)
    for name in {c.distance: name for name, c in configs.items()}.values():  # each distance's kernels
        warm_up(loaded.db, loaded.body, loaded.camera, replace(configs[name], body_candidates=bodies))
    rows: dict[str, list[dict[str, Any]]] = {k: [] for k in configs}
    for e in tqdm(pick, desc="held-out takes", disable=args.json):
        motion = load_motion(mocap_root() / e.path, fps=30.0)
        for name, cfg in configs.items():
            out = evaluate_motion(motion, loaded, replace(cfg, body_candidates=bodies),
                                  EvalOptions(frames=args.frames, seed=args.seed, force_loss_every_s=3.0,
                                              subject_measurements=given.get(name, ())))
            out["take"] = e.path
            rows[name].append(out)
    summary = {}
    for name, rs in rows.items():
        def avg(key: str, rs: list[dict[str, Any]] = rs) -> float:
            v = [r[key] for r in rs if r[key] is not None]
            return round(float(np.mean(v)), 2) if v else float("nan")

        re = [r["reacquire_s_max"] for r in rs]
        summary[name] = {"mpjpe_cm": avg("mpjpe_cm"), "root_error_cm": avg("root_error_cm"),
                         "mpjpe_2d_px": avg("mpjpe_2d_px"), "frames_within_10cm": avg("frames_within_10cm"),
                         "accel_error_cm": avg("accel_error_cm"),
                         "joint_jumps_15cm": int(sum(r["joint_jumps_15cm"] for r in rs)),
                         "worst_joint_jump_cm": max(r["worst_joint_jump_cm"] for r in rs),
                         "reacquire_s_max": None if any(x is None for x in re) else max(re),
                         "forced_losses": int(sum(r["forced_losses"] for r in rs)),
                         "reacquired": int(sum(r["reacquired"] for r in rs)),
                         "reacquire_s_max_of_reacquired": max((x for x in re if x is not None), default=None),
                         "ms_total_avg": round(float(np.nanmean([r["ms_per_frame"]["total"]["avg"] for r in rs])), 2),
                         "ms_total_max": round(float(np.nanmax([r["ms_per_frame"]["total"]["max"] for r in rs])), 2),
                         # each take's 99th percentile over its average: stalls in the steady frames
                         "ms_total_p99_over_avg_worst": round(float(np.nanmax(
                             [r["ms_per_frame"]["total"]["p99"] / r["ms_per_frame"]["total"]["avg"] for r in rs])), 2),
                         "initialisation_ms_avg": round(float(np.mean([r["initialisation_ms"] for r in rs])), 1),
                         "evals_per_level": np.mean([r["distance_evals_per_level"] for r in rs
                                                     if r["distance_evals_per_level"]], axis=0).round(0).tolist(),
                         "takes_without_steady_frames": sum(not r["distance_evals_per_level"] for r in rs)}
    res["summary"] = summary
    res["per_take"] = {k: [{kk: r[kk] for kk in ("take", "mpjpe_cm", "root_error_cm", "frames_within_10cm",
                                                 "accel_error_cm", "joint_jumps_15cm", "reacquire_s_max",
                                                 "body_selected", "subject_height_m", "body_height_m",
                                                 "stature_measured_m", "background_relearns", "withheld",
                                                 "tracked_frames", "frames")} for r in v]
                       for k, v in rows.items()}
    if not args.no_pyramid:
        res["pyramid"] = pyramid_speedup(loaded)
    print(json.dumps(res, indent=None if args.json else 1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
