"""Process entry point of ``mocap-tracker`` (and ``python -m tracker_service``).

A stop signal that arrives while the interpreter is still importing numpy, numba and zenoh (up to
a second or two on a loaded machine, before any command has installed its own handlers) must end
the process as cleanly as one that arrives later: exit status 0, nothing declared yet. This module
imports only the standard library and turns SIGTERM into ``SystemExit(0)`` from the start. The
handler stays for the long-running commands (``run``, ``replay``, ``demo``) until they install
:func:`protocol.net.session.stop_on_signals`; for the others (``build-db``, ``train-appearance``,
``eval``, ``render``) the command line puts SIGTERM's default action back once the arguments are
parsed (:func:`default_sigterm`, handed to :func:`tracker_service.app.cli.main`), since one killed
half-way must not report success. A Ctrl-C while importing gives status 130, as it does later
before a command has installed its handlers.

The command line is imported inside :func:`main`, after the handler is installed; it does not
import this module.
"""

from __future__ import annotations

import signal
import sys
from types import FrameType

__all__ = ["default_sigterm", "main", "single_threaded_blas"]

#: Environment variables that set the BLAS libraries' and OpenCV's thread counts.
_BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")
#: Batch commands that may use every core (the per-frame ones run BLAS on one thread).
_BATCH_COMMANDS = frozenset({"build-db", "train-appearance"})


def single_threaded_blas() -> None:
    """Run numpy's matrix products and OpenCV's functions on one thread unless the user says
    otherwise (call before numpy and cv2 are imported). The tracker's budget is one core per frame,
    its products are small (the appearance cue's network in numpy: 1.9 ms a frame on one thread,
    4.4 ms with OpenBLAS's default two threads on a 2-core machine), and a second thread only
    contends with the rest of the pipeline and any other process."""
    import os

    for name in _BLAS_THREADS:
        os.environ.setdefault(name, "1")


def _stop_during_import(signum: int, _frame: FrameType | None) -> None:
    raise SystemExit(0)


def default_sigterm() -> None:
    """Give SIGTERM its default action back if this module's start-up handler is still installed
    (called by the command line for the commands that have no clean stop of their own; a no-op
    when the handler is not installed, e.g. when the command line runs in-process in tests)."""
    if signal.getsignal(signal.SIGTERM) is _stop_during_import:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def main(argv: list[str] | None = None) -> int:
    """Install the start-up SIGTERM handler, then run the command line.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.

    Returns
    -------
    int
        The exit status of :func:`tracker_service.app.cli.main`; 130 after a Ctrl-C while importing
        (a SIGTERM before a command's own handlers exits with status 0 by ``SystemExit``).
    """
    signal.signal(signal.SIGTERM, _stop_during_import)
    args = sys.argv[1:] if argv is None else argv
    if not (args and args[0] in _BATCH_COMMANDS):
        single_threaded_blas()
    try:
        from tracker_service.app.cli import main as cli_main
    except KeyboardInterrupt:  # Ctrl-C while importing
        print("mocap-tracker: interrupted", file=sys.stderr)
        return 130
    return cli_main(argv, default_sigterm=default_sigterm)


if __name__ == "__main__":
    sys.exit(main())
