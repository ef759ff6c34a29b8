"""``mocap-tracker train-appearance``: train the appearance cue's network (cached under
``out/appearance``; :mod:`tracker_service.app.appearance_training`)."""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tracker_service.app.commands.common import script_dirs
from tracker_service.app.options import Passes, TrainAppearanceOptions

__all__ = ["CLEAN_STOP", "NAME", "add_parser", "main", "options_from_args", "parse_passes"]

NAME = "train-appearance"
CLEAN_STOP = False


def parse_passes(text: str) -> Passes:
    """``argparse`` type of ``--passes``: ``SEED:EVERY,...`` per network, networks separated by ``;``."""
    try:
        out = tuple(tuple((int(a), int(b)) for a, b in (t.split(":") for t in group.split(",") if t.strip()))
                    for group in text.split(";"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SEED:EVERY[,SEED:EVERY...][;...], got {text!r}") from None
    if not out or any(not g or any(every < 1 for _, every in g) for g in out):
        raise argparse.ArgumentTypeError(f"expected SEED:EVERY pairs with EVERY >= 1, got {text!r}")
    return out


def add_parser(sub: Any, parents: Sequence[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Add ``train-appearance`` to the ``mocap-tracker`` subparsers."""
    ap = sub.add_parser(NAME, parents=list(parents),
                        help="train the appearance cue's network (cached in out/appearance)",
                        description="Render the training recordings (held-out takes excluded) on random synthetic "
                                    "people and train the small network that reads the joints' depth from the "
                                    "person's colour image (docs/TRACKER.md). Needs PyTorch; the "
                                    "tracker itself does not.")
    ap.add_argument("--out", metavar="PATH", help="network file (default: out/appearance/net.npz)")
    ap.add_argument("--mocap", metavar="DIR", help="recordings folder (default: ../shared/mocap or $MOCAP_DATA)")
    ap.add_argument("--epochs", type=int, metavar="N", help="training epochs (default: 15)")
    ap.add_argument("--width", type=int, metavar="C",
                    help="channels of the first convolution, the others 2, 4, 8 and 8 times it (default: 24)")
    ap.add_argument("--passes", type=parse_passes, metavar="SEED:EVERY,...[;...]",
                    help="one pass per pair: every take on the person SEED+row chooses, every EVERY-th frame; "
                         "one list per network, separated by ';' (default: 1000:3,2000:2,3000:2,4000:2 for the "
                         "first, 5000:2,6000:2,2000:2,3000:2 for the second)")
    pg = ap.add_mutually_exclusive_group()
    pg.add_argument("--posture-passes", type=parse_passes, metavar="SEED:EVERY,...[;...]",
                    help="more passes with the poses varied (stooped, knees bent: tracker_service/build/"
                         "posture_variation.py), one list per network (default: 7000:3 for the first, 8000:3 "
                         "for the second, none for more)")
    pg.add_argument("--no-posture", action="store_true", help="no posture-varied passes")
    vg = ap.add_mutually_exclusive_group()
    vg.add_argument("--vary-passes", type=parse_passes, metavar="SEED:EVERY,...[;...]",
                    help="more passes in a randomised scene: each take varied along one or two of the axes body, "
                         "clothing, appearance, backdrop, lights, sensor, compression (tracker_service/scene/"
                         "variation.py), one list per network (default: 9000:3 for the first, 10000:3 for the "
                         "second, none for more)")
    vg.add_argument("--no-vary", action="store_true", help="no randomised-scene passes")
    ap.add_argument("--members", type=int, metavar="N",
                    help="networks in the ensemble, each trained on its own passes with its own initial weights "
                         "(default: as many as --passes lists, else 2)")
    ap.add_argument("--takes", type=int, metavar="N",
                    help="use only the first N training recordings (quick builds; the scripts are added)")
    sg = ap.add_mutually_exclusive_group()
    sg.add_argument("--scripts", metavar="DIR", action="append", default=None,
                    help="also train on every gesture script (*.toml) in DIR (repeatable; default: the game's "
                         "and protocol's bundled scripts, the motions build-db adds to the database)")
    sg.add_argument("--no-scripts", action="store_true", help="recordings only")
    ap.add_argument("--masks", choices=("subtracted", "truth"), default=None,
                    help="the silhouette each training view is cropped and masked with: the tracker's own background "
                         "subtraction (what the network reads when tracking) or the renderer's exact one (default: "
                         "subtracted)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, metavar="J",
                    help="rendering processes (default: the CPUs)")
    return ap


def options_from_args(args: argparse.Namespace) -> TrainAppearanceOptions:
    return TrainAppearanceOptions(
        out=args.out, mocap=args.mocap, epochs=args.epochs, width=args.width, passes=args.passes,
        posture_passes=() if args.no_posture else args.posture_passes,
        vary_passes=() if args.no_vary else args.vary_passes, members=args.members, takes=args.takes,
        scripts=script_dirs(args), jobs=args.jobs, masks=args.masks)


def _check(options: TrainAppearanceOptions) -> None:
    """0 or less is an error, not "the default"."""
    for flag, value in (("--jobs", options.jobs), ("--epochs", options.epochs), ("--takes", options.takes),
                        ("--width", options.width), ("--members", options.members)):
        if value is not None and value < 1:
            raise ValueError(f"{flag} must be >= 1, got {value}")


def main(options: TrainAppearanceOptions) -> int:
    """Train the network and print each member's validation figures."""
    from tracker_service.app.appearance_training import train_appearance
    from tracker_service.cues.appearance import default_appearance_path

    out = Path(options.out) if options.out else default_appearance_path()
    _check(options)
    meta = train_appearance(out, options)
    for i, m in enumerate(meta.get("members") or [meta]):
        val = ("validation RMS x / y / z " + " / ".join(f"{100 * m[c]:.1f}" for c in ("val_rms_x", "val_rms_y",
                                                                                      "val_rms_z"))
               + " % of the height" if "val_rms_z" in m else "no validation takes")
        print(f"appearance network {i + 1}: {m['samples']} training views, {val}")
    print(f"{meta['training_takes']} training takes and {len(meta['scripts'])} gesture scripts; "
          f"rendering {meta['render_s']:.0f} s, training "
          f"{meta['train_s']:.0f} s -> {out}")
    return 0
