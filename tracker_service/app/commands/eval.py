"""``mocap-tracker eval``: render the synthetic scene for a motion, track it and print the JSON
contract of :func:`tracker_service.app.evaluate.evaluate_motion`."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

from tracker_service.app.commands.common import add_tracker_args, tracker_options
from tracker_service.app.options import EvalCommandOptions, EvalOptions
from tracker_service.app.tracker_config import subject_keys

__all__ = ["CLEAN_STOP", "NAME", "add_parser", "main", "options_from_args"]

NAME = "eval"
CLEAN_STOP = False


def add_parser(sub: Any, parents: Sequence[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Add ``eval`` to the ``mocap-tracker`` subparsers."""
    ep = sub.add_parser(NAME, parents=list(parents), help="track a motion rendered as synthetic video; print errors",
                        description="Render the synthetic scene for a BVH recording or gesture script (a subject "
                                    "unlike the database's body models), run the whole pipeline from pixels and "
                                    "print one JSON object: mpjpe_cm, root_error_cm, mpjpe_2d_px, "
                                    "frames_within_10cm, accel_error_cm (jitter), reacquire_s_max, fps, ms_per_frame, "
                                    "distance_evals_per_level, templates, estimator, distance, body_selected, frames.")
    src = ep.add_mutually_exclusive_group(required=True)
    src.add_argument("--bvh", metavar="FILE")
    src.add_argument("--script", metavar="FILE")
    add_tracker_args(ep, subject=True)
    ep.add_argument("--frames", type=int, metavar="N", help="evaluate at most N frames")
    ep.add_argument("--seed", type=int, default=0, help="scene seed (subject, room, lighting, noise)")
    ep.add_argument("--force-loss-every", type=float, default=0.0, metavar="S",
                    help="force a tracking loss every S seconds and measure re-acquisition (default: never)")
    ep.add_argument("--json", action="store_true", help="print only the JSON object")
    return ep


def options_from_args(args: argparse.Namespace) -> EvalCommandOptions:
    tracker = tracker_options(args, subject=True)
    return EvalCommandOptions(motion=args.bvh or args.script, tracker=tracker, json=args.json,
                              evaluation=EvalOptions(frames=args.frames, seed=args.seed,
                                                     force_loss_every_s=args.force_loss_every))


def main(options: EvalCommandOptions) -> int:
    """Evaluate and print the JSON object (indented unless ``--json``)."""
    from dataclasses import replace

    from protocol.formats.load import load_motion
    from tracker_service.app.evaluate import evaluate_motion
    from tracker_service.app.resources import ensure_db
    from tracker_service.app.tracker_config import tracker_config
    from tracker_service.pipeline.warmup import warm_up

    motion = load_motion(options.motion, fps=30.0)
    loaded = ensure_db(options.tracker.db)
    cfg = tracker_config(options.tracker)
    warm_up(loaded.db, loaded.body, loaded.camera, cfg)  # kernels compiled before the clock starts
    evaluation = replace(options.evaluation, subject_measurements=subject_keys(options.tracker.measurements))

    def progress(done: int, total: int) -> None:
        if not options.json and sys.stderr.isatty():
            print(f"\r{done}/{total} frames", end="", file=sys.stderr)

    result = evaluate_motion(motion, loaded, cfg, evaluation, progress)
    print(json.dumps(result) if options.json else json.dumps(result, indent=1))
    return 0
