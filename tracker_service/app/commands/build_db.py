"""``mocap-tracker build-db``: build the template database of one or more body models (cached under
``out/db``)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tracker_service.app.commands.common import script_dirs
from tracker_service.app.options import BuildDbOptions
from tracker_service.app.resources import DEFAULT_BODY

__all__ = ["CLEAN_STOP", "NAME", "add_parser", "main", "options_from_args"]

NAME = "build-db"
CLEAN_STOP = False


def _bodies(text: str) -> list[str]:
    from tracker_service.body.family import BODY_MODELS

    names = [m.name for m in BODY_MODELS]
    if text == "all":
        return names
    out = [t.strip() for t in text.split(",") if t.strip()]
    bad = [t for t in out if t not in names]
    if bad or not out:
        raise argparse.ArgumentTypeError(
            f"unknown body model(s) {bad or text!r}; choose from {', '.join(names)} or all")
    return out


def add_parser(sub: Any, parents: Sequence[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Add ``build-db`` to the ``mocap-tracker`` subparsers."""
    bp = sub.add_parser(NAME, parents=list(parents), help="build the template database (cached in out/db)",
                        description="Poses of the shared recordings (held-out takes excluded, see docs/TRACKER.md) "
                                    "pruned at 5 degrees, headings augmented, rendered as run-length silhouettes "
                                    "on the 80x60/160x120/320x240 pyramid, clustered by Algorithm 1 into a "
                                    "3-level tree, with leaf transition histograms. One folder per body model.")
    bp.add_argument("--mocap", metavar="DIR", help="recordings folder (default: ../shared/mocap or $MOCAP_DATA)")
    bp.add_argument("--bodies", type=_bodies, default=[DEFAULT_BODY], metavar="NAMES|all",
                    help=f"comma-separated body models, or all 30 (default: {DEFAULT_BODY})")
    bp.add_argument("--scripts", metavar="DIR", action="append", default=None,
                    help="add the poses of every gesture script (*.toml) in DIR (repeatable; default: "
                         "the game's and protocol's bundled scripts, as the paper's game database "
                         "was built from the game's motions)")
    bp.add_argument("--no-scripts", action="store_true", help="recordings only")
    bp.add_argument("--out", metavar="PATH", help="output folder (default: out/db/<body>; with several "
                                                   "bodies, a parent folder)")
    bp.add_argument("--max-poses", type=int, metavar="N", help="cap the pruned pose set (quick builds)")
    bp.add_argument("--takes", type=int, metavar="N", help="use only the first N training takes (quick builds)")
    return bp


def options_from_args(args: argparse.Namespace) -> BuildDbOptions:
    return BuildDbOptions(bodies=tuple(args.bodies), mocap=args.mocap, scripts=script_dirs(args), out=args.out,
                          max_poses=args.max_poses, takes=args.takes)


def main(options: BuildDbOptions) -> int:
    """Build each body model's database and print one line per body."""
    from tracker_service.app.resources import build_database
    from tracker_service.templates.database import default_db_dir

    several = len(options.bodies) > 1
    for name in options.bodies:
        out = Path(options.out) / name if (options.out and several) else Path(options.out or default_db_dir(name))
        meta = build_database(name, out, options)
        s = meta["stats"]
        print(f"{name}: {int(s['poses'])} poses from {int(s['frames'])} frames; tree "
              f"{int(s['level1_nodes'])}/{int(s['level2_nodes'])}/{int(s['level3_nodes'])} nodes; "
              f"{meta['build_s']:.0f} s -> {out}")
    return 0
