"""Benchmark of the renderers: fast capsule silhouettes (masks, labelled masks, runs), the OpenCV
polygon variant, pyrender mesh silhouettes, their agreement (IoU), and synthetic-scene frames/s.

Usage::

    .venv/bin/python bench/bench_render.py [--poses 2000] [--scene-frames 150] [--json]

Poses are drawn from the 5-degree pruned database of a few shared recordings, turned to random
headings, and rendered for all 30 body models in turn at 320x240. Numbers are wall-clock on this
machine (the load average before and after is printed: the machine may be shared); the scene also
reports its CPU time per frame (all threads of the process, including the software rasteriser's).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from protocol.formats.load import load_motion
from protocol.formats.mocap_data import mocap_root
from protocol.kinematics import fk
from protocol.rotations import matrix_to_rotvec, rotvec_to_matrix
from tracker_service.body.family import BODY_MODELS, body_model
from tracker_service.body.mesh import BodyMesh
from tracker_service.body.raster import (
    render_labels,
    render_silhouette,
    render_silhouette_cv2,
    render_silhouettes,
    silhouette_runs_batch,
)
from tracker_service.camera import default_camera
from tracker_service.scene.gl import MeshRasterizer
from tracker_service.scene.synthetic import SceneConfig, SyntheticScene
from tracker_service.templates.pruning import prune_poses

RECORDINGS = ("bandai/dataset-1_dance-short_normal_001.bvh", "bandai/dataset-1_kick_normal_001.bvh",
              "bandai/dataset-1_slash_normal_001.bvh", "bandai/dataset-1_punch_normal_002.bvh")
SCENE_MOTION = "bandai/dataset-1_dance-short_normal_001.bvh"


def database_poses(n: int, seed: int = 0) -> np.ndarray:
    poses = np.concatenate([load_motion(mocap_root() / f).poses for f in RECORDINGS])
    kept = poses[prune_poses(poses, 5.0).kept]
    rng = np.random.default_rng(seed)
    p = kept[rng.choice(len(kept), n, replace=n > len(kept))].copy()
    p[:, [0, 2]] = 0.0
    yaw = rng.uniform(-np.pi, np.pi, n)
    ry = rotvec_to_matrix(np.stack([np.zeros(n), yaw, np.zeros(n)], axis=1))
    p[:, 3:6] = matrix_to_rotvec(ry @ rotvec_to_matrix(p[:, 3:6]))
    return p


def rate(fn: Any, n: int, repeat: int = 3) -> float:
    """Best of ``repeat`` runs of ``fn()`` (which does ``n`` items), items per second."""
    fn()  # warm up (numba compilation, GL uploads)
    best = min(_timed(fn) for _ in range(repeat))
    return n / best


def _timed(fn: Any) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def bench_fast(poses: np.ndarray) -> dict[str, float]:
    cam = default_camera()
    body = body_model("mMA").body
    joints = fk(poses, body)
    radii = body.capsule_radii
    n = len(joints)
    out = np.zeros((cam.height, cam.width), bool)

    def singles() -> None:
        for j in joints:
            render_silhouette(j, radii, cam, out=out)

    def batch() -> None:
        for s in range(0, n, 256):
            render_silhouettes(joints[s:s + 256], radii, cam)

    def labelled() -> None:
        for j in joints:
            render_labels(j, radii, cam)

    def cv2_poly() -> None:
        for j in joints[:500]:
            render_silhouette_cv2(j, radii, cam)

    return {"masks_per_s_single": rate(singles, n), "masks_per_s_batch256": rate(batch, n),
            "labelled_masks_per_s": rate(labelled, n),
            "runs_per_s_batch": rate(lambda: silhouette_runs_batch(joints, radii, cam), n),
            "cv2_polygon_masks_per_s": rate(cv2_poly, min(n, 500))}


def bench_pyrender(poses: np.ndarray) -> dict[str, float]:
    cam = default_camera()
    ious = []
    t_gl = 0.0
    with MeshRasterizer(cam) as rast:
        for k, pose in enumerate(poses):
            body = BODY_MODELS[k % len(BODY_MODELS)].body
            mesh = BodyMesh(body, segments=20, rings=5)
            joints = fk(pose, body)
            t = time.perf_counter()
            verts, _ = mesh.vertices(joints)
            truth = rast.silhouette(verts, mesh.faces)
            t_gl += time.perf_counter() - t
            fast = render_silhouette(joints, body.capsule_radii, cam)
            ious.append((fast & truth).sum() / max((fast | truth).sum(), 1))
    a = np.array(ious)
    return {"pyrender_silhouettes_per_s": len(poses) / t_gl, "iou_min": float(a.min()),
            "iou_p5": float(np.percentile(a, 5)), "iou_mean": float(a.mean()), "iou_poses": len(a)}


def bench_scene(frames: int, seed: int = 1) -> dict[str, float]:
    motion = load_motion(mocap_root() / SCENE_MOTION)
    t0 = time.perf_counter()
    with SyntheticScene(motion, seed=seed, config=SceneConfig(empty_prefix=0)) as scene:
        t_init = time.perf_counter() - t0
        n = min(frames, scene.n_frames)
        scene.frame(0)
        t, c = time.perf_counter(), time.process_time()
        for i in range(1, n + 1):
            scene.frame(i)
        dt, dc = time.perf_counter() - t, time.process_time() - c
    return {"scene_frames_per_s": n / dt, "scene_ms_per_frame": 1000 * dt / n,
            "scene_cpu_ms_per_frame": 1000 * dc / n, "scene_init_s": t_init, "scene_frames": n}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--poses", type=int, default=2000, help="poses for the fast renderer (default 2000)")
    ap.add_argument("--iou-poses", type=int, default=200, help="poses for pyrender / IoU (default 200)")
    ap.add_argument("--scene-frames", type=int, default=150, help="scene frames to time (default 150)")
    ap.add_argument("--json", action="store_true", help="print JSON only")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()[0]
    res: dict[str, Any] = {"cpu_count": os.cpu_count(), "load_before": load0}
    res.update(bench_fast(database_poses(args.poses)))
    res.update(bench_pyrender(database_poses(args.iou_poses, seed=1)))
    res.update(bench_scene(args.scene_frames))
    res["load_after"] = os.getloadavg()[0]
    if args.json:
        print(json.dumps(res))
        return 0
    for k, v in res.items():
        print(f"{k:28s} {v:12.4g}" if isinstance(v, float) else f"{k:28s} {v!s:>12}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
