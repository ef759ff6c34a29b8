"""``mocap-tracker eval``: render the synthetic scene for a motion, track it and print a readable
summary, or with ``--json`` exactly the JSON contract of :func:`tracker_service.app.evaluate.evaluate_motion`.
Progress goes to stderr (also with ``--json``; not with ``-q``); ``--video OUT.mp4`` writes the overlay
of every frame."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from typing import Any, TextIO

from tracker_service.app.commands.common import UsageError, add_tracker_args, add_video_arg, tracker_options
from tracker_service.app.options import EvalCommandOptions, EvalOptions
from tracker_service.app.tracker_config import subject_keys

__all__ = ["CLEAN_STOP", "NAME", "add_parser", "main", "options_from_args", "summary_lines"]

NAME = "eval"
CLEAN_STOP = False

log = logging.getLogger(__name__)


def add_parser(sub: Any, parents: Sequence[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Add ``eval`` to the ``mocap-tracker`` subparsers."""
    ep = sub.add_parser(NAME, parents=list(parents), help="track a motion rendered as synthetic video; print errors",
                        description="Render the synthetic scene for a BVH recording or gesture script (a subject "
                                    "unlike the database's body models), run the whole pipeline from pixels and "
                                    "print a summary, or with --json one JSON object: mpjpe_cm, root_error_cm, "
                                    "mpjpe_2d_px, frames_within_10cm, accel_error_cm (jitter), reacquire_s_max, fps, "
                                    "ms_per_frame, distance_evals_per_level, templates, estimator, distance, "
                                    "body_selected, frames.")
    src = ep.add_mutually_exclusive_group(required=True)
    src.add_argument("--bvh", metavar="FILE")
    src.add_argument("--script", metavar="FILE")
    add_tracker_args(ep, subject=True)
    ep.add_argument("--frames", type=int, metavar="N", help="evaluate at most N frames")
    ep.add_argument("--seed", type=int, default=0, help="scene seed (subject, room, lighting, noise)")
    ep.add_argument("--empty-prefix", type=int, default=12, metavar="N",
                    help="frames of the empty room before the person appears (default: 12); 0: the person is in "
                         "view from the first frame, as when a user starts the tracker standing in front of it")
    ep.add_argument("--force-loss-every", type=float, default=0.0, metavar="S",
                    help="force a tracking loss every S seconds and measure re-acquisition (default: never)")
    ep.add_argument("--jpeg-quality", type=int, metavar="Q",
                    help="pass every frame through JPEG at quality Q (1-100) first, as a webcam's MJPEG does "
                         "(default: lossless)")
    ep.add_argument("--h264-crf", type=int, metavar="CRF",
                    help="pass every frame through H.264 at this CRF (0-51; 28 is a typical stream) first")
    ep.add_argument("--input-size", metavar="WxH",
                    help="film the scene at this size (e.g. 640x480, 1280x720: a camera whose frames, scaled and "
                         "centre-cropped as run does, are the working camera's) (default: the working size)")
    ep.add_argument("--vary", metavar="AXES", default="",
                    help="domain randomisation of the scene: comma-separated axes of body, clothing, appearance, "
                         "backdrop, lights, sensor, compression, or all (default: none)")
    ep.add_argument("--json", action="store_true", help="print only the JSON object (progress stays on stderr)")
    add_video_arg(ep)
    return ep


def options_from_args(args: argparse.Namespace) -> EvalCommandOptions:
    tracker = tracker_options(args, subject=True)
    if args.jpeg_quality is not None and not 1 <= args.jpeg_quality <= 100:
        raise UsageError("--jpeg-quality must be in 1..100")
    if not 0 <= args.empty_prefix <= 10_000:
        raise UsageError("--empty-prefix must be in 0..10000")
    if args.h264_crf is not None and not 0 <= args.h264_crf <= 51:
        raise UsageError("--h264-crf must be in 0..51")
    from tracker_service.scene.variation import parse_axes

    size = None
    if args.input_size:
        try:
            w, h = (int(v) for v in args.input_size.lower().split("x"))
        except ValueError:
            raise UsageError(f"--input-size: expected WxH, e.g. 640x480, got {args.input_size!r}") from None
        if not (160 <= w <= 3840 and 120 <= h <= 2160):
            raise UsageError("--input-size: width 160-3840, height 120-2160")
        size = (w, h)

    try:
        variation = parse_axes(args.vary)
    except ValueError as e:
        raise UsageError(f"--vary: {e}") from None
    return EvalCommandOptions(motion=args.bvh or args.script, tracker=tracker, json=args.json,
                              evaluation=EvalOptions(frames=args.frames, seed=args.seed, empty_prefix=args.empty_prefix,
                                                     force_loss_every_s=args.force_loss_every,
                                                     jpeg_quality=args.jpeg_quality, h264_crf=args.h264_crf,
                                                     variation=variation, input_size=size),
                              progress=not args.quiet, video=args.video)


