"""``mocap-cloth``: an avatar that moves with the player, dressed in simulated cloth.

Subcommands
-----------
``simulate``
    Offline: dress the avatar of a recording (``--bvh``) or gesture script (``--script``) in a cape
    or skirt, simulate it, optionally render a video, and print speed and quality figures
    (``--json`` for machines).
``run``
    Live: subscribe to a tracker's poses and body over Zenoh and simulate the garment as the poses
    arrive; optionally render frames / a video and publish the cloth mesh.

Exit status: 0 on success (including a clean stop by Ctrl-C / SIGTERM), 1 when the command failed
(one line on stderr says why), 2 for bad command-line arguments.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import sys
import threading
from pathlib import Path
from typing import Any

from cloth_client.solver.garment import DEFAULT_PARTICLES, GARMENTS
from protocol.wire.keys import DEFAULT_TRACKER_ID, validate_id

__all__ = ["build_parser", "main"]

PROG = "mocap-cloth"


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text!r}")
    return value


def _particles(text: str) -> int:
    n = _positive_int(text)
    if not 100 <= n <= 50_000:
        raise argparse.ArgumentTypeError(f"particle count must be between 100 and 50000, got {n}")
    return n


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 640x480, got {text!r}") from None
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise argparse.ArgumentTypeError(f"size out of range: {text!r}")
    return w, h


def _tracker_id(text: str) -> str:
    try:
        return validate_id(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _version() -> str:
    """The installed ``mocap-service`` distribution's version."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("mocap-service")
    except PackageNotFoundError:
        return "0.1.0"


