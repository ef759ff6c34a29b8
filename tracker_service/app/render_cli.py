"""``mocap-tracker render``: write the synthetic scene of a motion to disk so a person can look at it.

::

    mocap-tracker render --bvh FILE|--script FILE --out DIR|VIDEO.mp4 [--seed S] [--frames N]
                         [--empty-prefix N] [--fps HZ] [--jitter PX] [--no-noise] [--in-place] [--masks]

``--out DIR`` writes ``DIR/frames/000000.png`` ..., ``DIR/truth.jsonl`` (one JSON object per frame:
index, time, pose, 3D and 2D joints, per-part pixel counts and visible fractions, silhouette area
and bounding box) and ``DIR/scene.json`` (seed, motion, camera, the person's measurements and
skeleton); with ``--masks`` also ``DIR/silhouettes/*.png`` and colour-coded ``DIR/labels/*.png``.
``--out NAME.mp4`` (or ``.avi``) writes a video and ``NAME.truth.jsonl`` / ``NAME.scene.json``
beside it. :func:`add_render_parser` adds the subcommand to the ``mocap-tracker`` parser and
:func:`run_render` runs it (exit status 0, or 1 with a one-line reason on stderr).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from protocol.net.cli_args import nonneg_float as _nonneg_float
from protocol.net.cli_args import nonneg_int as _nonneg_int
from protocol.net.cli_args import positive_int as _pos_int
from protocol.skeleton import JOINT_NAMES, PARTS

__all__ = ["add_render_parser", "label_palette", "run_render", "truth_record"]

log = logging.getLogger(__name__)
_VIDEO = {".mp4": "mp4v", ".avi": "MJPG"}








def add_render_parser(subparsers: Any, parents: Sequence[argparse.ArgumentParser] = ()) -> argparse.ArgumentParser:
    """Add the ``render`` subcommand to ``subparsers`` (from ``ArgumentParser.add_subparsers``)."""
    rp = subparsers.add_parser(
        "render", parents=list(parents), help="render the synthetic camera view of a motion to images or a video",
        description="Play a BVH recording or gesture script on a randomly proportioned, clothed person in "
                    "a furnished room seen by the 320x240 camera of the paper, and write the frames "
                    "with their ground truth (pose, 3D/2D joints, silhouette, part visibility). The "
                    "same --seed gives the same person, room, lighting and noise.")
    src = rp.add_argument_group("motion source (choose one)").add_mutually_exclusive_group(required=True)
    src.add_argument("--bvh", metavar="FILE", help="BVH recording (retargeted onto the shared skeleton)")
    src.add_argument("--script", metavar="FILE", help="gesture script (.toml)")
    rp.add_argument("--out", required=True, metavar="DIR|VIDEO",
                    help="output folder (PNG frames + truth.jsonl) or a .mp4/.avi video file")
    rp.add_argument("--seed", type=_nonneg_int, default=0, help="scene seed (default 0)")
    rp.add_argument("--frames", type=_pos_int, metavar="N", help="stop after N frames (prefix included)")
    rp.add_argument("--empty-prefix", type=_nonneg_int, default=0, metavar="N",
                    help="start with N frames of the empty room (background learning)")
    rp.add_argument("--fps", type=_nonneg_float, metavar="HZ", help="resample the motion (default: its own rate)")
    rp.add_argument("--jitter", type=_nonneg_float, default=0.0, metavar="PX",
                    help="camera wobble amplitude in pixels (default 0: tripod)")
    rp.add_argument("--no-noise", action="store_true",
                    help="clean renders: no sensor noise, exposure drift or vignetting")
    rp.add_argument("--in-place", action="store_true", help="remove the motion's horizontal travel")
    rp.add_argument("--masks", action="store_true", help="also write silhouette and part-label PNGs (folder output)")
    rp.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    rp.set_defaults(func=run_render)
    return rp


def label_palette() -> NDArray[np.uint8]:
    """(N_PARTS + 1, 3) uint8 BGR colours for part labels; the last row (index -1) is black."""
    hues = (np.arange(len(PARTS)) * 137.5) % 180
    hsv = np.stack([hues, np.full_like(hues, 200), np.full_like(hues, 255)], axis=1).astype(np.uint8)[None]
    bgr = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0]
    return np.concatenate([bgr, np.zeros((1, 3), np.uint8)])


def _r(a: NDArray[np.float64], nd: int = 5) -> Any:
    return np.round(np.asarray(a, dtype=np.float64), nd).tolist()


def truth_record(timestamp: float, truth: Any) -> dict[str, Any]:
    """The JSON-lines record of one frame's :class:`~tracker_service.scene.synthetic.GroundTruth`."""
    rec: dict[str, Any] = {"index": truth.index, "t": round(timestamp, 6), "present": truth.present}
    if truth.present:
        ys, xs = np.nonzero(truth.silhouette)
        rec.update(pose=_r(truth.pose, 6), joints=_r(truth.joints), joints_2d=_r(truth.joints_2d, 2),
                   part_pixels=truth.part_pixels.tolist(), visibility=_r(truth.visibility, 3),
                   silhouette_area=len(xs),
                   bbox=[int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1] if len(xs) else None)
    return rec


