"""Side by side with MediaPipe Pose on the very same frames: held-out takes rendered by the synthetic
scene (optionally varied: :mod:`tracker_service.scene.variation`), tracked by this product from
pixels and by MediaPipe Pose 0.10.21 (BlazePose world landmarks), scored on the 12 joints both
report (shoulders, elbows, wrists, hips, knees, ankles).

Usage::

    make bench-peers                       # creates .venv-peers, then runs this with its defaults
    .venv/bin/python bench/bench_peers.py [--axes default,backdrop,...] [--seeds 1,5,9] [--takes N]
        [--frames N] [--complexity 0|1|2] [--out DIR]

Scoring, per frame where both produced a pose: the 12 joints relative to the point between the hips
(both methods' own), in the camera's axes (MediaPipe's world landmarks are roughly camera-aligned;
ours are turned into the camera's axes), mean distance to the truth (``mpjpe``); the same after
the rotation that best aligns each frame (``r_mpjpe``: MediaPipe's world frame is often turned by
tens of degrees, its hips sometimes nearly coincident; sizes still count); and after a similarity
Procrustes alignment (``pa_mpjpe``: shape only, no rotation, scale or offset error). ``found`` is
the fraction of frames where a method published a pose. Milliseconds are each method's own
per-frame time on this machine (ours: the steady-tracking pipeline; MediaPipe: ``Pose.process``),
measured in the same run.

MediaPipe needs ``numpy<2``, ``opencv-python-headless<4.12`` and ``protobuf<5``: it runs in its own
environment (``.venv-peers``, see the Makefile) through ``bench/peers/mediapipe_pose.py``; the
product's environment never installs it. Not a test: it takes minutes.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from _host import bench_meta, held_out_spread, write_report  # bench/ is the script's folder
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from protocol.formats.load import load_motion
from protocol.formats.mocap_data import mocap_root
from protocol.skeleton import JOINT_INDEX
from tracker_service.app.evaluate import EvalOptions, evaluate_motion
from tracker_service.app.options import TrackerOptions
from tracker_service.app.resources import ensure_db
from tracker_service.app.tracker_config import tracker_config
from tracker_service.pipeline.warmup import warm_up
from tracker_service.scene.variation import AXES

ROOT = Path(__file__).resolve().parent.parent
PEER_PYTHON = ROOT / ".venv-peers" / "bin" / "python"
PEER_SCRIPT = ROOT / "bench" / "peers" / "mediapipe_pose.py"

#: The 12 joints both report: ours by name, MediaPipe's by landmark index (the person's left/right).
COMMON = ("l_shoulder", "r_shoulder", "l_elbow", "r_elbow", "l_wrist", "r_wrist",
          "l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle")
MP_INDEX = np.array([11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28])
OURS = np.array([JOINT_INDEX[n] for n in COMMON])
HIPS = np.array([6, 7])  # l_hip, r_hip within COMMON


def procrustes(pred: np.ndarray, truth: np.ndarray, with_scale: bool = True) -> np.ndarray:
    """``pred`` (N, 3) aligned to ``truth`` by the similarity (or, without scale, the rigid)
    transform of least squares."""
    mp, mt = pred.mean(0), truth.mean(0)
    p, t = pred - mp, truth - mt
    u, s, vt = np.linalg.svd(p.T @ t)
    d = np.sign(np.linalg.det(u @ vt))
    fix = np.diag([1.0, 1.0, d])
    r = u @ fix @ vt
    scale = (s * np.diag(fix)).sum() / max((p ** 2).sum(), 1e-12) if with_scale else 1.0
    return scale * p @ r + mt


def _hip_relative(j: np.ndarray) -> np.ndarray:
    return j - j[HIPS].mean(axis=0)


def score(truth: list[np.ndarray], ours: list[np.ndarray | None], peer: list[np.ndarray | None]) -> dict[str, Any]:
    """Errors (cm) of both methods on the frames where both found the person; coverages."""
    both = [k for k in range(len(truth)) if ours[k] is not None and peer[k] is not None]
    out: dict[str, Any] = {"frames": len(truth), "both": len(both),
                           "found_ours": round(sum(o is not None for o in ours) / max(len(truth), 1), 3),
                           "found_mediapipe": round(sum(p is not None for p in peer) / max(len(truth), 1), 3)}
    for name, preds in (("ours", ours), ("mediapipe", peer)):
        e, ra, pa = [], [], []
        for k in both:
            t, p = _hip_relative(truth[k]), _hip_relative(preds[k])  # type: ignore[arg-type]
            e.append(np.linalg.norm(p - t, axis=1).mean())
            ra.append(np.linalg.norm(procrustes(p, t, with_scale=False) - t, axis=1).mean())
            pa.append(np.linalg.norm(procrustes(p, t) - t, axis=1).mean())
        for key, v in (("mpjpe", e), ("r_mpjpe", ra), ("pa_mpjpe", pa)):
            out[f"{key}_{name}"] = round(float(np.mean(v)) * 100, 2) if v else None
    return out


def run_cell(loaded: Any, cfg: Any, bvh: Path, seed: int, axis: str, frames: int, folder: Path,
             complexity: int) -> dict[str, Any]:
    """Render, track with ours (saving the frames), run MediaPipe on the same frames, score."""
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    cam_rot = loaded.camera.pose[:3, :3]
    truth: list[np.ndarray] = []
    ours: list[np.ndarray | None] = []

    def observe(fr: Any, _state: Any, res: Any) -> None:
        if not fr.truth.present:
            return
        cv2.imwrite(str(folder / f"frame_{len(truth):04d}.png"), fr.image)
        truth.append(fr.truth.joints[OURS] @ cam_rot)  # camera axes: x right, y up, z toward the camera
        ours.append(None if res.joints is None else np.asarray(res.joints)[OURS] @ cam_rot)

    motion = load_motion(bvh, fps=30.0)
    options = EvalOptions(frames=frames, seed=seed, variation=() if axis == "default" else (axis,))
    result = evaluate_motion(motion, loaded, cfg, options, observe=observe)
    r = subprocess.run([str(PEER_PYTHON), str(PEER_SCRIPT), str(folder), "--complexity", str(complexity)],
                       capture_output=True, text=True, check=False)
    if r.returncode != 0:
        raise RuntimeError(f"MediaPipe failed on {folder}: {r.stderr.strip()[-400:]}")
    mp_out = json.loads((folder / "mediapipe.json").read_text())
    flip = np.array([1.0, -1.0, -1.0])  # MediaPipe: y down, z away from the camera
    peer = [None if f["world"] is None else np.asarray(f["world"])[MP_INDEX] * flip for f in mp_out["frames"]]
    cell = score(truth, ours, peer)
    cell.update({"axis": axis, "take": bvh.name, "seed": seed,
                 "ms_ours": result["ms_per_frame"]["total"], "ms_mediapipe": round(float(np.mean(
                     [f["ms"] for f in mp_out["frames"][1:]] or [np.nan])), 2), "peer_model": mp_out["model"]})
    for png in folder.glob("frame_*.png"):
        png.unlink()
    return cell


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--axes", default="default,backdrop,lights,clothing,body",
                    help=f"rows: default and/or axes of {', '.join(AXES)}")
    ap.add_argument("--seeds", default="1,5,9", help="scene seeds (subjects) of every row")
    ap.add_argument("--takes", type=int, default=3, help="held-out takes spread over the list")
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--complexity", type=int, default=1, choices=(0, 1, 2), help="MediaPipe's model (default 1)")
    ap.add_argument("--out", default=str(ROOT / "out" / "bench_peers"))
    args = ap.parse_args()
    if not PEER_PYTHON.exists():
        raise SystemExit("no .venv-peers: run `make bench-peers` (it creates the MediaPipe environment)")
    rows = [a.strip() for a in args.axes.split(",") if a.strip()]
    if unknown := [a for a in rows if a != "default" and a not in AXES]:
        raise SystemExit(f"unknown axis {unknown}; choose from default, {', '.join(AXES)}")
    seeds = [int(s) for s in args.seeds.split(",")]
    pick = held_out_spread(args.takes)
    loaded = ensure_db(None)
    cfg = tracker_config(TrackerOptions())
    out = Path(args.out)
    t0 = time.time()
    cells = []
    with threadpool_limits(1):  # the tracker on one core, as mocap-tracker runs it
        warm_up(loaded.db, loaded.body, loaded.camera, cfg)
        todo = [(a, e, s) for a in rows for e in pick for s in seeds]
        out.mkdir(parents=True, exist_ok=True)
        with (out / "peers_runs.jsonl").open("w") as log:  # every run as it ends (a crash keeps them)
            for a, e, s in tqdm(todo, desc="peers", unit="run"):
                cells.append(run_cell(loaded, cfg, mocap_root() / e.path, s, a, args.frames,
                                      out / f"{a}_{Path(e.path).stem}_{s}", args.complexity))
                log.write(json.dumps(cells[-1]) + "\n")
                log.flush()
    lines = ["| row | runs | MPJPE cm ours / MediaPipe | rigidly aligned ours / MediaPipe | "
             "PA-MPJPE ours / MediaPipe | runs ours lower (rigid) | found ours / MediaPipe | ms ours / MediaPipe |",
             "|---|---|---|---|---|---|---|---|"]
    summary: dict[str, Any] = {}
    for a in rows:
        c = [x for x in cells if x["axis"] == a and x["mpjpe_ours"] is not None]
        if not c:
            lines.append(f"| {a} | 0 | - | - | - | - | - | - |")
            continue

        def m(key: str, cs: list[dict[str, Any]] = c) -> float:
            return float(np.mean([x[key] for x in cs]))
        wins = sum(x["r_mpjpe_ours"] < x["r_mpjpe_mediapipe"] for x in c)
        ms_ours = float(np.nanmean([x["ms_ours"]["avg"] for x in c]))
        keys = [f"{e}_{w}" for e in ("mpjpe", "r_mpjpe", "pa_mpjpe") for w in ("ours", "mediapipe")]
        summary[a] = {k: round(m(k), 2) for k in (*keys, "found_ours", "found_mediapipe", "ms_mediapipe")} | {
            "ours_lower_rigid": f"{wins}/{len(c)}", "ms_ours": round(ms_ours, 2)}
        lines.append(f"| {a} | {len(c)} | {m('mpjpe_ours'):.2f} / {m('mpjpe_mediapipe'):.2f} | "
                     f"{m('r_mpjpe_ours'):.2f} / {m('r_mpjpe_mediapipe'):.2f} | "
                     f"{m('pa_mpjpe_ours'):.2f} / {m('pa_mpjpe_mediapipe'):.2f} | {wins}/{len(c)} | "
                     f"{m('found_ours'):.2f} / {m('found_mediapipe'):.2f} | {ms_ours:.1f} / {m('ms_mediapipe'):.1f} |")
    meta = bench_meta("bench_peers.py", t0, seeds=seeds, takes=[e.path for e in pick], frames=args.frames)
    write_report(out, "peers", {"meta": meta, "rows": summary, "runs": cells}, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
