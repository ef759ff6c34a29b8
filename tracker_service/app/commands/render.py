"""``mocap-tracker render``: write the synthetic scene of a motion to disk so a person can look at it
(:mod:`tracker_service.app.render`).

::

    mocap-tracker render --bvh FILE|--script FILE --out DIR|VIDEO.mp4 [--seed S] [--frames N]
                         [--empty-prefix N] [--fps HZ] [--jitter PX] [--no-noise] [--in-place] [--masks]

Exit status 0, or 1 with a one-line reason on stderr.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

from protocol.net.cli_args import nonneg_float, nonneg_int, positive_int
from tracker_service.app.options import RenderOptions

__all__ = ["CLEAN_STOP", "NAME", "add_parser", "main", "options_from_args"]

NAME = "render"
CLEAN_STOP = False


def add_parser(sub: Any, parents: Sequence[argparse.ArgumentParser] = ()) -> argparse.ArgumentParser:
    """Add ``render`` to ``sub`` (from ``ArgumentParser.add_subparsers``)."""
    rp = sub.add_parser(
        NAME, parents=list(parents), help="render the synthetic camera view of a motion to images or a video",
        description="Play a BVH recording or gesture script on a randomly proportioned, clothed person in "
                    "a furnished room seen by the 320x240 camera of the paper, and write the frames "
                    "with their ground truth (pose, 3D/2D joints, silhouette, part visibility). The "
                    "same --seed gives the same person, room, lighting and noise.")
    src = rp.add_argument_group("motion source (choose one)").add_mutually_exclusive_group(required=True)
    src.add_argument("--bvh", metavar="FILE", help="BVH recording (retargeted onto the shared skeleton)")
    src.add_argument("--script", metavar="FILE", help="gesture script (.toml)")
    rp.add_argument("--out", required=True, metavar="DIR|VIDEO",
                    help="output folder (PNG frames + truth.jsonl) or a .mp4/.avi video file")
    rp.add_argument("--seed", type=nonneg_int, default=0, help="scene seed (default 0)")
    rp.add_argument("--frames", type=positive_int, metavar="N", help="stop after N frames (prefix included)")
    rp.add_argument("--empty-prefix", type=nonneg_int, default=0, metavar="N",
                    help="start with N frames of the empty room (background learning)")
    rp.add_argument("--fps", type=nonneg_float, metavar="HZ", help="resample the motion (default: its own rate)")
    rp.add_argument("--jitter", type=nonneg_float, default=0.0, metavar="PX",
                    help="camera wobble amplitude in pixels (default 0: tripod)")
    rp.add_argument("--no-noise", action="store_true",
                    help="clean renders: no sensor noise, exposure drift or vignetting")
    rp.add_argument("--in-place", action="store_true", help="remove the motion's horizontal travel")
    rp.add_argument("--masks", action="store_true", help="also write silhouette and part-label PNGs (folder output)")
    rp.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    return rp


def options_from_args(args: argparse.Namespace) -> RenderOptions:
    return RenderOptions(motion=args.bvh or args.script, out=args.out, seed=args.seed, frames=args.frames,
                         empty_prefix=args.empty_prefix, fps=args.fps, jitter_px=args.jitter, noise=not args.no_noise,
                         in_place=args.in_place, masks=args.masks, json=args.json)


def main(options: RenderOptions) -> int:
    """Render; a missing or unreadable motion or a bad output is one line on stderr and status 1."""
    from tracker_service.app.render import render_motion

    try:
        return render_motion(options)
    except (OSError, ValueError) as exc:
        print(f"mocap-tracker render: {exc}", file=sys.stderr)
        return 1
