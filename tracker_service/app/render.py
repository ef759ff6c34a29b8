"""Render core of ``mocap-tracker render``: write the synthetic scene of a motion to disk so a person
can look at it.

``--out DIR`` writes ``DIR/frames/000000.png`` ..., ``DIR/truth.jsonl`` (one JSON object per frame:
index, time, pose, 3D and 2D joints, per-part pixel counts and visible fractions, silhouette area
and bounding box) and ``DIR/scene.json`` (seed, motion, camera, the person's measurements and
skeleton); with ``--masks`` also ``DIR/silhouettes/*.png`` and colour-coded ``DIR/labels/*.png``.
``--out NAME.mp4`` writes an H.264 video a browser plays (:class:`protocol.formats.video.VideoWriter`;
``.avi``: Motion JPEG) and ``NAME.truth.jsonl`` / ``NAME.scene.json``
beside it. The command line is :mod:`tracker_service.app.commands.render`.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from protocol.formats.video import VideoWriter
from protocol.skeleton import JOINT_NAMES, PARTS
from tracker_service.app.options import RenderOptions

__all__ = ["VIDEO_CODECS", "label_palette", "render_motion", "truth_record"]

#: Video file suffixes and their codecs (``h264``: :class:`protocol.formats.video.VideoWriter`, yuv420p;
#: the others: OpenCV's writer with that FourCC).
VIDEO_CODECS = {".mp4": "h264", ".avi": "MJPG"}


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


def _scene_meta(scene: Any, source: str) -> dict[str, Any]:
    cam = scene.camera
    spec = scene.subject.spec
    return {"seed": scene.seed, "motion": scene.motion_name, "source": source, "fps": scene.fps,
            "frames": scene.n_frames, "empty_prefix": scene.config.empty_prefix,
            "camera": {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy, "cx": cam.cx,
                       "cy": cam.cy, "dist": cam.dist.tolist(), "pose": cam.pose.tolist(),
                       "convention": "pose = camera-to-world, camera looks along -Z, Y up; pixel centres at integers"},
            "subject": {"group": spec.group, "height_m": spec.height, "chest_m": spec.chest, "waist_m": spec.waist,
                        "hip_m": spec.hip, "skirt": spec.skirt, "long_sleeves": spec.long_sleeves,
                        "offsets": _r(scene.subject.body.offsets),
                        "capsule_radii": _r(scene.subject.body.capsule_radii)},
            "joint_names": list(JOINT_NAMES), "parts": list(PARTS)}


class _Output:
    """Where the frames go: a video file, or PNG folders (frames, and with ``masks`` silhouettes and
    part labels); the ground truth and scene files beside them."""

    def __init__(self, out: Path, masks: bool, fps: float, size: tuple[int, int]):
        self.out = out
        self.masks = masks
        self.writer: cv2.VideoWriter | VideoWriter | None = None
        codec = VIDEO_CODECS.get(out.suffix.lower())
        if codec is not None:
            out.parent.mkdir(parents=True, exist_ok=True)
            self.truth_path, self.meta_path = out.with_suffix(".truth.jsonl"), out.with_suffix(".scene.json")
            if codec == "h264":
                self.writer = VideoWriter(out, fps)
            else:
                self.writer = cv2.VideoWriter(str(out), cv2.VideoWriter.fourcc(*codec), fps, size)
                if not self.writer.isOpened():
                    raise OSError(f"cannot open a video writer for {out}")
        else:
            (out / "frames").mkdir(parents=True, exist_ok=True)
            if masks:
                (out / "silhouettes").mkdir(exist_ok=True)
                (out / "labels").mkdir(exist_ok=True)
            self.truth_path, self.meta_path = out / "truth.jsonl", out / "scene.json"
        self.palette = label_palette()

    def write(self, i: int, image: NDArray[np.uint8], truth: Any) -> None:
        if self.writer is not None:
            self.writer.write(image)
            return
        cv2.imwrite(str(self.out / "frames" / f"{i:06d}.png"), image)
        if self.masks:
            cv2.imwrite(str(self.out / "silhouettes" / f"{i:06d}.png"), truth.silhouette.astype(np.uint8) * 255)
            cv2.imwrite(str(self.out / "labels" / f"{i:06d}.png"), self.palette[truth.part_labels.astype(np.int64)])

    def close(self) -> None:
        if isinstance(self.writer, VideoWriter):
            self.writer.close()
        elif self.writer is not None:
            self.writer.release()


def render_motion(options: RenderOptions) -> int:
    """Render ``options.motion`` to ``options.out`` and print a summary; returns the exit status.

    Raises
    ------
    OSError, ValueError
        For a missing or unreadable motion, or an output that is neither a folder nor a video file.
    """
    from tracker_service.scene.synthetic import SceneConfig, SyntheticScene  # GL is only needed here

    if not options.motion:
        raise ValueError("choose a motion with --bvh FILE or --script FILE")
    out = Path(options.out)
    if out.suffix and out.suffix.lower() not in VIDEO_CODECS and not out.is_dir():
        raise ValueError(f"--out {out}: use a folder or a {'/'.join(VIDEO_CODECS)} file")
    cfg = SceneConfig(fps=options.fps or None, empty_prefix=options.empty_prefix, camera_jitter_px=options.jitter_px,
                      noise=options.noise, in_place=options.in_place)
    t0 = time.perf_counter()
    with SyntheticScene.from_file(options.motion, seed=options.seed, config=cfg) as scene:
        n = min(scene.n_frames, options.frames) if options.frames else scene.n_frames
        output = _Output(out, options.masks, scene.fps, (cfg.width, cfg.height))
        output.meta_path.write_text(json.dumps(_scene_meta(scene, options.motion), indent=1) + "\n")
        t_render = 0.0
        with output.truth_path.open("w") as fh:
            for i in tqdm(range(n), desc="render", unit="frame", disable=None, file=sys.stderr):
                t1 = time.perf_counter()
                ts, image, truth = scene.frame(i)
                t_render += time.perf_counter() - t1
                fh.write(json.dumps(truth_record(ts, truth)) + "\n")
                output.write(i, image, truth)
        output.close()
    elapsed = time.perf_counter() - t0
    summary = {"frames": n, "out": str(out), "truth": str(output.truth_path), "seconds": round(elapsed, 3),
               "render_fps": round(n / t_render, 1) if t_render > 0 else None}
    if options.json:
        print(json.dumps(summary))
    else:
        print(f"wrote {n} frames to {out} ({summary['render_fps']} frames/s rendering, {elapsed:.1f} s in all); "
              f"ground truth in {output.truth_path}")
    return 0
