"""What a watching viewer (``mocap-view``) costs the tracker: the preview frame's work per frame.

While a viewer subscribes to ``mocap/tracker/<id>/preview``, the daemon draws the overlay on the
camera frame (silhouette, skeleton, HUD), encodes it as a JPEG and packs a ``PreviewFrame``
(``tracker_service.app.daemon.preview_payload``) at most ``PREVIEW_HZ`` times a second; an
unwatched tracker does none of it. This bench tracks a held-out take from pixels, keeps every
frame with its result, then times ``preview_payload`` on each of them on one core and reports the
milliseconds per preview and, spread over the tracker's frames at 30 frames a second, per frame
(the issue's target: a viewer adds at most 1 ms to the tracker's frame time). Not a test.

Usage::

    .venv/bin/python bench/bench_preview.py [--frames 90] [--seed 7] [--repeats 5] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from typing import Any

import numpy as np
from _host import bench_meta, held_out_spread, host_probe  # bench/ is the script's folder
from threadpoolctl import threadpool_limits

from protocol.formats.load import load_motion
from protocol.formats.mocap_data import recording_path
from tracker_service.app.daemon import PREVIEW_HZ, preview_payload
from tracker_service.app.evaluate import evaluate_motion
from tracker_service.app.options import EvalOptions, TrackerOptions
from tracker_service.app.resources import ensure_db
from tracker_service.app.tracker_config import tracker_config


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=90, help="frames of the take tracked")
    ap.add_argument("--seed", type=int, default=7, help="synthetic scene seed (the subject)")
    ap.add_argument("--repeats", type=int, default=5, help="times every kept frame is encoded")
    ap.add_argument("--fps", type=float, default=30.0, help="the tracker's frame rate the cost is spread over")
    ap.add_argument("--cpu", type=int, default=0, help="pin to this CPU (-1: do not pin)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    t0 = time.time()
    threadpool_limits(1, user_api="blas")
    if args.cpu >= 0:
        os.sched_setaffinity(0, {args.cpu})
    loaded = ensure_db(None)
    cfg = tracker_config(TrackerOptions())
    entry = held_out_spread(12)[2]
    motion = load_motion(recording_path(entry.path), fps=30.0)
    kept: list[tuple[Any, Any, float]] = []
    evaluate_motion(motion, loaded, cfg, EvalOptions(seed=args.seed, frames=args.frames),
                    observe=lambda fr, _st, res: kept.append((fr.image, res, fr.timestamp)))
    tracked = [k for k in kept if k[1].joints is not None]
    if not tracked:
        raise SystemExit(f"no frame of {entry.path} was tracked: nothing to draw a preview of")
    times, sizes = [], []
    for _ in range(args.repeats):
        for image, res, ts in tracked:
            t = time.perf_counter()
            payload = preview_payload("bench", 0, ts, image, loaded.camera, res, 30.0)
            times.append((time.perf_counter() - t) * 1e3)
            sizes.append(len(payload or b""))
    ms = np.asarray(times)
    per_frame = float(ms.mean()) * min(PREVIEW_HZ, args.fps) / args.fps
    report = {"take": entry.path, "frames": len(tracked), "preview_hz": PREVIEW_HZ,
              "ms_per_preview": {"mean": round(float(ms.mean()), 3), "p99": round(float(np.percentile(ms, 99)), 3),
                                 "max": round(float(ms.max()), 3)},
              "ms_per_tracker_frame": round(per_frame, 3), "tracker_fps": args.fps,
              "preview_bytes_mean": round(float(np.mean(sizes))), "host_probe_s": host_probe(),
              "meta": bench_meta("bench_preview.py", t0, seed=args.seed)}
    if args.json:
        print(json.dumps(report))
    else:
        print(f"{report['frames']} frames of {entry.path}: {report['ms_per_preview']['mean']} ms a preview "
              f"(p99 {report['ms_per_preview']['p99']}), {report['preview_bytes_mean']} bytes; at "
              f"{PREVIEW_HZ:g} previews a second over {args.fps:g} frames a second: "
              f"{report['ms_per_tracker_frame']} ms a tracker frame")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
