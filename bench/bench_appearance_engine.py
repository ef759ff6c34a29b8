"""The appearance network's two implementations on the same crops: OpenCV's DNN engine (what the
tracker runs, :mod:`tracker_service.cues.appearance_engine`) against the numpy reference (im2col +
BLAS, :func:`tracker_service.cues.appearance.forward`), one thread each.

Usage::

    .venv/bin/python bench/bench_appearance_engine.py [--frames N] [--repeats R] [--json]

Crops of the synthetic scene's person (a held-out take, the true silhouette), both views (the crop
and its mirror) through every network of the shipped ensemble, as ``predict_joints`` runs them;
the two implementations alternate frame by frame, so that the machine's load falls on both alike.
Prints per implementation the milliseconds a frame (min / median / p99), their ratio, and the
largest difference between their outputs. Not a test.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # one thread each, as mocap-tracker runs them
os.environ.setdefault("OPENCV_FOR_THREADS_NUM", "1")

import argparse  # (the thread settings above must precede numpy and cv2)
import json
import time
from typing import Any

import numpy as np
from _host import bench_meta, held_out_spread  # bench/ is the script's folder

from protocol.formats.load import load_motion
from protocol.formats.mocap_data import mocap_root
from tracker_service.cues.appearance import (
    forward,
    load_appearance,
    net_input,
    person_crop,
    shipped_appearance_path,
)
from tracker_service.scene.synthetic import SceneConfig, SyntheticScene


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--repeats", type=int, default=5, help="passes over the frames")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    t0 = time.time()
    path = shipped_appearance_path()
    if path is None:
        raise SystemExit("no shipped appearance network")
    net = load_appearance(path)
    take = held_out_spread(1)[0]
    with SyntheticScene(load_motion(mocap_root() / take.path, fps=30.0), seed=1,
                        config=SceneConfig(fps=30.0)) as scene:
        frames = [scene.frame(i) for i in range(min(args.frames, scene.n_frames))]
    views = []
    for fr in frames:
        c = person_crop(fr.image, fr.truth.silhouette, net.size)
        if c is not None:
            x = net_input(*c)
            views.append(np.stack([x, x[:, ::-1]]))
    engine = net.engine
    engine.forward(views[0])  # compile the model before the clock starts
    t_engine, t_numpy, diff = [], [], 0.0
    for _ in range(args.repeats):
        for v in views:
            a = time.perf_counter()
            fast = engine.forward(v)
            b = time.perf_counter()
            ref = [forward(net, v, k) for k in range(len(net.networks))]
            c_ = time.perf_counter()
            t_engine.append((b - a) * 1e3)
            t_numpy.append((c_ - b) * 1e3)
            diff = max(diff, max(float(np.abs(f - r).max()) for f, r in zip(fast, ref, strict=True)))

    # multiply-adds of one view through every network: what bounds the pass is arithmetic
    flops, side = 0.0, net.size
    for layers in net.networks:
        side = net.size
        for lay in layers:
            if lay.kind == "conv":
                side = (side - 1) // lay.stride + 1
                flops += 2.0 * side * side * lay.matrix.shape[0] * lay.matrix.shape[1]
                side = side // 2 if lay.pool else side
            else:
                flops += 2.0 * lay.matrix.shape[0] * lay.matrix.shape[1]
    flops *= 2  # both views

    def stats(t: list[float]) -> dict[str, float]:
        return {"min": round(min(t), 3), "median": round(float(np.median(t)), 3),
                "p99": round(float(np.percentile(t, 99)), 3)}

    meta = bench_meta("bench_appearance_engine.py", t0, take=take.path, networks=len(net.networks), views_per_frame=2)
    result: dict[str, Any] = {"meta": meta,
              "frames": len(views), "engine_ms": stats(t_engine), "numpy_ms": stats(t_numpy),
              "ratio_median": round(float(np.median(t_numpy) / np.median(t_engine)), 2),
              "mflop_per_frame": round(flops / 1e6, 1),
              "gflop_per_s": {"engine": round(flops / np.median(t_engine) / 1e6, 1),
                              "numpy": round(flops / np.median(t_numpy) / 1e6, 1)},
              "max_abs_difference": diff}
    if args.json:
        print(json.dumps(result))
    else:
        for k in ("engine_ms", "numpy_ms"):
            s = result[k]
            print(f"{k:10s} min {s['min']:.2f}  median {s['median']:.2f}  p99 {s['p99']:.2f} ms a frame")
        print(f"numpy / engine (median): {result['ratio_median']}x; largest output difference {diff:.2e}")
        g = result["gflop_per_s"]
        print(f"{result['mflop_per_frame']} MFLOP a frame: engine {g['engine']} GFLOP/s, numpy {g['numpy']} GFLOP/s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
