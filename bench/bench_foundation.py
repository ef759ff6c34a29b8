"""Foundation benchmarks: FK throughput, reading + retargeting every shared recording, pose pruning.

Usage::

    .venv/bin/python bench/bench_foundation.py [--json]

Prints one line per figure (and a JSON object with --json). Not a test: timings depend on the
machine and its load; run it on a quiet machine and copy the figures into docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np
from tqdm import tqdm

from protocol import POSE_SIZE, default_body, fk
from protocol.formats.bvh import read_bvh
from protocol.formats.load import load_motion
from protocol.formats.mocap_data import index_entries, mocap_root
from tracker_service.templates.pruning import prune_poses


def _best_of(fn, repeats: int = 5) -> float:  # type: ignore[no-untyped-def]
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print a JSON object instead of text")
    args = ap.parse_args()
    res: dict[str, object] = {"machine": f"{platform.node()} {platform.processor() or platform.machine()}",
                              "python": platform.python_version()}
    rng = np.random.default_rng(0)
    body = default_body()
    for n in (1, 100, 10_000):
        poses = rng.normal(0, 0.4, (n, POSE_SIZE))
        dt = _best_of(lambda p=poses: fk(p, body))
        res[f"fk_poses_per_s_batch_{n}"] = round(n / dt)
    root = mocap_root()
    entries = index_entries()
    t0 = time.perf_counter()
    for e in tqdm(entries, desc="parse BVH", disable=args.json):
        read_bvh(root / e.path)
    res["bvh_parse_all_s"] = round(time.perf_counter() - t0, 2)
    t0 = time.perf_counter()
    motions = [load_motion(root / e.path) for e in tqdm(entries, desc="read+retarget", disable=args.json)]
    res["read_retarget_all_s"] = round(time.perf_counter() - t0, 2)
    poses = np.concatenate([m.poses[m.valid] for m in motions])
    res["frames_all"] = len(poses)
    prune_poses(poses[:100])  # numba compile/cache load outside the timing
    r = prune_poses(poses, 5.0)
    res["prune_5deg_kept"] = r.n_kept
    res["prune_5deg_s"] = round(r.seconds, 2)
    at30 = np.concatenate([m.poses[m.valid][:: max(1, round(m.fps / 30))] for m in motions])
    r30 = prune_poses(at30, 5.0)
    res["frames_all_at_30hz"] = len(at30)
    res["prune_5deg_kept_at_30hz"] = r30.n_kept
    if args.json:
        print(json.dumps(res))
    else:
        for k, v in res.items():
            print(f"{k:32s} {v}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
