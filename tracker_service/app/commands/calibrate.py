"""``mocap-tracker calibrate``: make the camera file that ``run --camera FILE`` and ``eval --camera
FILE`` read, from images of a printed checkerboard (:mod:`tracker_service.calibration`)."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tracker_service.app.commands.common import UsageError, add_camera_args

__all__ = ["CLEAN_STOP", "NAME", "CalibrateOptions", "add_parser", "main", "options_from_args", "summary_lines"]

NAME = "calibrate"
CLEAN_STOP = False


@dataclass(frozen=True)
class CalibrateOptions:
    """``mocap-tracker calibrate``.

    Attributes
    ----------
    pattern : (int, int)
        Inner corners per row and per column of the board (OpenCV's pattern size).
    square_m : float
        Side of one square, metres.
    images : str
        A folder or a glob pattern of the board's images.
    out : str
        The camera file to write.
    floor_image : str, optional
        An image of the board lying on the floor where the person will stand (the camera's height,
        tilt and roll); without it the camera is placed by ``height_m``, ``tilt_deg``.
    distance_m : float, optional
        Horizontal distance from the camera to where the person stands (default: the floor board's
        centre; 3 m without a floor image).
    height_m, tilt_deg : float
        The placement without a floor image.
    json : bool
        Print the summary as one JSON object.
    """

    pattern: tuple[int, int]
    square_m: float
    images: str
    out: str
    floor_image: str | None = None
    distance_m: float | None = None
    height_m: float = 1.2
    tilt_deg: float = 0.0
    json: bool = False


def add_parser(sub: Any, parents: Sequence[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Add ``calibrate`` to the ``mocap-tracker`` subparsers."""
    cp = sub.add_parser(NAME, parents=list(parents), help="make a camera file from images of a checkerboard",
                        description="Intrinsics and distortion from images of a printed checkerboard held at varied "
                                    "angles (cv2.calibrateCamera); the camera's height, tilt and roll from one image "
                                    "of the board lying flat on the floor where you will stand (cv2.solvePnP). "
                                    "Writes the camera file (JSON in OpenCV's terms) that run/eval --camera read.")
    cp.add_argument("--checkerboard", required=True, metavar="COLSxROWS",
                    help="inner corners per row x per column (a board of 10 x 7 squares is 9x6)")
    cp.add_argument("--square", required=True, type=float, metavar="M", help="side of one square in metres")
    cp.add_argument("--images", required=True, metavar="DIR|GLOB",
                    help="the board's images (a folder, or a quoted glob such as 'calib/*.png'); 10-20 views "
                         "at different angles and distances, all at the resolution you track at")
    cp.add_argument("--floor-image", metavar="FILE",
                    help="the board lying flat on the floor where you will stand, seen by the camera in its "
                         "tracking position (without it: --camera-height / --camera-tilt place the camera)")
    cp.add_argument("--distance", type=float, metavar="M",
                    help="horizontal distance from the camera to where you stand (default: the floor board's "
                         "centre, or 3 m)")
    add_camera_args(cp, file=False, fov=False)
    cp.add_argument("--out", required=True, metavar="FILE", help="the camera file to write (e.g. camera.json)")
    cp.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    return cp


def options_from_args(args: argparse.Namespace) -> CalibrateOptions:
    from tracker_service.calibration import CalibrationError, parse_pattern

    try:
        pattern = parse_pattern(args.checkerboard)
    except CalibrationError as exc:
        raise UsageError(str(exc)) from None
    if not args.square > 0:
        raise UsageError("--square must be > 0 metres")
    if args.distance is not None and not args.distance > 0:
        raise UsageError("--distance must be > 0 metres")
    if args.floor_image and (args.camera_height is not None or args.camera_tilt is not None):
        raise UsageError("--floor-image measures the camera's height and tilt: drop --camera-height / --camera-tilt")
    height = 1.2 if args.camera_height is None else args.camera_height
    tilt = 0.0 if args.camera_tilt is None else args.camera_tilt
    if not height > 0 or not -80.0 <= tilt <= 80.0:
        raise UsageError("--camera-height must be > 0 m and --camera-tilt within +-80 degrees")
    return CalibrateOptions(pattern=pattern, square_m=args.square, images=args.images, out=args.out,
                            floor_image=args.floor_image, distance_m=args.distance, height_m=height, tilt_deg=tilt,
                            json=args.json)


def summary(result: Any, out: str) -> dict[str, Any]:
    """The figures the command prints (JSON-serialisable)."""
    cam = result.camera
    return {"out": out, "image_size": [cam.width, cam.height], "fx": cam.fx, "fy": cam.fy, "cx": cam.cx,
            "cy": cam.cy, "dist_coeffs": cam.to_opencv()["dist_coeffs"], "height_m": cam.height_m,
            "tilt_deg": cam.tilt_deg, "roll_deg": cam.roll_deg, "hfov_deg": cam.hfov_deg,
            "distance_m": result.distance_m, "reprojection_rms_px": result.rms_px,
            "floor_rms_px": result.floor_rms_px, "images_used": len(result.used),
            "images_skipped": list(result.skipped)}


def summary_lines(s: dict[str, Any]) -> list[str]:
    """The readable summary."""
    placed = "measured on the floor board" if s["floor_rms_px"] is not None else "as given (no --floor-image)"
    lines = [
        f"camera file     {s['out']}",
        f"image           {s['image_size'][0]}x{s['image_size'][1]}, fx {s['fx']:.1f} px, fy {s['fy']:.1f} px, "
        f"centre ({s['cx']:.1f}, {s['cy']:.1f})",
        f"field of view   {s['hfov_deg']:.1f} deg horizontal",
        "distortion      k1 k2 p1 p2 k3 = " + " ".join(f"{v:.4g}" for v in s["dist_coeffs"]),
        f"height          {s['height_m']:.3f} m ({placed})",
        f"tilt            {s['tilt_deg']:+.2f} deg (positive: looking down), roll {s['roll_deg']:+.2f} deg",
        f"person at       {s['distance_m']:.2f} m (the world origin)",
        f"reprojection    RMS {s['reprojection_rms_px']:.3f} px over {s['images_used']} images"
        + ("" if s["floor_rms_px"] is None else f"; floor board {s['floor_rms_px']:.3f} px"),
    ]
    if s["images_skipped"]:
        lines.append(f"skipped         {len(s['images_skipped'])} image(s) without the board: "
                     + ", ".join(s["images_skipped"][:5]) + (" ..." if len(s["images_skipped"]) > 5 else ""))
    return lines


def main(options: CalibrateOptions) -> int:
    """Calibrate, write the camera file and print the summary (exit status 0)."""
    from tracker_service.calibration import calibrate_checkerboard, image_files
    from tracker_service.camera import save_camera_file

    result = calibrate_checkerboard(image_files(options.images), options.pattern, options.square_m,
                                    None if options.floor_image is None else Path(options.floor_image),
                                    distance_m=options.distance_m, height_m=options.height_m,
                                    tilt_deg=options.tilt_deg)
    s = summary(result, options.out)
    save_camera_file(result.camera, options.out,
                     {"roll_deg": round(result.camera.roll_deg, 3), "distance_m": round(result.distance_m, 4),
                      "reprojection_rms_px": round(result.rms_px, 4),
                      "floor_rms_px": None if result.floor_rms_px is None else round(result.floor_rms_px, 4)})
    print(json.dumps(s) if options.json else "\n".join(summary_lines(s)))
    return 0
