"""``mocap-tracker run``: the tracker daemon, a frame source -> pipeline -> Zenoh
(:mod:`tracker_service.app.daemon`)."""

from __future__ import annotations

import argparse
import logging
import os
import sys
import threading
from collections.abc import Sequence
from typing import Any

from protocol.net.cli_args import positive_float
from protocol.net.session import add_zenoh_args
from tracker_service.app.commands.common import (
    add_tracker_args,
    add_video_arg,
    tracker_options,
    wait_for_subscriber,
    zenoh_options,
)
from tracker_service.app.options import RunCommandOptions, RunOptions

__all__ = ["CLEAN_STOP", "NAME", "add_parser", "main", "options_from_args", "with_camera_db"]

NAME = "run"
CLEAN_STOP = True

log = logging.getLogger(__name__)


def _frame_rate(text: str) -> float:
    """A frame rate in (0, 240] Hz (a higher one would render millions of frames of a motion)."""
    value = positive_float(text)
    if value > 240.0:
        raise argparse.ArgumentTypeError(f"must be at most 240 Hz, got {text!r}")
    return value


def add_parser(sub: Any, parents: Sequence[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Add ``run`` to the ``mocap-tracker`` subparsers."""
    rp = sub.add_parser(NAME, parents=list(parents), help="the tracker daemon: frames -> poses over Zenoh",
                        description="Track the person in front of the camera and publish PoseFrames on "
                                    "mocap/tracker/<id>/pose, BodyInfo on .../body (also answered to queries), "
                                    "TrackerStatus on .../status and a liveliness token .../alive.")
    rp.add_argument("--source", default="synthetic", metavar="SPEC",
                    help="synthetic[:BVH|SCRIPT] (default), camera[:INDEX], video:PATH or frames:DIR")
    add_tracker_args(rp, subject=False)
    rp.add_argument("--id", default="default", help="tracker id in the key expressions (default: default)")
    rp.add_argument("--frames", type=int, metavar="N", help="stop after N input frames")
    rp.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    rp.add_argument("--seed", type=int, default=0, help="synthetic scene seed")
    rp.add_argument("--fps", type=_frame_rate, metavar="HZ",
                    help="the synthetic camera's frame rate: the motion resampled to it (default: the motion's "
                         "own, 30 for gesture scripts)")
    rp.add_argument("--prerender", action="store_true",
                    help="render the whole synthetic scene before tracking, as a camera's frames cost the tracker "
                         "nothing (0.23 MB a frame at 320x240)")
    rp.add_argument("--as-fast-as-possible", action="store_true",
                    help="do not pace file/synthetic sources at their frame rate")
    rp.add_argument("--wait-for-subscriber", type=float, default=0.0, metavar="S",
                    help="wait up to S seconds for a pose subscriber before reading the first frame")
    add_video_arg(rp)
    add_zenoh_args(rp, "publisher")
    return rp


def options_from_args(args: argparse.Namespace) -> RunCommandOptions:
    return RunCommandOptions(
        source=args.source, seed=args.seed, tracker=tracker_options(args, subject=False), zenoh=zenoh_options(args),
        daemon=RunOptions(tracker_id=args.id, max_frames=args.frames, duration=args.duration,
                          realtime=not args.as_fast_as_possible, wait_for_subscriber=wait_for_subscriber(args)),
        video=args.video, fps=args.fps, prerender=args.prerender)


def with_camera_db(options: RunCommandOptions) -> RunCommandOptions:
    """``options`` with ``--db`` set to the database rendered for the requested camera (built once
    when missing, :func:`tracker_service.app.resources.resolve_db`); unchanged without a camera
    option."""
    from dataclasses import replace

    from tracker_service.app.resources import requested_camera, resolve_db

    camera = requested_camera(options.tracker)
    if camera is None:
        return options
    db = resolve_db(options.tracker.db, camera)
    return replace(options, tracker=replace(options.tracker, db=str(db)))


def main(options: RunCommandOptions) -> int:
    """Run the daemon until the source ends, a limit, SIGINT or SIGTERM (exit status 0)."""
    from protocol.net.session import stop_on_signals

    outcome: dict[str, Any] = {}

    def work(stop: threading.Event) -> None:
        try:
            # imported here, under the signal handlers: numba and cv2 take a while to import
            from tracker_service.app.daemon import run_from_options

            outcome["rc"] = run_from_options(with_camera_db(options), stop)
        except BaseException as exc:  # handed to the main thread, which reports it
            outcome["error"] = exc

    # The work runs in a worker thread so that a signal during the seconds of start-up (database,
    # EGL context) still ends the process promptly; once running, the loop checks ``stop`` per frame.
    with stop_on_signals(threading.Event()) as stop:
        worker = threading.Thread(target=work, args=(stop,), name="tracker", daemon=True)
        worker.start()
        while worker.is_alive():
            if stop.wait(0.05):
                worker.join(timeout=1.0)
                break
    if worker.is_alive():  # still starting up (loading, EGL, warm-up): no Zenoh session yet, leave now
        log.info("stopped during start-up")
        logging.shutdown()
        sys.stdout.flush()
        os._exit(0)
    if "error" in outcome:
        raise outcome["error"]
    return int(outcome.get("rc", 0))
