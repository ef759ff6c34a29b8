"""``mocap-tracker record``: subscribe to a tracker's poses (and body) and write the session as a BVH
Blender imports, JSON lines and CSV (:mod:`tracker_service.app.record`).

::

    mocap-tracker record --bvh OUT.bvh [--jsonl OUT.jsonl] [--csv OUT.csv] [--duration S] [--id ID]
                         [--bvh-names conventional|native] [zenoh options]

Records until SIGINT / SIGTERM or ``--duration``, then writes the files and prints one summary line.
Exit status 0, or 1 with a one-line reason on stderr (no pose received, a file cannot be written).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

from protocol.net.cli_args import nonneg_float
from protocol.net.session import add_zenoh_args
from tracker_service.app.commands.common import UsageError, tracker_id, zenoh_options
from tracker_service.app.options import RecordOptions

__all__ = ["CLEAN_STOP", "NAME", "add_parser", "main", "options_from_args"]

NAME = "record"
CLEAN_STOP = True


def add_parser(sub: Any, parents: Sequence[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Add ``record`` to the ``mocap-tracker`` subparsers."""
    rp = sub.add_parser(NAME, parents=list(parents),
                        help="subscribe to a tracker's poses and write the session as BVH, JSON lines and CSV",
                        description="Subscribe to mocap/tracker/<id>/pose and .../body and, at Ctrl-C or after "
                                    "--duration, write the session: a BVH on the tracked body's skeleton "
                                    "(centimetres, Y up, conventional joint names; Blender: File > Import > "
                                    "Motion Capture, scale 0.01), one JSON object per pose, and a CSV of the "
                                    "joint positions.")
    rp.add_argument("--bvh", metavar="OUT.bvh", help="write the poses as a BVH motion")
    rp.add_argument("--jsonl", metavar="OUT.jsonl",
                    help="write one JSON object per pose: seq, capture_ts, joints (metres), confidence")
    rp.add_argument("--csv", metavar="OUT.csv", help="write seq, t (s) and x/y/z of every joint (metres) per pose")
    rp.add_argument("--duration", type=nonneg_float, metavar="S", help="stop after S seconds (default: Ctrl-C)")
    rp.add_argument("--id", type=tracker_id, default="default", help="tracker id (default: default)")
    rp.add_argument("--bvh-names", choices=("conventional", "native"), default="conventional",
                    help="BVH joint names: conventional (Hips, Spine, LeftArm, ...; default) or native "
                         "(pelvis, l_shoulder, ...: read back exactly by replay --bvh)")
    rp.add_argument("--body-timeout", type=nonneg_float, default=2.0, metavar="S",
                    help="seconds to wait for the tracker's answer to the body query (default 2)")
    add_zenoh_args(rp, "subscriber")
    return rp


def options_from_args(args: argparse.Namespace) -> RecordOptions:
    if not (args.bvh or args.jsonl or args.csv):
        raise UsageError("record: give at least one of --bvh, --jsonl, --csv")
    return RecordOptions(bvh=args.bvh, jsonl=args.jsonl, csv=args.csv, tracker_id=args.id, duration=args.duration,
                         bvh_names=args.bvh_names, body_timeout=args.body_timeout, zenoh=zenoh_options(args))


def main(options: RecordOptions) -> int:
    """Record until SIGINT / SIGTERM or the duration, write the files, print a summary line."""
    import threading

    from protocol.net.session import stop_on_signals
    from tracker_service.app.record import record_session, save_recording

    conf = options.zenoh.config()
    with stop_on_signals(threading.Event()) as stop:
        rec = record_session(conf, options, stop)
    summary = save_recording(rec, options)
    print(f"recorded {summary.frames} poses ({summary.missing} missing, {summary.fps} fps) to "
          f"{', '.join(summary.files)}" + (f"; body {summary.body}" if summary.body else ""))
    return 0
