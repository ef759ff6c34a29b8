"""The camera's placement measured from its own frames (no calibration file): tilt and roll from
the room's vertical edges, height from the person standing in the first frames
(:mod:`tracker_service.pipeline.camera_estimate`), against the camera that filmed the synthetic scene.

Usage::

    .venv/bin/python bench/bench_camera_estimate.py [--seeds 1,5,9] [--vary AXES] [--out DIR]

For each placement and seed: 10 empty-room frames give the background (its vertical edges give the
tilt and roll), then the person of ``protocol/scripts/step_aside.toml`` stands still for half a
second (the silhouette's top and bottom rows give the height, once with the subject's true
stature, once with the assumed 1.70 m). Writes ``camera_estimate.md`` and ``camera_estimate.json``
to ``--out`` (default ``out/bench_camera_estimate``). Not a test: it takes a minute or two.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
from _host import bench_meta, write_report  # bench/ is the script's folder
from tqdm import tqdm

from protocol.formats.load import load_motion
from tracker_service.camera import placed_camera
from tracker_service.pipeline.camera_estimate import ASSUMED_STATURE_M, camera_height, level_tilt, vertical_segments
from tracker_service.scene.synthetic import SceneConfig, SyntheticScene
from tracker_service.scene.variation import parse_axes
from tracker_service.silhouette.background import learn_background, subtract

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "protocol" / "scripts" / "step_aside.toml"
#: (height m, tilt deg down, horizontal field of view deg or None, distance m)
PLACEMENTS: list[tuple[float, float, float | None, float]] = [
    (1.2, 0.0, None, 3.0), (1.8, 15.0, None, 3.0), (0.8, -5.0, None, 3.0), (0.6, -10.0, None, 3.0),
    (1.5, 10.0, 70.0, 3.0), (1.8, 20.0, 80.0, 2.5), (1.2, 0.0, 50.0, 4.5), (1.2, 5.0, 80.0, 2.0)]
EMPTY, STAND = 10, 12


def _one(height: float, tilt: float, fov: float | None, dist: float, seed: int, vary: tuple[str, ...]
         ) -> dict[str, Any]:
    cam = placed_camera(height_m=height, tilt_deg=tilt, hfov_deg=fov, distance_m=dist)
    motion = load_motion(SCRIPT, fps=30.0)
    with SyntheticScene(motion, seed=seed, config=SceneConfig(fps=30.0, empty_prefix=EMPTY, camera=cam,
                                                             variation=vary)) as scene:
        frames = [scene.frame(i) for i in range(EMPTY + STAND)]
        stature = float(scene.subject.spec.height)
    bg = learn_background(np.stack([f.image for f in frames[:EMPTY]]))
    segs = vertical_segments(bg.bright_mean)
    t, r = level_tilt(segs, cam)
    rows = []
    for f in frames[EMPTY:]:
        ys = np.nonzero(subtract(bg, f.image).any(axis=1))[0]
        if len(ys):
            rows.append((float(ys.max()) + 0.5, float(ys.min()) - 0.5))  # pixel edges: soles, head top
    feet, head = np.median(np.array(rows), axis=0) if rows else (math.nan, math.nan)
    h_true = camera_height(feet, head, cam, t, stature) if math.isfinite(t) else math.nan
    h_assumed = camera_height(feet, head, cam, t, ASSUMED_STATURE_M) if math.isfinite(t) else math.nan
    return {"height_m": height, "tilt_deg": tilt, "fov_deg": fov or round(cam.hfov_deg, 1), "distance_m": dist,
            "seed": seed, "segments": len(segs), "tilt_est": t, "roll_est": r, "stature_m": stature,
            "height_est_true_stature": h_true, "height_est_assumed_stature": h_assumed}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1,5,9")
    ap.add_argument("--vary", default="", help="domain-randomisation axes of the scene (eval --vary)")
    ap.add_argument("--out", default=str(ROOT / "out" / "bench_camera_estimate"))
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    vary = parse_axes(args.vary)
    t0 = time.time()
    cells = [(k, s) for k in range(len(PLACEMENTS)) for s in seeds]
    runs = []
    for k, s in tqdm(cells, desc="camera estimate", unit="run"):
        height, tilt, fov, dist = PLACEMENTS[k]
        runs.append({"placement": k, **_one(height, tilt, fov, dist, s, vary)})
    lines = ["| camera (height, tilt, lens, distance) | runs | tilt error ° (max) | roll error ° (max) | height error, "
             "true stature cm (max) | height error, 1.70 m assumed cm (max) | vertical edges |",
             "|---|---|---|---|---|---|---|"]
    summary: list[dict[str, Any]] = []
    for k, p in enumerate(PLACEMENTS):
        rs = [r for r in runs if r["placement"] == k]
        te = np.array([abs(r["tilt_est"] - r["tilt_deg"]) for r in rs])
        re = np.array([abs(r["roll_est"]) for r in rs])
        he = np.array([abs(r["height_est_true_stature"] - r["height_m"]) * 100 for r in rs])
        ha = np.array([abs(r["height_est_assumed_stature"] - r["height_m"]) * 100 for r in rs])
        row: dict[str, Any] = {"camera": f"{p[0]} m, {p[1]:+.0f}°, {rs[0]['fov_deg']}° lens, {p[3]} m", "runs": len(rs),
               "tilt_err_max": float(np.nanmax(te)) if np.isfinite(te).any() else None,
               "roll_err_max": float(np.nanmax(re)) if np.isfinite(re).any() else None,
               "height_err_cm_max": float(np.nanmax(he)) if np.isfinite(he).any() else None,
               "height_err_assumed_cm_max": float(np.nanmax(ha)) if np.isfinite(ha).any() else None,
               "segments": [r["segments"] for r in rs]}
        summary.append(row)

        def f(v: float | None, nd: int = 1) -> str:
            return "-" if v is None else f"{v:.{nd}f}"
        lines.append(f"| {row['camera']} | {len(rs)} | {f(row['tilt_err_max'])} | {f(row['roll_err_max'])} | "
                     f"{f(row['height_err_cm_max'])} | {f(row['height_err_assumed_cm_max'])} | "
                     f"{', '.join(str(n) for n in row['segments'])} |")
    meta = bench_meta("bench_camera_estimate.py", t0, seeds=seeds, vary=list(vary))
    write_report(Path(args.out), "camera_estimate", {"meta": meta, "rows": summary, "runs": runs}, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
