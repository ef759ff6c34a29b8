"""Estimators compared on the very same rendered silhouettes: the tree filter (Okada & Stenger),
Condensation (Isard & Blake), the cardbox paper's hierarchical particle filter with deterministic
(DRS) and stratified (SRS) resampling, and ELMO (Demirdjian et al.: likelihood modes found by
parameter-sensitive hashing over the tree's database leaves and local search, reweighted by a wide
temporal prior; its hash index is built before the clip, not timed). ``elmo-lite`` (ELMO on a
third of the evaluations) can be named in ``--estimators``.

Usage::

    .venv/bin/python bench/bench_estimators.py [--frames 60] [--step 2] [--take NAME | --bvh FILE]
        [--subject mMA] [--seed 0] [--estimators tree,condensation,drs,srs,elmo] [--out out/bench_estimators.json]

The tree filter searches a small database (the four takes of the test suite's fixture, body mMA,
built here in a few seconds); by default the clip is the first of them (the both-hands raise, so
*in* the tree filter's database: the tree's best case). ``--take`` picks another recording of the
index by file name (e.g. ``dataset-2_raise-up-both-hands_normal_002.bvh``, not in the database),
``--bvh`` any BVH file. Each frame is the subject's capsule silhouette
(:func:`tracker_service.body.raster.render_silhouette`), pre-processed once
(:func:`tracker_service.silhouette.features.preprocess`, nwXOR as the pipeline) and handed to every
estimator. Each estimator runs two frames first (numba compilation), then the clip from a fresh
state, numpy on one thread.

Prints a Markdown table and writes JSON: MPJPE (cm, root-relative, posterior-mean and MAP pose),
frames within 10 cm, ms per frame (min / avg / max), silhouette evaluations per frame, and the time
and error of each as a ratio to the tree filter's.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
from _host import host_probe  # bench/ is the script's folder
from threadpoolctl import threadpool_limits

from protocol import fk
from protocol.formats.load import load_motion
from protocol.formats.mocap_data import index_entries
from tracker_service.body.family import body_model
from tracker_service.body.raster import render_silhouette
from tracker_service.build.database import DbBuildConfig, build_filter_db, heading_of, set_heading, training_motions
from tracker_service.camera import default_camera
from tracker_service.estimators.base import Observation
from tracker_service.estimators.condensation import Condensation, CondensationParams
from tracker_service.estimators.elmo import Elmo, ElmoParams
from tracker_service.estimators.hierarchical_pf import HierarchicalPF, HPFParams
from tracker_service.estimators.particles import world_pose
from tracker_service.estimators.tree_filter.filter import FilterParams, TreeFilter
from tracker_service.silhouette.features import preprocess
from tracker_service.silhouette.placement import observed_placement

TAKES = ("dataset-2_raise-up-both-hands_normal_001.bvh", "dataset-2_raise-up-both-hands_active_062.bvh",
         "dataset-2_raise-up-right-hand_normal_001.bvh", "dataset-1_bye_normal_001.bvh")


def _clip(args: argparse.Namespace, body: Any, motions: list[Any]) -> tuple[str, np.ndarray]:
    if args.bvh:
        poses, name = load_motion(args.bvh, body=body, fps=30.0).poses, str(args.bvh)
    elif args.take:
        entries = [e for e in index_entries() if e.path.split("/")[-1] == args.take]
        if not entries:
            raise SystemExit(f"no recording {args.take!r} in the index")
        poses, name = training_motions(body, entries)[0].poses, args.take
    else:
        poses, name = motions[0].poses, TAKES[0] + " (in the tree's database)"
    poses = np.asarray(poses, np.float64)[: args.frames * args.step: args.step].copy()
    return name, set_heading(poses, heading_of(poses) - heading_of(poses[:1])[0])


def _run(est: Any, observations: list[Observation], truth: np.ndarray, cam: Any, body: Any) -> dict[str, Any]:
    st = est.init()
    for obs in observations[:2]:  # compile
        st, _ = est.step(st, obs)
    st = est.init()
    ms: list[float] = []
    err_mean: list[float] = []
    err_map: list[float] = []
    evals: list[int] = []
    for obs, tj in zip(observations, truth, strict=True):
        t0 = time.perf_counter()
        st, e = est.step(st, obs)
        ms.append(1000.0 * (time.perf_counter() - t0))
        evals.append(sum(e.evaluations))
        for mean, out in ((True, err_mean), (False, err_map)):
            j = fk(world_pose(e, cam, mean=mean), body)
            out.append(float(np.linalg.norm((j - j[0]) - (tj - tj[0]), axis=1).mean()))
    em = np.asarray(err_mean)
    return {"mpjpe_cm": 100 * float(em.mean()), "mpjpe_map_cm": 100 * float(np.mean(err_map)),
            "within_10cm": float(np.mean(em < 0.10)), "ms_min": float(np.min(ms)), "ms_avg": float(np.mean(ms)),
            "ms_max": float(np.max(ms)), "evals_per_frame": float(np.mean(evals)),
            "per_frame_cm": [round(100 * v, 2) for v in em]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=60, help="frames evaluated (after --step)")
    ap.add_argument("--step", type=int, default=2, help="take every step-th frame of the 30 Hz clip")
    ap.add_argument("--take", default=None, help="a recording of the index, by file name")
    ap.add_argument("--bvh", type=Path, default=None, help="a BVH file")
    ap.add_argument("--subject", default="mMA", help="body model rendered (the database's is mMA)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--estimators", default="tree,condensation,drs,srs,elmo")
    ap.add_argument("--out", type=Path, default=Path("out/bench_estimators.json"))
    args = ap.parse_args()

    cam = default_camera()
    db_body = body_model("mMA").body
    motions = training_motions(db_body, [e for e in index_entries() if e.path.split("/")[-1] in TAKES])
    cfg = DbBuildConfig(yaw_offsets_deg=(0.0,), level_thresholds=(0.02, 0.008, 0.004))
    db, _ = build_filter_db(motions, db_body, cam, cfg, rng=np.random.default_rng(1))
    subject = body_model(args.subject).body
    name, poses = _clip(args, subject, motions)
    truth = fk(poses, subject)
    observations = []
    for tj in truth:
        mask = render_silhouette(tj, subject.capsule_radii, cam)
        observations.append(Observation(preprocess(mask), observed_placement(mask, cam)))
    rng = np.random.default_rng(args.seed)
    make = {
        "tree": lambda: TreeFilter(db, FilterParams()),
        "condensation": lambda: Condensation(db_body, cam, CondensationParams(), rng),
        "drs": lambda: HierarchicalPF(db_body, cam, HPFParams("drs"), rng),
        "srs": lambda: HierarchicalPF(db_body, cam, HPFParams("srs"), rng),
        "elmo": lambda: Elmo(db, db_body, cam, ElmoParams(), rng),
        # ELMO on a smaller budget (not in the default list): 20 hypotheses, 2 refined, 2 rounds, 1 mode
        "elmo-lite": lambda: Elmo(db, db_body, cam, ElmoParams(n_hypotheses=20, n_refine=2, iterations=2,
                                                               max_modes=1), rng),
    }
    results: dict[str, dict[str, Any]] = {}
    with threadpool_limits(1):
        for key in args.estimators.split(","):
            results[key] = _run(make[key](), observations, truth, cam, db_body)
    ref = results.get("tree")
    for r in results.values():
        r["time_vs_tree"] = r["ms_avg"] / ref["ms_avg"] if ref else None
        r["error_vs_tree"] = r["mpjpe_cm"] / ref["mpjpe_cm"] if ref else None
    print(f"clip: {name}, {len(poses)} frames (every {args.step}), subject {args.subject}, seed {args.seed}\n")
    print("| estimator | MPJPE mean (cm) | MPJPE MAP (cm) | frames < 10 cm | ms/frame min / avg / max "
          "| evaluations / frame | time / tree | error / tree |")
    print("|---|---|---|---|---|---|---|---|")
    for key, r in results.items():
        ratio = ("—", "—") if ref is None else (f"{r['time_vs_tree']:.2f}", f"{r['error_vs_tree']:.2f}")
        print(f"| {key} | {r['mpjpe_cm']:.1f} | {r['mpjpe_map_cm']:.1f} | {100 * r['within_10cm']:.0f} % "
              f"| {r['ms_min']:.1f} / {r['ms_avg']:.1f} / {r['ms_max']:.1f} | {r['evals_per_frame']:.0f} "
              f"| {ratio[0]} | {ratio[1]} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"clip": name, "frames": len(poses), "step": args.step, "subject": args.subject, "seed": args.seed,
            "host_probe_s": host_probe(), "python": platform.python_version(), "machine": platform.machine()}
    args.out.write_text(json.dumps({"meta": meta, "results": results}, indent=1))
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
