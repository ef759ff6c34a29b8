"""The tracker on cameras placed elsewhere than the default one, with the appearance cue and without.

Held-out takes filmed by a camera of another height, tilt, lens or distance, the tracker told that
camera (``mocap-tracker eval --camera FILE``'s path, the file written to ``--out``: templates
rendered for it, built once per camera and cached in ``out/db``). Each placement is tracked with the
shipped network (its reading turned into the camera's axes, :mod:`tracker_service.cues.level_frame`)
and with the silhouettes alone (``--appearance off``); the default camera is the reference.

    .venv/bin/python bench/bench_camera_placements.py --takes 6 --seed 7 --frames 90

Writes ``camera_placements.md`` and ``.json`` to ``--out`` (default ``out/bench_camera_placements``).
A new placement builds its database first (1.5–3 minutes); then ~1.5 minutes a take and placement.
"""

from __future__ import annotations

import argparse
import logging
import math
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from _host import bench_meta, held_out_spread, write_report  # bench/ is the script's folder
from tqdm import tqdm

from protocol.formats.load import load_motion
from protocol.formats.mocap_data import mocap_root
from tracker_service.app.evaluate import evaluate_motion
from tracker_service.app.options import EvalOptions, TrackerOptions
from tracker_service.app.resources import ensure_db, requested_camera
from tracker_service.app.tracker_config import tracker_config
from tracker_service.camera import Camera, placed_camera, save_camera_file
from tracker_service.cues.appearance import appearance_unfit

ROOT = Path(__file__).resolve().parent.parent
Placement = tuple[float, float, float | None, float, float, float]
#: (height m, tilt deg down, horizontal field of view deg or None, distance m, roll deg, yaw deg) of
#: the placements measured; the first is the default camera. A yaw turns the camera away from the
#: person about the vertical: they stand that far right of the image's centre.
PLACEMENTS: list[Placement] = [
    (1.2, 0.0, None, 3.0, 0.0, 0.0), (1.8, 15.0, None, 3.0, 0.0, 0.0), (0.8, -5.0, None, 3.0, 0.0, 0.0),
    (0.6, -10.0, None, 3.0, 0.0, 0.0), (1.8, 20.0, 80.0, 2.5, 0.0, 0.0), (1.2, 0.0, None, 3.0, 10.0, 0.0),
    (1.5, 10.0, None, 3.0, 8.0, 0.0), (1.2, 0.0, None, 3.0, 0.0, 15.0)]


def _label(height: float, tilt: float, fov: float | None, dist: float, roll: float, yaw: float) -> str:
    turn = "level" if tilt == 0 else (f"{tilt:g} deg down" if tilt > 0 else f"{-tilt:g} deg up")
    return (f"{height:g} m, {turn}" + (f", rolled {roll:g} deg" if roll else "")
            + (f", the person {yaw:g} deg right of centre" if yaw else "")
            + (f", {fov:g} deg lens at {dist:g} m" if fov else ""))


def _camera(height: float, tilt: float, fov: float | None, dist: float, roll: float, yaw: float) -> Camera:
    """:func:`placed_camera`, turned by ``roll`` degrees about its optical axis and then by ``yaw``
    about the vertical through its centre."""
    cam = placed_camera(height_m=height, tilt_deg=tilt, hfov_deg=fov, distance_m=dist)
    a, b = math.radians(roll), math.radians(yaw)
    turn = np.eye(4)
    turn[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    pose = cam.pose @ turn
    pose[:3, :3] = np.array([[math.cos(b), 0.0, math.sin(b)], [0.0, 1.0, 0.0],
                             [-math.sin(b), 0.0, math.cos(b)]]) @ pose[:3, :3]
    return cam.moved(pose)


def _run(placement: Placement, takes: list[Any], seed: int, frames: int, out: Path) -> dict[str, Any]:
    height, tilt, fov, dist, roll, yaw = placement
    base = TrackerOptions()
    if placement != PLACEMENTS[0]:
        path = out / f"camera_{height:g}m_{tilt:g}deg_{fov or 0:g}_{dist:g}m_{roll:g}roll_{yaw:g}yaw.json"
        save_camera_file(_camera(*placement), path)
        base = TrackerOptions(camera_file=str(path))
    camera = requested_camera(base)
    loaded = ensure_db(None) if camera is None else ensure_db(None, camera=camera)
    row: dict[str, Any] = {"placement": _label(*placement), "height_m": height, "tilt_deg": tilt,
                           "fov_deg": fov, "distance_m": dist, "roll_deg": roll, "yaw_deg": yaw,
                           "cue_unfit": appearance_unfit(loaded.camera), "takes": {}}
    configs = {"cue": tracker_config(base), "silhouettes": tracker_config(replace(base, appearance="off"))}
    for name, cfg in configs.items():
        row[f"{name}_on"] = cfg.appearance is not None
    opts = EvalOptions(frames=frames, seed=seed, camera=camera)
    for e in tqdm(takes, desc=row["placement"], unit="take", leave=False):
        motion = load_motion(str(mocap_root() / e.path), fps=30.0)
        row["takes"][e.path] = {name: evaluate_motion(motion, loaded, cfg, opts)["mpjpe_cm"]
                                for name, cfg in configs.items()}
    for name in configs:
        row[f"{name}_mpjpe_cm"] = round(float(np.mean([t[name] for t in row["takes"].values()])), 2)
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--takes", type=int, default=6, help="held-out takes spread over the list")
    ap.add_argument("--seed", type=int, default=7, help="the scene's seed (the person, the room)")
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--placements", default="", help="indices into PLACEMENTS, comma-separated (default: all)")
    ap.add_argument("--out", default=str(ROOT / "out" / "bench_camera_placements"))
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    t0 = time.time()
    takes = held_out_spread(args.takes)
    chosen = [PLACEMENTS[int(k)] for k in args.placements.split(",")] if args.placements else PLACEMENTS
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = [_run(p, takes, args.seed, args.frames, out) for p in tqdm(chosen, desc="placements", unit="camera")]
    ref = next((r for r in rows if r["placement"] == _label(*PLACEMENTS[0])), None)
    lines = [f"{len(takes)} held-out takes, seed {args.seed}, {args.frames} frames: MPJPE", "",
             "| camera | with the cue | silhouettes alone | cue on / off vs the default camera's cue |",
             "|---|---|---|---|"]
    for r in rows:
        d = "" if ref is None else (f"{r['cue_mpjpe_cm'] - ref['cue_mpjpe_cm']:+.2f} / "
                                    f"{r['silhouettes_mpjpe_cm'] - ref['cue_mpjpe_cm']:+.2f}")
        cue = f"{r['cue_mpjpe_cm']:.2f} cm" + ("" if r["cue_on"] else " (cue off: " + str(r["cue_unfit"]) + ")")
        lines.append(f"| {r['placement']} | {cue} | {r['silhouettes_mpjpe_cm']:.2f} cm | {d} |")
    write_report(out, "camera_placements", {"meta": bench_meta("bench_camera_placements.py", t0), "runs": rows}, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
