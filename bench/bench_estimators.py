"""Estimators compared on the very same rendered silhouettes: the tree filter (Okada & Stenger),
Condensation (Isard & Blake), the cardbox paper's hierarchical particle filter with deterministic
(DRS) and stratified (SRS) resampling, and ELMO (Demirdjian et al.). ``elmo-lite`` (ELMO on a
third of the evaluations) can be named in ``--estimators``. A thin wrapper over
:mod:`tracker_service.app.estimator_bench` (also ``mocap-tracker bench``), which documents the
set-up.

Usage::

    .venv/bin/python bench/bench_estimators.py [--frames 60] [--step 2] [--take NAME | --bvh FILE]
        [--subject mMA] [--seed 0] [--estimators tree,condensation,drs,srs,elmo] [--repeats 1]
        [--plots] [--out out/bench_estimators.json]

Prints a Markdown table and writes JSON to ``--out`` (and ``table.md``, ``table.json`` and, with
``--plots``, the PNG plots into the folder of the same name without ``.json``): MPJPE (cm,
root-relative, posterior-mean and MAP pose), frames within 10 cm, ms per frame (min / avg / max),
silhouette evaluations per frame, and the time and error of each as a ratio to the tree filter's.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from tracker_service.app.estimator_bench import BenchOptions, markdown_table, run_bench, write_outputs


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=60, help="frames evaluated (after --step)")
    ap.add_argument("--step", type=int, default=2, help="take every step-th frame of the 30 Hz clip")
    ap.add_argument("--take", default=None, help="a recording of the index, by file name")
    ap.add_argument("--bvh", type=Path, default=None, help="a BVH file")
    ap.add_argument("--subject", default="mMA", help="body model rendered (the database's is mMA)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--estimators", default="tree,condensation,drs,srs,elmo")
    ap.add_argument("--repeats", type=int, default=1, help="DRS/SRS runs with seeds seed, seed+1, ...")
    ap.add_argument("--plots", action="store_true", help="also write the PNG plots")
    ap.add_argument("--out", type=Path, default=Path("out/bench_estimators.json"))
    args = ap.parse_args()

    options = BenchOptions(estimators=tuple(args.estimators.split(",")), out=str(args.out.with_suffix("")),
                           bvh=(str(args.bvh),) if args.bvh else (), take=args.take, frames=args.frames,
                           step=args.step, subject=args.subject, seed=args.seed, repeats=args.repeats,
                           plots=args.plots)
    report = run_bench(options)
    print(markdown_table(report))
    write_outputs(report, options.out, options.plots)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    print(f"wrote {args.out} (and {options.out}/)")


if __name__ == "__main__":
    main()
