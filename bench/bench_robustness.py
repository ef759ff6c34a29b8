"""The robustness matrix: the tracker from pixels on held-out takes, one row per domain-randomisation
axis of the synthetic scene (:mod:`tracker_service.scene.variation`), several subjects per row.

Usage::

    .venv/bin/python bench/bench_robustness.py [--axes default,body,...] [--seeds 1,5,9]
        [--takes N] [--frames N] [--jobs J] [--out DIR]

Every cell is ``mocap-tracker eval --json --vary AXIS`` (a subprocess, as a user runs it; ``--jobs``
at a time). Row ``default`` is the scene without variation: the same takes and seeds, so each row's
cost is its difference from that one. Writes ``robustness.md`` (the table) and ``robustness.json``
(every run) to ``--out`` (default ``out/bench_robustness``). Not a test: it takes minutes.
"""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from _host import bench_meta, held_out_spread, write_report  # bench/ is the script's folder
from tqdm import tqdm

from protocol.formats.mocap_data import mocap_root
from tracker_service.scene.variation import AXES

ROOT = Path(__file__).resolve().parent.parent


def _eval(bvh: Path, seed: int, axis: str, frames: int, appearance: str | None = None) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "tracker_service", "eval", "-q", "--json", "--bvh", str(bvh), "--seed", str(seed),
           "--frames", str(frames), "--vary", "" if axis == "default" else axis,
           *(["--appearance", appearance] if appearance else [])]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, check=False)
    if r.returncode != 0:
        return {"error": r.stderr.strip().splitlines()[-1:] or [f"exit {r.returncode}"]}
    return dict(json.loads(r.stdout.strip().splitlines()[-1]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--axes", default="default," + ",".join(AXES), help="rows (default: default and every axis)")
    ap.add_argument("--seeds", default="1,5,9", help="scene seeds: the subjects of every row")
    ap.add_argument("--takes", type=int, default=3, help="held-out takes spread over the list")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "out" / "bench_robustness"))
    ap.add_argument("--appearance", metavar="PATH|off", help="appearance network (default: the shipped one)")
    args = ap.parse_args()
    rows = [a.strip() for a in args.axes.split(",") if a.strip()]
    if unknown := [a for a in rows if a != "default" and a not in AXES]:
        raise SystemExit(f"unknown axis {unknown}; choose from default, {', '.join(AXES)}")
    seeds = [int(s) for s in args.seeds.split(",")]
    pick = held_out_spread(args.takes)
    root = mocap_root()
    cells = list(itertools.product(rows, pick, seeds))
    t0 = time.time()
    with ThreadPoolExecutor(args.jobs) as ex:
        runs = list(tqdm(ex.map(lambda c: _eval(root / c[1].path, c[2], c[0], args.frames, args.appearance), cells),
                         total=len(cells), desc="robustness", unit="run"))
    records = [{"axis": a, "take": e.path, "seed": s, **r} for (a, e, s), r in zip(cells, runs, strict=True)]
    # MPJPE and "within 10 cm" count the frames with a published pose: a row that loses frames (a false
    # ghost, the room learned again) shows it in "frames tracked" alone
    lines = ["| axis | runs | MPJPE cm (mean) | worst run cm | frames within 10 cm | frames tracked | stature error cm "
             "| what varied |", "|---|---|---|---|---|---|---|---|"]
    summary: dict[str, Any] = {}
    for a in rows:
        ok = [r for r in records if r["axis"] == a and r.get("mpjpe_cm") is not None]
        if not ok:
            lines.append(f"| {a} | 0 | - | - | - | - | - | failed |")
            continue
        mp = np.array([r["mpjpe_cm"] for r in ok])
        w10 = np.array([r["frames_within_10cm"] for r in ok])
        st = np.array([abs(r["body_height_m"] - r["subject_height_m"]) * 100 for r in ok])
        tracked = sum(int(r["tracked_frames"]) for r in ok) / max(sum(int(r["frames"]) for r in ok), 1)
        what = sorted({f"{r['subject']['group']}" for r in ok} | {r["scene"]["lights"] for r in ok} |
                      {f"{r['scene']['codec']}" for r in ok} - {"none", "default"})
        summary[a] = {"runs": len(ok), "mpjpe_cm": round(float(mp.mean()), 2), "worst_cm": round(float(mp.max()), 2),
                      "within_10cm": round(float(w10.mean()), 3), "tracked": round(tracked, 3),
                      "stature_error_cm": round(float(st.mean()), 1)}
        lines.append(f"| {a} | {len(ok)} | {mp.mean():.2f} | {mp.max():.2f} | {w10.mean():.3f} | {tracked:.3f} | "
                     f"{st.mean():.1f} | {', '.join(what)} |")
    out = Path(args.out)
    meta = bench_meta("bench_robustness.py", t0, seeds=seeds, takes=[e.path for e in pick], frames=args.frames)
    write_report(out, "robustness", {"meta": meta, "rows": summary, "runs": records}, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
