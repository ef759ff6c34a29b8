"""``mocap-game``: the headless ninja game of Okada & Stenger §4, played with the body.

Subcommands
-----------
``recognize``
    Run the gesture recogniser offline over a gesture script (``--script``) or a BVH recording
    (``--bvh``) and print the recognised gestures (``--json``: ``{"events": [...], "frames": N}``).
``play``
    Play a whole round offline from a script or recording: the same recogniser and game as the live
    client, written to a JSON-lines log and optionally to rendered frames (PNG, GIF, MP4).
``run``
    The live client: subscribe to a tracker's poses over Zenoh, play, publish events and state on
    ``mocap/game/<id>/event`` and ``.../state``.

Exit status: 0 on success (including a clean stop by Ctrl-C / SIGTERM), 1 when the command failed
(one line on stderr says why), 2 for bad command-line arguments.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
from pathlib import Path
from typing import Any

from protocol.formats.load import load_motion
from protocol.kinematics import fk
from protocol.motion import Motion, resample
from protocol.net.cli_args import positive_float as _positive_float
from protocol.net.cli_args import positive_int as _positive_int
from protocol.net.session import add_zenoh_args, config_from_args, stop_on_signals
from protocol.wire.codec import ProtocolError
from protocol.wire.keys import ANY, DEFAULT_TRACKER_ID, validate_id

__all__ = ["build_parser", "main"]

PROG = "mocap-game"






def _id(allow_any: bool) -> Any:
    def check(text: str) -> str:
        try:
            return validate_id(text, allow_any=allow_any)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return check


def _add_source(p: argparse.ArgumentParser) -> None:
    src = p.add_argument_group("motion source (choose one)").add_mutually_exclusive_group(required=True)
    src.add_argument("--script", metavar="FILE", help="gesture script (.toml), e.g. game_client/scripts/strike.toml")
    src.add_argument("--bvh", metavar="FILE", help="BVH recording, retargeted onto the shared skeleton")
    p.add_argument("--rate", type=_positive_float, metavar="HZ",
                   help="resample the motion to this frame rate first (default: its own rate)")


def _version() -> str:
    """The installed ``mocap-service`` distribution's version."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("mocap-service")
    except PackageNotFoundError:
        return "0.1.0"


def build_parser() -> argparse.ArgumentParser:
    """The ``mocap-game`` argument parser (subcommands ``recognize``, ``play`` and ``run``)."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-v", "--verbose", action="count", default=0, help="more log output on stderr (-vv: debug)")
    common.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors on stderr")
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Headless ninja game played with the body (Okada & Stenger, section 4): five gestures - "
                    "transform (arms out, then onto the chest), crouch, side-step, strike (right arm up, "
                    "down fast), fire ring (both arms up, down fast) - recognised from tracked 3D joints.",
        epilog=f"Run '{PROG} <command> --help' for the options of a command.",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="<command>", required=True)

    rp = sub.add_parser("recognize", parents=[common], help="recognise gestures in a script or recording",
                        description="Run the gesture recogniser offline over a pose sequence and list the "
                                    "recognised gestures with their start and end (pose-stream seconds), "
                                    "confidence and latency (recognition minus end, ms).")
    _add_source(rp)
    rp.add_argument("--json", action="store_true",
                    help='print {"events": [{"gesture", "start_s", "end_s", "confidence", "latency_ms", '
                         '"direction", "t"}...], "frames": N}')
    rp.set_defaults(func=_cmd_recognize)

    pp = sub.add_parser("play", parents=[common], help="play a whole round offline from a script or recording",
                        description="Feed a script or recording frame by frame to the recogniser and the game "
                                    "(exactly as the live client does) and report the outcome.")
    _add_source(pp)
    pp.add_argument("--log", type=Path, metavar="PATH", help="write the round's JSON-lines log here")
    pp.add_argument("--frames-out", type=Path, metavar="DIR",
                    help="write rendered frames (frame_*.png, round.gif, round.mp4) into DIR")
    pp.add_argument("--fps", type=_positive_float, default=10.0, metavar="HZ",
                    help="rendered frames per second of game time (default: 10)")
    pp.add_argument("--json", action="store_true", help="print the round summary as JSON")
    pp.set_defaults(func=_cmd_play)

    up = sub.add_parser("run", parents=[common], help="play live from a tracker's pose stream over Zenoh",
                        description="Subscribe to mocap/tracker/<tracker>/pose, play the game and publish "
                                    "GameEvent messages on mocap/game/<id>/event and GameState on "
                                    "mocap/game/<id>/state. Undecodable messages are counted and skipped; a "
                                    "tracker restart does not end the round. Stops on Ctrl-C/SIGTERM, after "
                                    "--duration or --max-frames, or when the round is over (--exit-when-over).")
    up.add_argument("--id", type=_id(False), default=DEFAULT_TRACKER_ID,
                    help=f"game id in the key expressions (default: '{DEFAULT_TRACKER_ID}')")
    up.add_argument("--tracker", type=_id(True), default=DEFAULT_TRACKER_ID,
                    help=f"tracker id to follow, or '{ANY}' for any (default: '{DEFAULT_TRACKER_ID}')")
    up.add_argument("--follow", action="store_true",
                    help="follow the first tracker alive on the network instead of --tracker, and switch to "
                         "the next one when it stops (trackers announce themselves with a liveliness token)")
    up.add_argument("--log", type=Path, metavar="PATH", help="write the JSON-lines game log here")
    up.add_argument("--frames-out", type=Path, metavar="DIR", help="write rendered frames (PNG, GIF, MP4) into DIR")
    up.add_argument("--fps", type=_positive_float, default=10.0, metavar="HZ",
                    help="with --frames-out: rendered frames per second of game time (default: 10)")
    up.add_argument("--max-frames", type=_positive_int, metavar="N", help="stop after N pose frames")
    up.add_argument("--duration", type=_positive_float, metavar="S", help="stop after S seconds (wall clock)")
    up.add_argument("--exit-when-over", action="store_true", help="stop when the first round ends")
    up.add_argument("--json", action="store_true", help="print a JSON summary of the run on exit")
    add_zenoh_args(up, "subscriber")
    up.set_defaults(func=_cmd_run)
    return parser


def _setup_logging(args: argparse.Namespace) -> None:
    level = logging.WARNING if args.quiet else logging.INFO if args.verbose == 1 else \
        logging.DEBUG if args.verbose >= 2 else logging.WARNING
    logging.basicConfig(level=level, format=f"{PROG}: %(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    """Run ``mocap-game`` with ``argv`` (default ``sys.argv[1:]``) and return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    _setup_logging(args)
    try:
        return int(args.func(args))
    except (OSError, ValueError, ConnectionError, ProtocolError) as exc:
        print(f"{PROG} {args.command}: {exc}", file=sys.stderr)
    return 1


