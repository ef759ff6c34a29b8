"""``mocap-tracker replay``: publish a recorded (``--bvh``) or scripted (``--script``) motion over
Zenoh as if a tracker saw it live, or the built-in ``--synthetic-wave`` self-test motion that needs
no files (:mod:`tracker_service.app.replay_daemon`)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

from protocol.net.cli_args import positive_float, positive_int
from protocol.net.session import add_zenoh_args
from protocol.wire.keys import DEFAULT_TRACKER_ID
from tracker_service.app.commands.common import tracker_id, wait_for_subscriber, zenoh_options
from tracker_service.app.options import ReplayCommandOptions, ReplayOptions

__all__ = ["CLEAN_STOP", "NAME", "add_parser", "main", "options_from_args"]

NAME = "replay"
CLEAN_STOP = True


def add_parser(sub: Any, parents: Sequence[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Add ``replay`` to the ``mocap-tracker`` subparsers."""
    rp = sub.add_parser(
        NAME, parents=list(parents), help="publish a recorded or scripted motion as a live pose stream",
        description="Publish a motion over Zenoh exactly like a live tracker: PoseFrames at the motion's "
                    "frame rate on mocap/tracker/<id>/pose, the body description on .../body (also "
                    "answered to queries), a status message every second on .../status and a "
                    "liveliness token on .../alive. Stops at the end of the motion (unless --loop), "
                    "after --duration or --frames, or on Ctrl-C.",
    )
    src = rp.add_argument_group("motion source (choose one)").add_mutually_exclusive_group(required=True)
    src.add_argument("--bvh", metavar="FILE", help="BVH recording, retargeted onto the shared skeleton")
    src.add_argument("--script", metavar="FILE", help="gesture script (.toml)")
    src.add_argument("--synthetic-wave", action="store_true",
                     help="built-in 4 s right-arm wave at 30 fps; a self-test source that needs no files")
    rp.add_argument("--rate", type=positive_float, metavar="HZ",
                    help="frames per second to publish (default: the motion's own rate); frames are "
                         "repeated or skipped to match")
    rp.add_argument("--loop", action="store_true", help="start again at the end (seq and time continue)")
    rp.add_argument("--duration", type=positive_float, metavar="S", help="stop after S seconds")
    rp.add_argument("--frames", type=positive_int, metavar="N", help="stop after N frames")
    rp.add_argument("--id", type=tracker_id, default=DEFAULT_TRACKER_ID,
                    help=f"tracker id used in the key expressions (default: '{DEFAULT_TRACKER_ID}'; "
                         "letters, digits, '_' and '-')")
    rp.add_argument("--wait-for-subscriber", type=float, default=0.0, metavar="S",
                    help="wait up to S seconds for a pose subscriber before the first frame, so it "
                         "receives the stream from seq 0 (default: start at once)")
    add_zenoh_args(rp, "publisher")
    return rp


def options_from_args(args: argparse.Namespace) -> ReplayCommandOptions:
    publish = ReplayOptions(tracker_id=args.id, rate=args.rate, loop=args.loop, duration=args.duration,
                            max_frames=args.frames, wait_for_subscriber=wait_for_subscriber(args))
    return ReplayCommandOptions(motion=args.bvh or args.script, synthetic_wave=args.synthetic_wave,
                                zenoh=zenoh_options(args), publish=publish)


def main(options: ReplayCommandOptions) -> int:
    """Publish the motion until it ends, a limit, SIGINT or SIGTERM (exit status 0)."""
    from tracker_service.app.replay_daemon import run_replay

    return run_replay(options)