def build_parser() -> argparse.ArgumentParser:
    """The ``mocap-cloth`` argument parser (subcommands ``simulate`` and ``run``)."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--garment", choices=GARMENTS, default="cape",
                        help="cape (pinned at the collar) or skirt (pinned at the waist); default cape")
    common.add_argument("--particles", type=_particles, default=DEFAULT_PARTICLES, metavar="N",
                        help=f"approximate number of cloth particles (default {DEFAULT_PARTICLES})")
    common.add_argument("--video", type=Path, metavar="PATH",
                        help="render avatar + cloth to PATH: .mp4 (H.264) or .gif")
    common.add_argument("--video-fps", type=_positive_float, default=30.0, metavar="HZ",
                        help="frame rate of rendered frames and videos (default 30)")
    common.add_argument("--size", type=_size, default=(480, 480), metavar="WxH",
                        help="rendered image size (default 480x480)")
    common.add_argument("--json", action="store_true", help="print the result as one JSON object")
    common.add_argument("--log-level", default="WARNING",
                        choices=("DEBUG", "INFO", "WARNING", "ERROR"), help="logging level (default WARNING)")

    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Dress the tracked (or recorded) person's avatar in a simulated cape or skirt: a "
                    "mass-spring cloth with strain limiting and body collision, rendered offscreen.",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="<command>", required=True)

    sp = sub.add_parser(
        "simulate", parents=[common], help="simulate a garment on a recording or gesture script (offline)",
        description="Simulate a garment on every frame of a recording or script and report speed and "
                    "quality: steps_per_s, particles, realtime_factor, max/mean penetration (mm), "
                    "max_strain, energy_drift, nan, ...",
    )
    src = sp.add_argument_group("motion source (choose one)").add_mutually_exclusive_group(required=True)
    src.add_argument("--bvh", type=Path, metavar="FILE", help="BVH recording (retargeted onto the shared skeleton)")
    src.add_argument("--script", type=Path, metavar="FILE", help="gesture script (.toml)")
    sp.add_argument("--fps", type=_positive_float, metavar="HZ",
                    help="resample the motion to HZ frames per second (default: its own rate)")
    sp.add_argument("--start", type=float, default=0.0, metavar="S",
                    help="skip the first S seconds of the motion (default 0)")
    sp.add_argument("--max-frames", type=_positive_int, metavar="N", help="simulate only the first N frames")
    sp.add_argument("--no-progress", action="store_true", help="no progress bar")
    sp.set_defaults(func=_cmd_simulate)

    rp = sub.add_parser(
        "run", parents=[common], help="live: simulate the garment on a tracker's poses received over Zenoh",
        description="Subscribe to mocap/tracker/<id>/pose and .../body, simulate the garment on every "
                    "pose, and optionally render frames, a video and publish the mesh on "
                    "mocap/cloth/<id>/mesh. Stops on Ctrl-C / SIGTERM, --max-frames or --duration.",
    )
    rp.add_argument("--id", type=_tracker_id, default=DEFAULT_TRACKER_ID,
                    help=f"tracker id to follow (default '{DEFAULT_TRACKER_ID}')")
    rp.add_argument("--follow", action="store_true",
                    help="follow the first tracker alive on the network instead of --id, and switch to the next "
                         "one when it stops (the mesh is still published under --id)")
    rp.add_argument("--frames-out", type=Path, metavar="DIR", help="write rendered frames as PNG files into DIR")
    rp.add_argument("--publish-mesh", action="store_true",
                    help="publish the cloth vertices on mocap/cloth/<id>/mesh for another viewer")
    rp.add_argument("--max-frames", type=_positive_int, metavar="N", help="stop after simulating N poses")
    rp.add_argument("--duration", type=_positive_float, metavar="S", help="stop after S seconds")
    from protocol.net.session import add_zenoh_args

    add_zenoh_args(rp, "subscriber")
    rp.set_defaults(func=_cmd_run)
    return parser


def _emit(args: argparse.Namespace, result: dict[str, Any], lines: list[str]) -> None:
    if args.json:
        print(json.dumps(result))
    else:
        for line in lines:
            print(line)


def _cmd_simulate(args: argparse.Namespace) -> int:
    from cloth_client.app.offline import simulate_motion
    from protocol.formats.load import load_motion

    path = args.bvh if args.bvh is not None else args.script
    if not path.is_file():
        print(f"{PROG} simulate: file not found: {path}", file=sys.stderr)
        return 1
    try:
        motion = load_motion(path, fps=args.fps)
    except (OSError, ValueError) as exc:
        print(f"{PROG} simulate: cannot read {path}: {exc}", file=sys.stderr)
        return 1
    if args.start > 0.0:
        first = round(args.start * motion.fps)
        if not 0 <= first < motion.n_frames - 1:
            print(f"{PROG} simulate: --start {args.start} s is beyond the motion ({motion.duration:.2f} s)",
                  file=sys.stderr)
            return 1
        valid = None if motion.valid is None else motion.valid[first:]
        motion = dataclasses.replace(motion, poses=motion.poses[first:], valid=valid)
    long_run = motion.duration * args.particles > 5.0 * DEFAULT_PARTICLES  # more than a few seconds
    result = simulate_motion(motion, args.garment, particles=args.particles, video=args.video,
                             video_fps=args.video_fps, size=args.size, max_frames=args.max_frames,
                             progress=long_run and not args.no_progress and not args.json)
    _emit(args, result, [
        f"{result['garment']} ({result['particles']} particles) on {path.name}: {result['frames']} frames, "
        f"{result['sim_time_s']:.2f} s simulated in {result['wall_s']:.2f} s "
        f"(real-time factor {result['realtime_factor']}, {result['steps_per_s']} substeps/s)",
        f"penetration max {result['max_penetration_mm']:.2f} mm, mean {result['mean_penetration_mm']:.2f} mm; "
        f"max strain {100 * result['max_strain']:.1f} %; energy drift {result['energy_drift']:.2e}; "
        f"resets {result['resets']}; NaN {'yes' if result['nan'] else 'no'}",
        *([f"video: {result['video']}"] if "video" in result else []),
    ])
    return 1 if result["nan"] else 0


def _cmd_run(args: argparse.Namespace) -> int:
    from cloth_client.app.live import LiveOptions, run_live
    from protocol.net.session import config_from_args, stop_on_signals

    opts = LiveOptions(tracker_id=args.id, garment=args.garment, particles=args.particles,
                       frames_out=args.frames_out, video=args.video, video_fps=args.video_fps, size=args.size,
                       publish_mesh=args.publish_mesh, max_frames=args.max_frames, duration=args.duration,
                       follow=args.follow)
    try:
        conf = config_from_args(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"{PROG} run: {exc}", file=sys.stderr)
        return 1
    with stop_on_signals(threading.Event()) as stop:
        try:
            result = run_live(conf, opts, stop)
        except ConnectionError as exc:
            print(f"{PROG} run: {exc}", file=sys.stderr)
            return 1
    d = result.as_dict()
    _emit(args, d, [f"{PROG} run: {d['frames']} poses simulated, {d['rendered']} frames rendered, "
                    f"{d['published']} meshes published, {d['malformed']} malformed messages; "
                    f"max strain {100 * d['max_strain']:.1f} %, max penetration {d['max_penetration_mm']:.1f} mm "
                    f"(stopped: {d['reason']})"])
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``mocap-cloth`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=getattr(logging, args.log_level), format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        return 0