def _motion(args: argparse.Namespace) -> Motion:
    path = Path(args.script or args.bvh)
    if not path.is_file():
        raise FileNotFoundError(f"motion file not found: {path}")
    if args.script and path.suffix.lower() != ".toml":
        raise ValueError(f"{path}: a gesture script must be a .toml file")
    if args.bvh and path.suffix.lower() != ".bvh":
        raise ValueError(f"{path}: expected a .bvh file")
    motion = load_motion(path)
    return resample(motion, args.rate) if args.rate else motion


def _cmd_recognize(args: argparse.Namespace) -> int:
    from .gestures import recognize

    m = _motion(args)
    events = recognize(m.times, fk(m.poses, m.body), height_m=m.body.height)
    if args.json:
        print(json.dumps({"events": [e.to_json() for e in events], "frames": m.n_frames}))
        return 0
    print(f"{m.name}: {m.n_frames} frames at {m.fps:g} Hz ({m.duration:.2f} s), {len(events)} gesture(s)")
    for e in events:
        side = f" {e.direction}" if e.direction else ""
        print(f"  {e.gesture.value}{side:7s} {e.start_s:7.2f} - {e.end_s:7.2f} s  confidence {e.confidence:.2f}  "
              f"latency {e.latency_ms:5.0f} ms")
    return 0


def _cmd_play(args: argparse.Namespace) -> int:
    from .app import FrameSink
    from .round import GameRound

    m = _motion(args)
    joints = fk(m.poses, m.body)
    rnd = GameRound(height_m=m.body.height)
    sink = FrameSink(args.frames_out, rnd.game.config, args.fps) if args.frames_out else None
    fh = args.log.open("w", encoding="utf-8") if args.log else None
    try:
        for k, t in enumerate(m.times):
            res = rnd.feed(float(t), joints[k])
            if fh is not None:
                fh.writelines(json.dumps(r) + "\n" for r in res.log)
            if sink is not None:
                sink.note(res.game_t, res.gestures, res.events)
                sink.maybe_draw(rnd.game.snapshot(), joints[k])
        summary = rnd.summary()
        if fh is not None:
            fh.write(json.dumps(summary) + "\n")
    finally:
        if fh is not None:
            fh.close()
        written = sink.close() if sink is not None else []
    if args.json:
        print(json.dumps({**summary, "files": [str(p) for p in written]}))
    else:
        outcome = f"{summary['winner']} wins by {summary['reason']}" if summary["winner"] else "round not finished"
        print(f"{m.name}: {outcome}; player {summary['player_health']:.0f} HP, opponent "
              f"{summary['opponent_health']:.0f} HP after {summary['t']:.1f} s; gestures {summary['gestures']}")
        for p in written:
            print(f"  wrote {p}")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from .app import AppOptions, run_game

    options = AppOptions(game_id=args.id, tracker_id=args.tracker, log_path=args.log, frames_out=args.frames_out,
                         frames_fps=args.fps, max_frames=args.max_frames, duration=args.duration,
                         exit_when_over=args.exit_when_over, follow=args.follow)
    conf = config_from_args(args, role="subscriber")
    with stop_on_signals(threading.Event()) as stop:
        result = run_game(conf, options, stop)
    if args.json:
        print(json.dumps({"frames": result.frames, "events": result.events, "rounds": result.rounds,
                          "reason": result.reason, "counters": result.counters, "summaries": result.summaries}))
    return 0
