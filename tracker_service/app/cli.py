"""``mocap-tracker``: the command line of the tracker service, assembled from one module per command
(:mod:`tracker_service.app.commands`).

Subcommands
-----------
``replay``            publish a recorded or scripted motion as a live pose stream.
``demo``              what ``make demo`` runs: the tracker (or a replay) in a child process and a
                      subscriber here that prints what arrives.
``build-db``          build the template database (cached under ``out/db``).
``train-appearance``  train the appearance cue's network (cached under ``out/appearance``).
``run``               the tracker daemon: frames -> poses over Zenoh.
``eval``              track a motion rendered as synthetic video; print the errors as JSON.
``render``            render the synthetic camera view of a motion to images or a video.
``record``            subscribe to a tracker's poses and write the session as BVH, JSON lines and CSV.
``calibrate``         make the camera file ``run``/``eval --camera`` read, from checkerboard images.
``list``              the trackers publishing on the network.
``bench``             compare the pose estimators on the same rendered silhouettes (table and plots).

Exit status: 0 on success (including a clean stop by Ctrl-C / SIGTERM), 1 when the command failed
(one line on stderr says why), 2 for bad command-line arguments.

The process entry point is :mod:`tracker_service.app.entry`, which imports this module only once its
start-up signal handling is in place and hands :func:`main` the function that gives SIGTERM its
default action back (this module does not import it).
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable

from protocol.wire.codec import ProtocolError
from tracker_service.app.commands import (
    Command,
    bench,
    build_db,
    calibrate,
    demo,
    list_trackers,
    record,
    render,
    replay,
    run,
    train_appearance,
)
from tracker_service.app.commands import eval as eval_command
from tracker_service.app.commands.common import UsageError

__all__ = ["COMMANDS", "PROG", "build_parser", "main", "version"]

PROG = "mocap-tracker"
#: The commands in the order ``--help`` lists them.
COMMANDS: tuple[Command, ...] = (replay, demo, build_db, train_appearance, run, eval_command, render, record, calibrate,
                                 list_trackers, bench)
_BY_NAME: dict[str, Command] = {c.NAME: c for c in COMMANDS}


def version() -> str:
    """The installed ``mocap-service`` distribution's version (``protocol.__version__`` or 0.1.0 when
    the package runs from a checkout that is not installed)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("mocap-service")
    except PackageNotFoundError:
        import protocol

        return str(getattr(protocol, "__version__", "0.1.0"))


def build_parser() -> argparse.ArgumentParser:
    """The ``mocap-tracker`` argument parser with every subcommand."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log output on stderr (-vv for debug)")
    common.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors on stderr")
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Single-camera motion capture service: tracks (or replays) a person's pose and "
                    "streams it over Eclipse Zenoh on mocap/tracker/<id>/pose.",
        epilog=f"Run '{PROG} <command> --help' for the options of a command.",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {version()}")
    sub = parser.add_subparsers(dest="command", metavar="<command>", required=True)
    for command in COMMANDS:
        command.add_parser(sub, [common])
    return parser


def _setup_logging(verbose: int, quiet: bool) -> None:
    level = logging.WARNING if quiet else logging.INFO if verbose < 2 else logging.DEBUG
    logging.basicConfig(level=level, format=f"{PROG}: %(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    # PyOpenGL says at INFO whether its OpenGL_accelerate module loaded (OpenGL.acceleratesupport): only -vv shows it
    logging.getLogger("OpenGL").setLevel(logging.WARNING if verbose < 2 else logging.DEBUG)


def main(argv: list[str] | None = None, *, default_sigterm: Callable[[], None] | None = None) -> int:
    """Run ``mocap-tracker`` with ``argv`` (default ``sys.argv[1:]``) and return the exit status.

    Parameters
    ----------
    argv : list of str, optional
    default_sigterm : callable, optional
        Called once the arguments are parsed for a command without a clean stop of its own
        (``CLEAN_STOP`` false: build-db, train-appearance, eval, render), so that a SIGTERM ends it
        with its usual status; :mod:`tracker_service.app.entry` passes
        :func:`~tracker_service.app.entry.default_sigterm`.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    command = _BY_NAME[args.command]
    if default_sigterm is not None and not command.CLEAN_STOP:
        default_sigterm()
    _setup_logging(args.verbose, args.quiet)
    try:
        options = command.options_from_args(args)
    except UsageError as exc:
        parser.error(str(exc))
    try:
        return int(command.main(options))
    except KeyboardInterrupt:  # only before a command installed its own signal handlers
        print(f"{PROG} {command.NAME}: interrupted", file=sys.stderr)
        return 130
    except NotImplementedError as exc:
        print(f"{PROG} {command.NAME}: not available yet: {exc}", file=sys.stderr)
    except (OSError, ValueError, ConnectionError, ProtocolError, RuntimeError) as exc:
        print(f"{PROG} {command.NAME}: {exc}", file=sys.stderr)
    return 1