def _scene_meta(scene: Any, args: argparse.Namespace) -> dict[str, Any]:
    cam = scene.camera
    spec = scene.subject.spec
    return {"seed": scene.seed, "motion": scene.motion_name, "source": args.bvh or args.script, "fps": scene.fps,
            "frames": scene.n_frames, "empty_prefix": scene.config.empty_prefix,
            "camera": {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy, "cx": cam.cx,
                       "cy": cam.cy, "dist": cam.dist.tolist(), "pose": cam.pose.tolist(),
                       "convention": "pose = camera-to-world, camera looks along -Z, Y up; pixel centres at integers"},
            "subject": {"group": spec.group, "height_m": spec.height, "chest_m": spec.chest, "waist_m": spec.waist,
                        "hip_m": spec.hip, "skirt": spec.skirt, "long_sleeves": spec.long_sleeves,
                        "offsets": _r(scene.subject.body.offsets),
                        "capsule_radii": _r(scene.subject.body.capsule_radii)},
            "joint_names": list(JOINT_NAMES), "parts": list(PARTS)}


def run_render(args: argparse.Namespace) -> int:
    """Run ``mocap-tracker render`` with parsed ``args``; returns the exit status."""
    try:
        return _render(args)
    except (OSError, ValueError) as exc:
        print(f"mocap-tracker render: {exc}", file=sys.stderr)
        return 1


def _render(args: argparse.Namespace) -> int:
    from tracker_service.scene.synthetic import SceneConfig, SyntheticScene  # GL is only needed here

    src = args.bvh or args.script
    if not src:
        raise ValueError("choose a motion with --bvh FILE or --script FILE")
    out = Path(args.out)
    video = out.suffix.lower() in _VIDEO
    if out.suffix and not video and not out.is_dir():
        raise ValueError(f"--out {out}: use a folder or a {'/'.join(_VIDEO)} file")
    cfg = SceneConfig(fps=args.fps or None, empty_prefix=args.empty_prefix, camera_jitter_px=args.jitter,
                      noise=not args.no_noise, in_place=args.in_place)
    t0 = time.perf_counter()
    with SyntheticScene.from_file(src, seed=args.seed, config=cfg) as scene:
        n = min(scene.n_frames, args.frames) if args.frames else scene.n_frames
        if video:
            out.parent.mkdir(parents=True, exist_ok=True)
            truth_path, meta_path = out.with_suffix(".truth.jsonl"), out.with_suffix(".scene.json")
            writer = cv2.VideoWriter(str(out), cv2.VideoWriter.fourcc(*_VIDEO[out.suffix.lower()]), scene.fps,
                                     (cfg.width, cfg.height))
            if not writer.isOpened():
                raise OSError(f"cannot open a video writer for {out}")
        else:
            (out / "frames").mkdir(parents=True, exist_ok=True)
            if args.masks:
                (out / "silhouettes").mkdir(exist_ok=True)
                (out / "labels").mkdir(exist_ok=True)
            truth_path, meta_path = out / "truth.jsonl", out / "scene.json"
        meta_path.write_text(json.dumps(_scene_meta(scene, args), indent=1) + "\n")
        palette = label_palette()
        t_render = 0.0
        with truth_path.open("w") as fh:
            for i in tqdm(range(n), desc="render", unit="frame", disable=None, file=sys.stderr):
                t1 = time.perf_counter()
                ts, image, truth = scene.frame(i)
                t_render += time.perf_counter() - t1
                fh.write(json.dumps(truth_record(ts, truth)) + "\n")
                if video:
                    writer.write(image)
                else:
                    cv2.imwrite(str(out / "frames" / f"{i:06d}.png"), image)
                    if args.masks:
                        cv2.imwrite(str(out / "silhouettes" / f"{i:06d}.png"), truth.silhouette.astype(np.uint8) * 255)
                        cv2.imwrite(str(out / "labels" / f"{i:06d}.png"), palette[truth.part_labels.astype(np.int64)])
        if video:
            writer.release()
    elapsed = time.perf_counter() - t0
    summary = {"frames": n, "out": str(out), "truth": str(truth_path), "seconds": round(elapsed, 3),
               "render_fps": round(n / t_render, 1) if t_render > 0 else None}
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"wrote {n} frames to {out} ({summary['render_fps']} frames/s rendering, {elapsed:.1f} s in all); "
              f"ground truth in {truth_path}")
    return 0
