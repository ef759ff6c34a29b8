"""Does the published confidence mean something? Its rank correlation with each frame's joint error.

Held-out takes tracked from pixels (``mocap-tracker eval``'s path, the shipped network); for every
published pose the frame's MPJPE (root-relative, cm) and the pose's ``confidence``. Reports
Spearman's rank correlation pooled over all frames and within each run (negative: the confidence
falls where the pose is wrong), and the error by confidence band.

    .venv/bin/python bench/bench_confidence.py --takes 12 --seeds 3,11 --frames 90
"""

from __future__ import annotations

import argparse
import logging
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from _host import bench_meta, held_out_spread, write_report
from scipy.stats import spearmanr
from tqdm import tqdm

from protocol.formats.load import load_motion
from protocol.formats.mocap_data import mocap_root
from tracker_service.app.evaluate import evaluate_motion
from tracker_service.app.options import EvalOptions, TrackerOptions
from tracker_service.app.resources import ensure_db
from tracker_service.app.tracker_config import tracker_config

ROOT = Path(__file__).resolve().parent.parent
BANDS = ((0.0, 0.3), (0.3, 0.6), (0.6, 0.8), (0.8, 1.0001))


def _frames(take: str, seed: int, frames: int, loaded: Any, cfg: Any) -> list[tuple[float, float]]:
    """``(confidence, error cm)`` of every published pose of one run."""
    rows: list[tuple[float, float]] = []

    def observe(fr: Any, st: Any, res: Any) -> None:
        if res.joints is None or not fr.truth.present:
            return
        t, e = fr.truth.joints, res.joints
        err = float(np.mean(np.linalg.norm((e - e[0]) - (t - t[0]), axis=1))) * 100.0
        rows.append((float(res.confidence), err))

    motion = load_motion(str(mocap_root() / take), fps=30.0)
    evaluate_motion(motion, loaded, cfg, replace(EvalOptions(), seed=seed, frames=frames), observe=observe)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--takes", type=int, default=12, help="held-out takes spread over the list")
    ap.add_argument("--seeds", default="3,11", help="scene seeds (the people)")
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--out", default=str(ROOT / "out" / "bench_confidence"))
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    t0 = time.time()
    options = TrackerOptions()
    loaded = ensure_db(options.db)
    cfg = tracker_config(options)
    seeds = [int(s) for s in args.seeds.split(",")]
    cells = [(e.path, s) for e in held_out_spread(args.takes) for s in seeds]
    runs = {f"{t} seed {s}": _frames(t, s, args.frames, loaded, cfg)
            for t, s in tqdm(cells, desc="confidence", unit="run")}
    within = [float(spearmanr(*np.array(r).T).statistic) for r in runs.values()
              if len(r) >= 10 and np.ptp(np.array(r)[:, 0]) > 0]
    conf, err = np.array([x for r in runs.values() for x in r]).T
    pooled = float(spearmanr(conf, err).statistic)
    bands = []
    for lo, hi in BANDS:
        sel = (conf >= lo) & (conf < hi)
        bands.append({"band": [lo, min(hi, 1.0)], "frames": round(float(sel.mean()), 3),
                      "mpjpe_cm": round(float(err[sel].mean()), 2) if sel.any() else None,
                      "within_10cm": round(float(np.mean(err[sel] < 10)), 3) if sel.any() else None})
    lines = [f"Spearman (confidence, error): pooled {pooled:+.2f} over {len(err)} frames; within a run "
             f"mean {np.mean(within):+.2f}, negative in {sum(w < 0 for w in within)} of {len(within)} runs", "",
             "| confidence | frames | MPJPE cm | within 10 cm |", "|---|---|---|---|"]
    lines += [f"| {b['band'][0]:.1f}–{b['band'][1]:.1f} | {b['frames']:.2f} | {b['mpjpe_cm']} | {b['within_10cm']} |"
              for b in bands]
    report = {"meta": bench_meta("bench_confidence.py", t0), "pooled_spearman": round(pooled, 3),
              "within_run_spearman": [round(w, 3) for w in within], "bands": bands}
    write_report(Path(args.out), "confidence", report, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