def _num(v: Any, unit: str = "", nd: int = 2) -> str:
    return "-" if v is None else f"{v:.{nd}f}{unit}"


def summary_lines(result: dict[str, Any], extra: Sequence[tuple[str, str]] = ()) -> list[str]:
    """The readable summary of an ``eval`` result (aligned ``label  value`` lines), ``extra`` rows last."""
    ms = result.get("ms_per_frame", {}).get("total", {})
    within = result.get("frames_within_10cm")
    rows = [
        ("motion", str(result.get("motion"))),
        ("frames", f"{result.get('tracked_frames')} tracked of {result.get('frames')} with the person in view"),
        ("MPJPE", _num(result.get("mpjpe_cm"), " cm")),
        ("within 10 cm", "-" if within is None else f"{100.0 * within:.1f} % of frames"),
        ("root error", _num(result.get("root_error_cm"), " cm")),
        ("2D error", _num(result.get("mpjpe_2d_px"), " px")),
        ("jitter", _num(result.get("accel_error_cm"), " cm/frame^2", 3)),
        ("fps", f"{_num(result.get('fps'), '', 1)} ({_num(ms.get('avg'), ' ms', 1)} per steady frame)"),
        ("body", f"{result.get('body_selected')} (subject {_num(result.get('subject_height_m'), ' m', 2)})"),
    ]
    if result.get("forced_losses"):
        rows.append(("re-acquired", f"{result.get('reacquired')} of {result.get('forced_losses')} losses, "
                                    f"slowest {_num(result.get('reacquire_s_max'), ' s')}"))
    rows.append(("reinitialised", str(result.get("reinitialisations"))))
    rows.extend(extra)
    width = max(len(k) for k, _ in rows)
    return [f"{k:<{width}}  {v}" for k, v in rows]


class _Progress:
    """Frame counts on stderr: one updated line on a terminal, else a line every tenth of the clip."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.tty = stream.isatty()
        self.last = -1
        self.shown = False

    def __call__(self, done: int, total: int) -> None:
        if self.tty:
            print(f"\r{done}/{total} frames", end="", file=self.stream, flush=True)
            self.shown = True
            return
        step = max(total // 10, 1)
        if done // step != self.last or done == total:
            self.last = done // step
            print(f"{done}/{total} frames", file=self.stream, flush=True)

    def end(self) -> None:
        if self.tty and self.shown:
            print(file=self.stream, flush=True)


def main(options: EvalCommandOptions) -> int:
    """Evaluate and print the summary (``--json``: the JSON object, on one line)."""
    from dataclasses import replace

    from protocol.formats.load import load_motion
    from tracker_service.app.evaluate import evaluate_motion
    from tracker_service.app.resources import ensure_db, requested_camera
    from tracker_service.app.tracker_config import tracker_config
    from tracker_service.pipeline.warmup import warm_up

    motion = load_motion(options.motion, fps=30.0)
    camera = requested_camera(options.tracker)
    loaded = ensure_db(options.tracker.db, camera=camera)
    cfg = tracker_config(options.tracker)
    warm_up(loaded.db, loaded.body, loaded.camera, cfg)  # kernels compiled before the clock starts
    # the scene is filmed by the camera the tracker is told about (its frames fitted to the working size)
    evaluation = replace(options.evaluation, subject_measurements=subject_keys(options.tracker.measurements),
                         camera=camera)

    progress = _Progress(sys.stderr) if options.progress else None
    if options.video is None:
        result = evaluate_motion(motion, loaded, cfg, evaluation, progress)
    else:
        from tracker_service.viz.overlay import OverlayVideo

        with OverlayVideo(options.video, loaded.camera, evaluation.fps) as video:
            result = evaluate_motion(motion, loaded, cfg, evaluation, progress,
                                     observe=lambda fr, _state, res: video(fr.image, res))
    if progress is not None:
        progress.end()
    if options.json:
        print(json.dumps(result))
    else:
        print("\n".join(summary_lines(result, () if options.video is None else (("video", options.video),))))
    return 0
