"""Process entry point of ``mocap-tracker`` (and ``python -m tracker_service``).

A stop signal that arrives while the interpreter is still importing numpy, numba and zenoh (up to
a second or two on a loaded machine, before any command has installed its own handlers) must end
the process as cleanly as one that arrives later: exit status 0, nothing declared yet. This module
imports only the standard library and, while :mod:`tracker_service.cli` is being imported, turns
SIGTERM into ``SystemExit(0)``; a Ctrl-C then gives status 130, as it does later before a command
has installed its handlers. Afterwards SIGTERM's default action is back (a ``build-db`` or
``eval`` killed half-way must not report success) until a long-running command (``run``,
``replay``, ``demo``) installs :func:`protocol.session.stop_on_signals` as its first step.
"""

from __future__ import annotations

import signal
import sys
from types import FrameType

__all__ = ["main"]


def _stop_during_import(signum: int, _frame: FrameType | None) -> None:
    raise SystemExit(0)


def main(argv: list[str] | None = None) -> int:
    """Install the early SIGTERM handler, then run the command line.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.

    Returns
    -------
    int
        The exit status of :func:`tracker_service.cli.main`; 130 after a Ctrl-C while importing
        (a SIGTERM then exits with status 0 by ``SystemExit``).
    """
    previous = signal.signal(signal.SIGTERM, _stop_during_import)
    try:
        from .cli import main as cli_main
    except KeyboardInterrupt:  # Ctrl-C while importing
        print("mocap-tracker: interrupted", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    return cli_main(argv)


if __name__ == "__main__":
    sys.exit(main())
