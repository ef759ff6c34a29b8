"""The ``mocap-tracker`` commands, one module each; :mod:`tracker_service.app.cli` assembles them.

Every command module has

* ``NAME``: the command's name on the command line;
* ``CLEAN_STOP``: whether it installs :func:`protocol.net.session.stop_on_signals` and exits 0 on
  SIGTERM (otherwise the command line gives SIGTERM its default action back once it has parsed);
* ``add_parser(sub, parents)``: adds the command's sub-parser (``--help`` text, options);
* ``options_from_args(args)``: the only place that reads the command's ``argparse.Namespace``; it
  returns the command's frozen options (:mod:`tracker_service.app.options`) and raises
  :class:`~tracker_service.app.commands.common.UsageError` for arguments the parser cannot check;
* ``main(options)``: runs the command and returns the exit status.

The modules import only the command line's own light dependencies at module level; the pipeline,
the renderer and the daemons are imported when a command runs.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any, Protocol

__all__ = ["Command"]


class Command(Protocol):
    """What :mod:`tracker_service.app.cli` needs of a command module."""

    NAME: str
    CLEAN_STOP: bool

    def add_parser(self, sub: Any, parents: Sequence[argparse.ArgumentParser]) -> argparse.ArgumentParser: ...

    def options_from_args(self, args: argparse.Namespace) -> Any: ...

    def main(self, options: Any) -> int: ...
