"""Arguments several ``mocap-tracker`` commands share and the functions that read them back into the
frozen options: the tracker options of ``run`` and ``eval`` (:func:`add_tracker_args`,
:func:`tracker_options`), the Zenoh session options (added by
:func:`protocol.net.session.add_zenoh_args`, read by :func:`zenoh_options`), the tracker id,
``--wait-for-subscriber`` and the gesture-script folders of ``build-db`` and ``train-appearance``."""

from __future__ import annotations

import argparse

from protocol.wire.keys import validate_id
from tracker_service.app.options import TrackerOptions, ZenohOptions
from tracker_service.app.resources import default_script_dirs
from tracker_service.estimators import ESTIMATORS

__all__ = [
    "UsageError",
    "add_camera_args",
    "add_tracker_args",
    "add_video_arg",
    "camera_args",
    "script_dirs",
    "tracker_id",
    "tracker_options",
    "wait_for_subscriber",
    "zenoh_options",
]


class UsageError(Exception):
    """A command-line argument the parser could not check; the command line exits with status 2
    and the message, as for the parser's own errors."""


def tracker_id(text: str) -> str:
    """``argparse`` type of a tracker id (letters, digits, ``_`` and ``-``)."""
    try:
        return validate_id(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def wait_for_subscriber(args: argparse.Namespace) -> float:
    """``--wait-for-subscriber`` (seconds, >= 0)."""
    seconds = float(args.wait_for_subscriber)
    if seconds < 0:
        raise UsageError("--wait-for-subscriber must be >= 0")
    return seconds


def script_dirs(args: argparse.Namespace) -> tuple[str, ...]:
    """The gesture-script folders ``--scripts`` / ``--no-scripts`` name (build-db and
    train-appearance); the bundled ones without either."""
    if args.no_scripts:
        return ()
    if args.scripts is not None:
        return tuple(args.scripts)
    return default_script_dirs()


def zenoh_options(args: argparse.Namespace) -> ZenohOptions:
    """The options :func:`protocol.net.session.add_zenoh_args` added."""
    return ZenohOptions(role=args.zenoh_role, mode=args.mode,
                        connect=None if args.connect is None else tuple(args.connect),
                        listen=None if args.listen is None else tuple(args.listen),
                        config_file=args.config)


def add_video_arg(p: argparse.ArgumentParser) -> None:
    """``--video OUT.mp4``: the overlay of every frame (``run`` and ``eval``)."""
    p.add_argument("--video", metavar="OUT.mp4",
                   help="write every frame with the silhouette, the projected skeleton and a HUD drawn on it "
                        "(H.264 MP4 a browser plays; .gif: an animated GIF)")


def add_camera_args(p: argparse.ArgumentParser, *, file: bool = True, fov: bool = True) -> None:
    """The camera options: ``--camera FILE`` (with ``file``) and the shorthands ``--camera-height``,
    ``--camera-tilt`` and ``--fov`` (with ``fov``) (``run``, ``eval``; ``calibrate`` takes height and
    tilt)."""
    if file:
        p.add_argument("--camera", metavar="FILE",
                       help="the camera's calibration (JSON in OpenCV's terms, see docs/RENDERING.md; mocap-tracker "
                            "calibrate makes it): the templates are rendered for it (a database per camera, built "
                            "once under out/db/<body>-cam<digest>)")
    p.add_argument("--camera-height", type=float, metavar="M",
                   help="camera height above the floor in metres (default 1.2)")
    p.add_argument("--camera-tilt", type=float, metavar="DEG",
                   help="camera tilt in degrees, positive looking down (default 0: level)")
    if fov:
        p.add_argument("--fov", type=float, metavar="DEG",
                       help="horizontal field of view in degrees (default 62.7)")


def camera_args(args: argparse.Namespace) -> tuple[str | None, float | None, float | None, float | None]:
    """``(camera_file, height_m, tilt_deg, fov_deg)`` of :func:`add_camera_args`, checked: a file
    that cannot be used, shorthands out of range, or a file with shorthands are a
    :class:`UsageError` (exit status 2, one line)."""
    from tracker_service.camera import CameraFileError, load_camera_file, placed_camera

    file = getattr(args, "camera", None)
    height, tilt, fov = args.camera_height, args.camera_tilt, args.fov
    shorthands = [n for n, v in (("--camera-height", height), ("--camera-tilt", tilt), ("--fov", fov)) if v is not None]
    if file is not None:
        if shorthands:
            raise UsageError(f"--camera FILE gives the whole camera: drop {', '.join(shorthands)}")
        try:
            load_camera_file(file)
        except CameraFileError as exc:
            raise UsageError(str(exc)) from None
    elif shorthands:
        try:
            placed_camera(height_m=1.2 if height is None else height, tilt_deg=tilt or 0.0, hfov_deg=fov)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    return file, height, tilt, fov


def add_tracker_args(p: argparse.ArgumentParser, *, subject: bool) -> None:
    """Add the tracker options (``--db``, ``--body``, the cues and stages); ``subject``: ``eval``'s
    ``--measurements subject[:KEY,...]`` is allowed."""
    p.add_argument("--db", metavar="PATH", help="template database folder (default: out/db/mMA, "
                                                "built on first use)")
    p.add_argument("--body", default="auto", metavar="auto|NAME",
                   help="body model: auto (chosen by silhouette match on the first frames) or a name")
    p.add_argument("--measurements", metavar="K=V,...",
                   help="build the body from the user's measurements instead of choosing one: height=M "
                        "(required), group=men|women|children, chest=M, waist=M, hip=M, weight=KG, "
                        "shoulder=M (joint spacing), arm=RATIO, leg=RATIO (1.0 = the family's proportions)"
                        + (" or subject[:KEY,...] (the synthetic person's own, all or those keys)"
                           if subject else ""))
    p.add_argument("--estimator", choices=list(ESTIMATORS), default="tree",
                   help="pose estimator: tree (Okada & Stenger's tree filter), tree-elmo (the tree filter's estimate "
                        "refined to the nearest silhouette likelihood mode), condensation (1000 particles), "
                        "drs / srs (hierarchical particle filter, deterministic / stratified resampling; "
                        "drs-cardbox / srs-cardbox with the paper's 3D cardbox body model), "
                        "elmo (likelihood modes: hashing, local search, wide temporal prior) (default: tree)")
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
    p.add_argument("--smooth-cutoff", type=float, metavar="HZ",
                   help="One Euro minimum cut-off of the joints' and the root's rotations (default 5 Hz; "
                        "lower: steadier, more lag)")
    p.add_argument("--smooth-beta", type=float, metavar="B",
                   help="One Euro speed coefficient of the joints' and the root's rotations (default 1.5; "
                        "higher: less lag in fast moves)")
    p.add_argument("--appearance", metavar="PATH|off",
                   help="the appearance cue's network (default: the one shipped in the package, "
                        "tracker_service/cues/models/appearance-vN.npz; a file mocap-tracker "
                        "train-appearance wrote; off: no cue)")
    p.add_argument("--no-refine", action="store_true",
                   help="with the appearance cue: publish the filter's pose as it is, not refined toward the "
                        "joints the network reads")
    p.add_argument("--no-proportions", action="store_true",
                   help="with the appearance cue: keep the selected body model's bone proportions (by default "
                        "the torso, arms and legs take the lengths the network reads in the first second)")
    p.add_argument("--no-reading-filter", action="store_true",
                   help="with the refinement: refine toward each frame's raw reading, not the readings "
                        "Kalman-filtered over time")
    p.add_argument("--no-floor", action="store_true",
                   help="let a published foot go through the floor (by default a leg whose ankle sinks below "
                        "the floor is bent back onto it, the hip kept)")
    p.add_argument("--min-confidence", type=float, default=0.01, metavar="C",
                   help="withhold poses whose silhouette match confidence is below C, in [0, 1] (default 0.01: "
                        "the match the filter itself counts as a miss; 0: publish every estimate)")
    p.add_argument("--pose", choices=("mean", "map"), default="mean",
                   help="publish the posterior-mean pose (default: hedges between the modes of an "
                        "ambiguous silhouette) or the MAP leaf's pose")
    add_camera_args(p)


def tracker_options(args: argparse.Namespace, *, subject: bool) -> TrackerOptions:
    """The options :func:`add_tracker_args` added."""
    cutoff, beta = args.smooth_cutoff, args.smooth_beta
    if cutoff is not None and not cutoff > 0:
        raise UsageError("--smooth-cutoff must be > 0 Hz")
    if beta is not None and not beta >= 0:
        raise UsageError("--smooth-beta must be >= 0")
    if not 0.0 <= args.min_confidence <= 1.0:
        raise UsageError("--min-confidence must be in [0, 1]")
    if args.no_smoothing and (cutoff is not None or beta is not None):
        raise UsageError("--smooth-cutoff / --smooth-beta set the smoothing that --no-smoothing turns off")
    camera_file, camera_height, camera_tilt, fov = camera_args(args)
    return TrackerOptions(
        db=args.db, body=args.body, measurements=args.measurements, subject_allowed=subject,
        estimator=args.estimator, distance=args.distance, occlusion=not args.no_occlusion,
        max_heading_deg=args.max_heading, skin=not args.no_skin, shoes=not args.no_shoes,
        smoothing=not args.no_smoothing, appearance=args.appearance, refine=not args.no_refine,
        proportions=not args.no_proportions, reading_filter=not args.no_reading_filter, floor=not args.no_floor,
        pose=args.pose,
        smooth_cutoff=cutoff, smooth_beta=beta, min_confidence=args.min_confidence,
        camera_file=camera_file, camera_height_m=camera_height, camera_tilt_deg=camera_tilt, fov_deg=fov)
