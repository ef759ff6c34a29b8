"""``mocap-tracker bench``: the pose estimators on the very same rendered silhouettes, with a table
and plots (:mod:`tracker_service.app.estimator_bench`).

::

    mocap-tracker bench [--estimators tree,condensation,drs,srs,elmo] [--bvh FILE ...] [--take NAME]
                        [--frames N] [--step K] [--subject BODY] [--seed S] [--repeats R] [--joint NAME]
                        [--no-plots] --out DIR

Exit status 0, or 1 with a one-line reason on stderr.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

from protocol.net.cli_args import nonneg_int, positive_int
from tracker_service.app.commands.common import UsageError
from tracker_service.app.estimator_bench import ESTIMATOR_NAMES, BenchOptions

__all__ = ["CLEAN_STOP", "NAME", "add_parser", "main", "options_from_args"]

NAME = "bench"
CLEAN_STOP = False


def add_parser(sub: Any, parents: Sequence[argparse.ArgumentParser] = ()) -> argparse.ArgumentParser:
    """Add ``bench`` to ``sub`` (from ``ArgumentParser.add_subparsers``)."""
    d = BenchOptions()
    bp = sub.add_parser(
        NAME, parents=list(parents), help="compare the pose estimators on the same rendered silhouettes",
        description="Build a small template database (4 takes, body mMA), render a clip's capsule "
                    "silhouettes once and run each estimator on the very same frames. Writes "
                    "DIR/table.md, DIR/table.json (MPJPE, frames within 10 cm, ms a frame, likelihood "
                    "evaluations a frame, ratios to the tree filter) and PNG plots: error per frame, "
                    "error per joint, and one joint's angle over --repeats DRS/SRS runs.")
    bp.add_argument("--estimators", default=",".join(d.estimators), metavar="NAMES",
                    help=f"comma-separated, from {', '.join(ESTIMATOR_NAMES)} (default: %(default)s)")
    src = bp.add_mutually_exclusive_group()
    src.add_argument("--bvh", nargs="+", metavar="FILE", help="BVH files, one clip each")
    src.add_argument("--take", metavar="NAME", help="a recording of the index, by file name "
                                                    "(default: the database's first take)")
    bp.add_argument("--frames", type=positive_int, default=d.frames, metavar="N",
                    help="frames evaluated per clip, after --step (default: %(default)s)")
    bp.add_argument("--step", type=positive_int, default=d.step, metavar="K",
                    help="take every K-th frame of the 30 Hz motion (default: %(default)s)")
    bp.add_argument("--subject", default=d.subject, metavar="BODY",
                    help="body model rendered (the database's is mMA)")
    bp.add_argument("--seed", type=nonneg_int, default=d.seed, help="seed of the stochastic estimators")
    bp.add_argument("--repeats", type=positive_int, default=d.repeats, metavar="R",
                    help="DRS/SRS runs with seeds S, S+1, ... (default: %(default)s)")
    bp.add_argument("--joint", default=d.joint, metavar="NAME",
                    help="joint whose bend angle the spread plot shows (default: %(default)s)")
    bp.add_argument("--no-plots", action="store_true", help="only table.md and table.json")
    bp.add_argument("--out", required=True, metavar="DIR", help="output folder")
    return bp


def options_from_args(args: argparse.Namespace) -> BenchOptions:
    names = tuple(n.strip() for n in args.estimators.split(",") if n.strip())
    bad = [n for n in names if n not in ESTIMATOR_NAMES]
    if bad or not names:
        raise UsageError(f"--estimators: unknown {bad or args.estimators!r}; choose from {', '.join(ESTIMATOR_NAMES)}")
    if len(set(names)) != len(names):
        raise UsageError("--estimators: a name is repeated")
    return BenchOptions(estimators=names, out=args.out, bvh=tuple(args.bvh or ()), take=args.take,
                        frames=args.frames, step=args.step, subject=args.subject, seed=args.seed,
                        repeats=args.repeats, joint=args.joint, plots=not args.no_plots)


def main(options: BenchOptions) -> int:
    """Run the benchmark, print the table and the files written."""
    from tracker_service.app.estimator_bench import main_options

    table, written = main_options(options, lambda msg: print(f"mocap-tracker bench: {msg}", file=sys.stderr))
    print(table)
    for path in written:
        print(f"wrote {path}")
    return 0
