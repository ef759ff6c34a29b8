"""``mocap-tracker build-db``, ``run`` and ``eval``: argument parsing and wiring (the I/O edge).

``build-db``  builds the template database of one or more body models (cached under ``out/db``).
``run``       the tracker daemon: a frame source -> pipeline -> Zenoh (see :mod:`.tracker_app`).
``eval``      renders the synthetic scene for a motion, tracks it and prints the JSON contract of
              :func:`tracker_service.app.evaluate.evaluate_motion`.
``train-appearance``  trains the appearance cue's network (cached under ``out/appearance``).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, TypeGuard

from protocol.net.session import add_zenoh_args

__all__ = ["DEFAULT_SCRIPT", "add_tracker_parsers", "ensure_appearance", "ensure_db"]

from tracker_service.paths import REPO_ROOT

log = logging.getLogger(__name__)

_REPO = REPO_ROOT
#: Motion of ``--source synthetic`` without a file: a shipped gesture script.
DEFAULT_SCRIPT = _REPO / "protocol" / "scripts" / "crouch.toml"
#: Gesture scripts added to the default database: motions the recordings lack (crouch, side-steps,
#: the game's gestures and near-misses). Data files only: the tracker does not import the game.
DEFAULT_SCRIPT_DIRS = (_REPO / "protocol" / "scripts", _REPO / "game_client" / "scripts")
_DEFAULT_BODY = "mMA"


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


def add_tracker_parsers(sub: Any, parents: Sequence[argparse.ArgumentParser]) -> None:
    """Add ``build-db``, ``run`` and ``eval`` to the ``mocap-tracker`` subparsers."""
    bp = sub.add_parser("build-db", parents=list(parents), help="build the template database (cached in out/db)",
                        description="Poses of the shared recordings (held-out takes excluded, see docs/TRACKER.md) "
                                    "pruned at 5 degrees, headings augmented, rendered as run-length silhouettes "
                                    "on the 80x60/160x120/320x240 pyramid, clustered by Algorithm 1 into a "
                                    "3-level tree, with leaf transition histograms. One folder per body model.")
    bp.add_argument("--mocap", metavar="DIR", help="recordings folder (default: ../shared/mocap or $MOCAP_DATA)")
    bp.add_argument("--bodies", type=_bodies, default=[_DEFAULT_BODY], metavar="NAMES|all",
                    help=f"comma-separated body models, or all 30 (default: {_DEFAULT_BODY})")
    bp.add_argument("--scripts", metavar="DIR", action="append", default=None,
                    help="add the poses of every gesture script (*.toml) in DIR (repeatable; default: "
                         "the game's and protocol's bundled scripts, as the paper's game database "
                         "was built from the game's motions)")
    bp.add_argument("--no-scripts", action="store_true", help="recordings only")
    bp.add_argument("--out", metavar="PATH", help="output folder (default: out/db/<body>; with several "
                                                   "bodies, a parent folder)")
    bp.add_argument("--max-poses", type=int, metavar="N", help="cap the pruned pose set (quick builds)")
    bp.add_argument("--takes", type=int, metavar="N", help="use only the first N training takes (quick builds)")
    bp.set_defaults(func=_cmd_build_db)

    ap = sub.add_parser("train-appearance", parents=list(parents),
                        help="train the appearance cue's network (cached in out/appearance)",
                        description="Render the training recordings (held-out takes excluded) on random synthetic "
                                    "people and train the small network that reads the joints' depth from the "
                                    "person's colour image (docs/TRACKER.md, session 24). Needs PyTorch; the "
                                    "tracker itself does not.")
    ap.add_argument("--out", metavar="PATH", help="network file (default: out/appearance/net.npz)")
    ap.add_argument("--mocap", metavar="DIR", help="recordings folder (default: ../shared/mocap or $MOCAP_DATA)")
    ap.add_argument("--epochs", type=int, metavar="N", help="training epochs (default: 15)")
    ap.add_argument("--width", type=int, metavar="C",
                    help="channels of the first convolution, the others 2, 4, 8 and 8 times it (default: 24; "
                         "16 before session 28)")
    ap.add_argument("--passes", type=_passes, metavar="SEED:EVERY,...[;...]",
                    help="one pass per pair: every take on the person SEED+row chooses, every EVERY-th frame; "
                         "one list per network, separated by ';' (default: 1000:3,2000:2,3000:2,4000:2 for the "
                         "first, 5000:2,6000:2,2000:2,3000:2 for the second)")
    pg = ap.add_mutually_exclusive_group()
    pg.add_argument("--posture-passes", type=_passes, metavar="SEED:EVERY,...[;...]",
                    help="more passes with the poses varied (stooped, knees bent: tracker_service/"
                         "posture_variation.py), one list per network (default: 7000:3 for the first, 8000:3 "
                         "for the second, none for more)")
    pg.add_argument("--no-posture", action="store_true", help="no posture-varied passes")
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
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, metavar="J",
                    help="rendering processes (default: the CPUs)")
    ap.set_defaults(func=_cmd_train_appearance)

    def tracker_opts(p: argparse.ArgumentParser) -> None:
        p.add_argument("--db", metavar="PATH", help="template database folder (default: out/db/mMA, "
                                                    "built on first use)")
        p.add_argument("--body", default="auto", metavar="auto|NAME",
                       help="body model: auto (chosen by silhouette match on the first frames) or a name")
        p.add_argument("--measurements", metavar="K=V,...",
                       help="build the body from the user's measurements instead of choosing one: height=M "
                            "(required), group=men|women|children, chest=M, waist=M, hip=M, weight=KG, "
                            "shoulder=M (joint spacing), arm=RATIO, leg=RATIO (1.0 = the family's proportions)"
                            + (" or subject[:KEY,...] (the synthetic person's own, all or those keys)"
                               if p.prog.endswith("eval") else ""))
        p.set_defaults(measurements_subject=p.prog.endswith("eval"))
        p.add_argument("--estimator", choices=["tree"], default="tree", help="pose estimator (default: tree)")
        p.add_argument("--distance", choices=["nwxor", "cwxor", "xor"], default="xor",
                       help="silhouette distance (default: xor, the most accurate in our measurements; the "
                            "paper's choice is nwxor)")
        p.add_argument("--no-occlusion", action="store_true", help="disable eq. 14 (dynamic model DM1)")
        p.add_argument("--max-heading", type=float, metavar="DEG",
                       help="the user faces the camera within DEG degrees (e.g. 35 for the game): poses turned "
                            "further get no prior (default: any heading)")
        p.add_argument("--no-skin", action="store_true", help="silhouettes only (no skin colour cue for the hands)")
        p.add_argument("--no-shoes", action="store_true", help="no shoe colour cue for the legs")
        p.add_argument("--no-smoothing", action="store_true", help="publish the raw per-frame estimate "
                                                                  "(no One Euro smoothing)")
        p.add_argument("--appearance", metavar="PATH|off",
                       help="the appearance cue's network (default: out/appearance/net.npz when it exists; "
                            "mocap-tracker train-appearance makes it, once); off: no cue")
        p.add_argument("--no-refine", action="store_true",
                       help="with the appearance cue: publish the filter's pose as it is, not refined toward the "
                            "joints the network reads")
        p.add_argument("--no-proportions", action="store_true",
                       help="with the appearance cue: keep the selected body model's bone proportions (by default "
                            "the torso, arms and legs take the lengths the network reads in the first second)")
        p.add_argument("--no-reading-filter", action="store_true",
                       help="with the refinement: refine toward each frame's raw reading, not the readings "
                            "Kalman-filtered over time")
        p.add_argument("--pose", choices=("mean", "map"), default="mean",
                       help="publish the posterior-mean pose (default: hedges between the modes of an "
                            "ambiguous silhouette) or the MAP leaf's pose")

    rp = sub.add_parser("run", parents=list(parents), help="the tracker daemon: frames -> poses over Zenoh",
                        description="Track the person in front of the camera and publish PoseFrames on "
                                    "mocap/tracker/<id>/pose, BodyInfo on .../body (also answered to queries), "
                                    "TrackerStatus on .../status and a liveliness token .../alive.")
    rp.add_argument("--source", default="synthetic", metavar="SPEC",
                    help="synthetic[:BVH|SCRIPT] (default), camera[:INDEX], video:PATH or frames:DIR")
    tracker_opts(rp)
    rp.add_argument("--id", default="default", help="tracker id in the key expressions (default: default)")
    rp.add_argument("--frames", type=int, metavar="N", help="stop after N input frames")
    rp.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    rp.add_argument("--seed", type=int, default=0, help="synthetic scene seed")
    rp.add_argument("--as-fast-as-possible", action="store_true",
                    help="do not pace file/synthetic sources at their frame rate")
    rp.add_argument("--wait-for-subscriber", type=float, default=0.0, metavar="S",
                    help="wait up to S seconds for a pose subscriber before reading the first frame")
    add_zenoh_args(rp, "publisher")
    rp.set_defaults(func=_cmd_run)

    ep = sub.add_parser("eval", parents=list(parents), help="track a motion rendered as synthetic video; print errors",
                        description="Render the synthetic scene for a BVH recording or gesture script (a subject "
                                    "unlike the database's body models), run the whole pipeline from pixels and "
                                    "print one JSON object: mpjpe_cm, root_error_cm, mpjpe_2d_px, "
                                    "frames_within_10cm, accel_error_cm (jitter), reacquire_s_max, fps, ms_per_frame, "
                                    "distance_evals_per_level, templates, estimator, distance, body_selected, frames.")
    src = ep.add_mutually_exclusive_group(required=True)
    src.add_argument("--bvh", metavar="FILE")
    src.add_argument("--script", metavar="FILE")
    tracker_opts(ep)
    ep.add_argument("--frames", type=int, metavar="N", help="evaluate at most N frames")
    ep.add_argument("--seed", type=int, default=0, help="scene seed (subject, room, lighting, noise)")
    ep.add_argument("--force-loss-every", type=float, default=0.0, metavar="S",
                    help="force a tracking loss every S seconds and measure re-acquisition (default: never)")
    ep.add_argument("--json", action="store_true", help="print only the JSON object")
    ep.set_defaults(func=_cmd_eval)


def ensure_db(path: str | None, body: str = _DEFAULT_BODY, build_if_missing: bool = True) -> Any:
    """Load a database, building the default one first when it is missing."""
    from tracker_service.templates.database import DatabaseError, default_db_dir, load_db

    p = Path(path) if path else default_db_dir(body)
    try:
        return load_db(p)
    except DatabaseError as exc:
        if path or not build_if_missing or (p / "manifest.json").exists():
            raise
        log.warning("%s; building it now (a few minutes, cached for next time)", exc)
        _build(body, p, None, _script_dirs(None), None, None)
        return load_db(p)


def _passes(text: str) -> tuple[tuple[tuple[int, int], ...], ...]:
    """``SEED:EVERY,...`` per network, networks separated by ``;``."""
    try:
        out = tuple(tuple((int(a), int(b)) for a, b in (t.split(":") for t in group.split(",") if t.strip()))
                    for group in text.split(";"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SEED:EVERY[,SEED:EVERY...][;...], got {text!r}") from None
    if not out or any(not g or any(every < 1 for _, every in g) for g in out):
        raise argparse.ArgumentTypeError(f"expected SEED:EVERY pairs with EVERY >= 1, got {text!r}")
    return out


def ensure_appearance(spec: str | None, train_if_missing: bool) -> Any:
    """The appearance network ``spec`` names (a path, ``off``, or None for the default file).

    A missing default file is trained first when ``train_if_missing`` (some minutes, cached), else
    the cue is off with a warning; a named file that cannot be read, or a corrupt default one,
    raises :class:`tracker_service.cues.appearance.AppearanceError`.
    """
    from tracker_service.cues.appearance import default_appearance_path, load_appearance

    if spec == "off":
        return None
    p = Path(spec) if spec else default_appearance_path()
    if spec or p.exists():
        net = load_appearance(p)
        if not net.members:
            log.warning("the appearance network %s is one network; the tracker's defaults are tuned for the "
                        "ensemble of two that mocap-tracker train-appearance now makes (docs/TRACKER.md, "
                        "session 26)", p)
        return net
    if not train_if_missing:
        log.warning("no appearance network at %s: the appearance cue is off (train it once with: "
                    "mocap-tracker train-appearance)", p)
        return None
    log.warning("no appearance network at %s; training it now (some minutes, cached for next time)", p)
    _train_appearance(p, None, None, None, None, os.cpu_count() or 1, scripts=_script_dirs(None))
    return load_appearance(p)


def _train_appearance(out: Path, mocap: str | None, epochs: int | None,
                      passes: tuple[tuple[tuple[int, int], ...], ...] | None, takes: int | None, jobs: int,
                      members: int | None = None, scripts: Sequence[str] = (),
                      posture_passes: tuple[tuple[tuple[int, int], ...], ...] | None = None,
                      width: int | None = None) -> dict[str, Any]:
    """Render the training views and train the ensemble (``scripts``: folders of gesture scripts
    whose motions are trained on too; ``posture_passes``: each network's passes with varied
    postures, None for the defaults, ``()`` for none; ``width``: None for the default)."""
    from dataclasses import replace as dc_replace

    from tqdm import tqdm

    from tracker_service.build.appearance_train import (
        MEMBER_PASSES,
        TrainConfig,
        config_samples,
        member_posture_passes,
        render_samples,
        train_network,
        training_takes,
    )
    from tracker_service.build.database import is_held_out
    from tracker_service.cues.appearance import ensemble, save_appearance

    n = members or (len(passes) if passes else len(MEMBER_PASSES))
    plan = passes or MEMBER_PASSES[:n]
    if len(plan) != n:
        raise ValueError(f"{n} network(s) need {n} pass list(s) separated by ';' in --passes, got {len(plan)}"
                         if passes else f"--members {n}: the defaults cover {len(MEMBER_PASSES)} networks; "
                         f"give each one's --passes (';'-separated)")
    if mocap:
        os.environ["MOCAP_DATA"] = mocap
    from protocol.formats.mocap_data import index_entries, mocap_root

    root = mocap_root()
    recordings = [(i, str(root / e.path)) for i, e in enumerate(index_entries()) if not is_held_out(i)]
    if takes:
        recordings = recordings[:takes]
    script_files = _gesture_scripts(scripts)
    entries = training_takes(recordings, script_files)
    postures = member_posture_passes(n) if posture_passes is None else posture_passes
    if postures and len(postures) != n:
        raise ValueError(f"{n} network(s) need {n} posture pass list(s) separated by ';' in --posture-passes, "
                         f"got {len(postures)}")
    base = TrainConfig()
    if epochs is not None:
        base = dc_replace(base, epochs=epochs)
    if width is not None:
        base = dc_replace(base, width=width)
    configs = [dc_replace(base, passes=plan[k], posture_passes=postures[k] if postures else (), seed=k)
               for k in range(n)]
    t0 = time.perf_counter()
    every_pass = tuple(dict.fromkeys(p for c in configs for p in c.passes))
    with tqdm(desc="render training views", unit="take") as bar:
        def rendered(done: int, total: int) -> None:
            bar.total = total
            bar.n = done
            bar.refresh()

        render_samples(entries, every_pass, configs[0].size, out.parent / "data", jobs, rendered, load=False)
        every_posture = tuple(dict.fromkeys(p for c in configs for p in c.posture_passes))
        if every_posture:
            render_samples(entries, every_posture, configs[0].size, out.parent / "data", jobs, rendered, load=False,
                           posture=configs[0].posture)
    t1 = time.perf_counter()
    nets = []
    for k, cfg in enumerate(configs):
        samples = config_samples(entries, cfg, out.parent / "data")  # cached: read only
        with tqdm(total=cfg.epochs, desc=f"train network {k + 1}/{n} on {len(samples)} views", unit="epoch") as bar:
            def trained(epoch: int, epochs: int, fig: dict[str, float]) -> None:
                bar.update(1)
                bar.set_postfix({name: round(v, 4) for name, v in fig.items() if name != "seconds"})

            nets.append(train_network(samples, cfg, threads=max(jobs, 1), progress=trained))
        del samples
    net = nets[0] if n == 1 else ensemble(nets)
    common = {"render_s": round(t1 - t0, 1), "train_s": round(time.perf_counter() - t1, 1), "mocap": str(root),
              "training_takes": len(recordings), "scripts": [str(p) for p in script_files]}
    meta = net.meta | common
    save_appearance(out, replace(net, meta=meta))
    return meta


def _cmd_train_appearance(args: argparse.Namespace) -> int:
    from tracker_service.cues.appearance import default_appearance_path

    out = Path(args.out) if args.out else default_appearance_path()
    for name in ("jobs", "epochs", "takes", "width"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            raise ValueError(f"--{name} must be >= 1, got {getattr(args, name)}")
    if args.members is not None and args.members < 1:
        raise ValueError(f"--members must be >= 1, got {args.members}")
    postures = () if args.no_posture else args.posture_passes
    meta = _train_appearance(out, args.mocap, args.epochs, args.passes, args.takes, args.jobs, args.members,
                             _script_dirs(args), postures, args.width)
    for i, m in enumerate(meta.get("members") or [meta]):
        val = ("validation RMS x / y / z " + " / ".join(f"{100 * m[c]:.1f}" for c in ("val_rms_x", "val_rms_y",
                                                                                      "val_rms_z"))
               + " % of the height" if "val_rms_z" in m else "no validation takes")
        print(f"appearance network {i + 1}: {m['samples']} training views, {val}")
    print(f"{meta['training_takes']} training takes and {len(meta['scripts'])} gesture scripts; "
          f"rendering {meta['render_s']:.0f} s, training "
          f"{meta['train_s']:.0f} s -> {out}")
    return 0


def _script_dirs(args: argparse.Namespace | None) -> list[str]:
    """The folders of gesture scripts ``--scripts`` / ``--no-scripts`` name (build-db and
    train-appearance); :data:`DEFAULT_SCRIPT_DIRS` without them (or without ``args``)."""
    if args is not None and args.no_scripts:
        return []
    if args is not None and args.scripts is not None:
        return list(args.scripts)
    return [str(d) for d in DEFAULT_SCRIPT_DIRS]


def _gesture_scripts(dirs: Sequence[str]) -> list[Path]:
    """The gesture scripts (``*.toml`` with ``[[key]]`` tables) in the given folders; other TOML
    files there (e.g. a game's label file) are skipped with a note."""
    import tomllib

    out = []
    for p in sorted(q for d in dirs for q in Path(d).glob("*.toml")):
        try:
            doc = tomllib.loads(p.read_text())
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
            out.append(p)  # let the script reader report it with file and line
            continue
        if "key" in doc:
            out.append(p)
        else:
            print(f"{p} has no [[key]] tables: not a gesture script, skipped", file=sys.stderr)
    return out


def _build(body_name: str, out: Path, mocap: str | None, scripts: list[str], max_poses: int | None,
           takes: int | None) -> dict[str, Any]:


    from tracker_service.body.family import body_model
    from tracker_service.build.database import DbBuildConfig, build_filter_db, is_held_out, training_motions
    from tracker_service.camera import default_camera
    from tracker_service.templates.database import save_db

    if mocap:
        os.environ["MOCAP_DATA"] = mocap
    from protocol.formats.mocap_data import index_entries

    body = body_model(body_name).body
    entries = [e for i, e in enumerate(index_entries()) if not is_held_out(i)]
    if takes:
        entries = entries[:takes]
    script_files = _gesture_scripts(scripts)
    t0 = time.perf_counter()
    motions = training_motions(body, entries, scripts=script_files, progress=True)
    db, stats = build_filter_db(motions, body, default_camera(), DbBuildConfig(max_poses=max_poses), progress=True)
    meta = {"stats": stats, "takes": [e.path for e in entries], "scripts": [str(s) for s in script_files],
            "build_s": time.perf_counter() - t0}
    save_db(out, db, body, default_camera(), meta)
    return meta


def _cmd_build_db(args: argparse.Namespace) -> int:
    from tracker_service.templates.database import default_db_dir

    for name in args.bodies:
        out = Path(args.out) / name if (args.out and len(args.bodies) > 1) else Path(args.out or default_db_dir(name))
        meta = _build(name, out, args.mocap, _script_dirs(args), args.max_poses, args.takes)
        s = meta["stats"]
        print(f"{name}: {int(s['poses'])} poses from {int(s['frames'])} frames; tree "
              f"{int(s['level1_nodes'])}/{int(s['level2_nodes'])}/{int(s['level3_nodes'])} nodes; "
              f"{meta['build_s']:.0f} s -> {out}")
    return 0


def _config(args: argparse.Namespace) -> Any:
    from tracker_service.body.family import BODY_MODELS
    from tracker_service.body.measured import given_body, parse_measurements
    from tracker_service.estimators.tree_filter.filter import FilterParams
    from tracker_service.pipeline.process import TrackerConfig

    names = [m.name for m in BODY_MODELS]
    if args.body != "auto" and args.body not in names:
        raise ValueError(f"unknown body model {args.body!r}; choose auto or one of {', '.join(names)}")
    # auto: the family is scored on the first frames; NAME: that model (templates scaled to its height)
    cands = tuple(names) if args.body == "auto" else (args.body,)
    given = None
    if args.measurements:
        if args.body != "auto":
            raise ValueError("give either --body NAME or --measurements, not both")
        cands = ()
        if _is_subject(args.measurements):  # eval's 'subject' is resolved with the scene
            if not getattr(args, "measurements_subject", False):
                raise ValueError("--measurements subject is eval's (the synthetic person's own measurements); "
                                 "give the user's as height=M,leg=RATIO,...")
            _subject_keys(args.measurements)  # a bad key is an error now, not after the warm-up
        else:
            given = given_body(parse_measurements(args.measurements))
    if args.max_heading is not None and not 0.0 < args.max_heading <= 180.0:
        raise ValueError(f"--max-heading must be in (0, 180] degrees, got {args.max_heading}")
    cfg = TrackerConfig(distance=args.distance, occlusion=not args.no_occlusion, body_candidates=cands, body=given,
                        filter=FilterParams(max_heading=None if args.max_heading is None
                                            else math.radians(args.max_heading)))
    if args.no_skin:
        cfg = replace(cfg, skin=None)
    if args.no_shoes:
        cfg = replace(cfg, shoes=None)
    if args.no_smoothing:
        cfg = replace(cfg, smoothing=None)
    if args.pose == "map":
        cfg = replace(cfg, use_mean_pose=False)
    if getattr(args, "no_refine", False):
        cfg = replace(cfg, refine=None)
    if getattr(args, "no_proportions", False):
        cfg = replace(cfg, proportions=None)
    if getattr(args, "no_reading_filter", False):
        cfg = replace(cfg, reading_filter=None)
    net = ensure_appearance(getattr(args, "appearance", None), train_if_missing=False)
    if net is not None:
        cfg = replace(cfg, appearance=net)
    return cfg


def _cmd_run(args: argparse.Namespace) -> int:
    import threading

    from protocol.net.session import stop_on_signals

    outcome: dict[str, Any] = {}

    def work(stop: threading.Event) -> None:
        try:
            # imported here, under the signal handlers: numba and cv2 take a while to import
            from tracker_service.app.daemon import run_tracker_cli
            from tracker_service.sources.frame_source import open_source, parse_source

            spec = parse_source(args.source)
            config = _config(args)
            loaded = ensure_db(args.db)
            if stop.is_set():
                return
            source = open_source(spec, (loaded.camera.width, loaded.camera.height), default_motion=DEFAULT_SCRIPT,
                                 seed=args.seed)
            outcome["rc"] = run_tracker_cli(args, loaded, config, source, stop)
        except BaseException as exc:  # handed to the main thread, which reports it
            outcome["error"] = exc

    # The work runs in a worker thread so that a signal during the seconds of start-up (database,
    # EGL context) still ends the process promptly; once running, the loop checks ``stop`` per frame.
    with stop_on_signals(threading.Event()) as stop:
        worker = threading.Thread(target=work, args=(stop,), name="tracker", daemon=True)
        worker.start()
        while worker.is_alive():
            if stop.wait(0.05):
                worker.join(timeout=1.0)
                break
    if worker.is_alive():  # still starting up (loading, EGL, warm-up): no Zenoh session yet, leave now
        log.info("stopped during start-up")
        logging.shutdown()
        sys.stdout.flush()
        os._exit(0)
    if "error" in outcome:
        raise outcome["error"]
    return int(outcome.get("rc", 0))


def _is_subject(spec: str | None) -> TypeGuard[str]:
    """Whether ``--measurements`` names the synthetic person's own (``subject`` or ``subject:KEYS``)."""
    return bool(spec) and (spec == "subject" or str(spec).startswith("subject:"))


def _subject_keys(spec: str | None) -> tuple[str, ...]:
    """``subject`` -> every measurement of the scene's person; ``subject:height,leg`` -> those."""
    if not _is_subject(spec):
        return ()
    _, _, keys = spec.partition(":")
    known = ("height", "group", "chest", "waist", "hip", "shoulder", "arm", "leg")
    chosen = tuple(k.strip() for k in keys.split(",") if k.strip()) if keys else known
    if bad := sorted(set(chosen) - set(known)):
        raise ValueError(f"--measurements subject: unknown key(s) {bad}; choose from {', '.join(known)}")
    return chosen


def _cmd_eval(args: argparse.Namespace) -> int:
    from protocol.motion import load_motion
    from tracker_service.app.evaluate import EvalOptions, evaluate_motion
    from tracker_service.pipeline.warmup import warm_up

    path = args.bvh or args.script
    motion = load_motion(path, fps=30.0)
    loaded = ensure_db(args.db)
    cfg = _config(args)
    warm_up(loaded.db, loaded.body, loaded.camera, cfg)  # kernels compiled before the clock starts
    opts = EvalOptions(frames=args.frames, seed=args.seed, force_loss_every_s=args.force_loss_every,
                       subject_measurements=_subject_keys(args.measurements))

    def progress(done: int, total: int) -> None:
        if not args.json and sys.stderr.isatty():
            print(f"\r{done}/{total} frames", end="", file=sys.stderr)

    result = evaluate_motion(motion, loaded, cfg, opts, progress)
    print(json.dumps(result) if args.json else json.dumps(result, indent=1))
    return 0
