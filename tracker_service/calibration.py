"""Calibrating the camera with a printed checkerboard (``mocap-tracker calibrate``).

* **Intrinsics and distortion**: the board's inner corners are found in every image
  (``cv2.findChessboardCorners``, refined by ``cv2.cornerSubPix``) and ``cv2.calibrateCamera`` fits
  ``K`` and ``(k1, k2, p1, p2)`` (``k3`` fixed at 0 unless asked: a handful of views does not pin it).
* **Extrinsics**: one image of the board **lying flat on the floor** where the person will stand;
  ``cv2.solvePnP`` gives the board's pose, so the floor plane and the camera's height, tilt and roll
  above it. The world frame is then set up as the tracker's: floor ``y = 0``, Y up, the origin on the
  floor straight ahead of the camera at the board centre's horizontal distance (or ``distance_m``),
  +Z from there towards the camera. The camera's heading on the floor is not kept (the templates are
  rendered for a person at the origin facing the camera), its tilt and roll are.

Everything here works on images and numbers; the command line is
:mod:`tracker_service.app.commands.calibrate`.
"""

from __future__ import annotations

import glob
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from tracker_service.camera import DEFAULT_DISTANCE_M, Camera, look_at

__all__ = [
    "CalibrationError",
    "CalibrationResult",
    "board_points",
    "calibrate_checkerboard",
    "find_corners",
    "floor_camera",
    "image_files",
    "parse_pattern",
]

_IMAGE_EXT = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp"}


class CalibrationError(ValueError):
    """Calibration impossible with the given images or settings (one-line message)."""


@dataclass(frozen=True)
class CalibrationResult:
    """What :func:`calibrate_checkerboard` found.

    Attributes
    ----------
    camera : Camera
        At the images' size; its pose from the floor image (or the placement given without one).
    rms_px : float
        ``cv2.calibrateCamera``'s RMS reprojection error over all used images, pixels.
    floor_rms_px : float, optional
        RMS reprojection error of the floor board after ``solvePnP`` (None without a floor image).
    used : tuple of str
        The images whose corners were found (the others were skipped).
    skipped : tuple of str
    distance_m : float
        Horizontal distance from the camera to the world origin (where the person stands).
    """

    camera: Camera
    rms_px: float
    floor_rms_px: float | None
    used: tuple[str, ...]
    skipped: tuple[str, ...]
    distance_m: float


def parse_pattern(text: str) -> tuple[int, int]:
    """``COLSxROWS`` inner corners (OpenCV's pattern size: a board of 10 x 7 squares is ``9x6``)."""
    parts = text.lower().replace("×", "x").split("x")
    try:
        cols, rows = (int(p) for p in parts)
    except ValueError:
        raise CalibrationError(f"checkerboard must be COLSxROWS inner corners (e.g. 9x6), got {text!r}") from None
    if cols < 3 or rows < 3:
        raise CalibrationError(f"checkerboard needs at least 3x3 inner corners, got {text!r}")
    if cols == rows:
        raise CalibrationError(f"use a board with different numbers of inner corners along its sides "
                               f"(got {text!r}): a square one is ambiguous")
    return cols, rows


def image_files(spec: str) -> list[Path]:
    """The images a folder holds (name order) or a glob pattern matches."""
    p = Path(spec)
    if p.is_dir():
        files = sorted(q for q in p.iterdir() if q.suffix.lower() in _IMAGE_EXT)
    else:
        files = sorted(Path(q) for q in glob.glob(spec) if Path(q).suffix.lower() in _IMAGE_EXT)
    if not files:
        raise CalibrationError(f"no images found at {spec}")
    return files


def board_points(pattern: tuple[int, int], square_m: float) -> NDArray[np.float32]:
    """(cols*rows, 3) the inner corners in the board's frame (metres, z = 0), OpenCV's order."""
    cols, rows = pattern
    g = np.zeros((rows * cols, 3), np.float32)
    g[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square_m
    return g


def find_corners(image: NDArray[np.uint8], pattern: tuple[int, int]) -> NDArray[np.float32] | None:
    """(cols*rows, 1, 2) sub-pixel inner corners of the board in a BGR or grey image, or None."""
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    ok, corners = cv2.findChessboardCorners(gray, pattern, flags=flags)
    if not ok or corners is None:
        return None
    # the search window must stay within half the spacing of neighbouring corners (a board seen at a
    # grazing angle on the floor has rows a few pixels apart)
    grid = corners.reshape(pattern[1], pattern[0], 2)
    spacing = min(float(np.linalg.norm(np.diff(grid, axis=0), axis=-1).min()),
                  float(np.linalg.norm(np.diff(grid, axis=1), axis=-1).min()))
    half = int(np.clip(np.floor(spacing * 0.4), 2, 7))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    return np.asarray(cv2.cornerSubPix(gray, corners, (half, half), (-1, -1), crit), np.float32)


def floor_camera(k: NDArray[np.float64], dist: NDArray[np.float64], size: tuple[int, int],
                 corners: NDArray[np.float32], pattern: tuple[int, int], square_m: float,
                 distance_m: float | None = None) -> tuple[Camera, float, float]:
    """The camera placed in the tracker's world frame from the board lying on the floor.

    Parameters
    ----------
    k, dist : the intrinsics (OpenCV's ``K`` and ``dist_coeffs``)
    size : (width, height)
    corners : (N, 1, 2) the board's inner corners in the floor image
    pattern, square_m : the board
    distance_m : float, optional
        Horizontal distance from the camera to the world origin; default: to the board's centre.

    Returns
    -------
    camera : Camera
    rms_px : float
        Reprojection error of the board's corners.
    distance_m : float
    """
    obj = board_points(pattern, square_m).astype(np.float64)
    img = np.asarray(corners, np.float64).reshape(-1, 1, 2)
    ok, rvec, tvec = cv2.solvePnP(obj, img, k, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise CalibrationError("solvePnP found no pose of the floor board")
    proj, _ = cv2.projectPoints(obj, rvec, tvec, k, dist)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img.reshape(-1, 2)) ** 2, axis=1))))
    r_b, _ = cv2.Rodrigues(rvec)  # board -> OpenCV camera
    t_b = tvec.reshape(3)
    centre = -r_b.T @ t_b  # camera centre in board coordinates
    up = np.array([0.0, 0.0, 1.0]) if centre[2] > 0 else np.array([0.0, 0.0, -1.0])
    height = float(centre @ up)
    fwd = r_b.T @ np.array([0.0, 0.0, 1.0])  # optical axis in board coordinates
    horiz = fwd - (fwd @ up) * up
    if np.linalg.norm(horiz) < 1e-6:
        raise CalibrationError("the camera looks straight down at the floor: no heading to set the world frame by")
    horiz /= np.linalg.norm(horiz)
    board_centre = obj.mean(axis=0)
    dist_m = float((board_centre - centre) @ horiz) if distance_m is None else float(distance_m)
    if not dist_m > 0:
        raise CalibrationError(f"the board is not in front of the camera (distance {dist_m:.2f} m)")
    ey, ez = up, -horiz
    ex = np.cross(ey, ez)
    m = np.stack([ex, ey, ez])  # board -> world axes
    origin = centre - height * up + dist_m * horiz  # on the floor, straight ahead of the camera
    r_w = r_b @ m.T  # world -> OpenCV camera
    t_w = r_b @ origin + t_b
    cam = Camera.from_opencv({"image_size": list(size), "camera_matrix": k.tolist(),
                              "dist_coeffs": np.asarray(dist, np.float64).reshape(-1).tolist(),
                              "rotation": r_w.tolist(), "translation": t_w.tolist()})
    return cam, rms, dist_m


def calibrate_checkerboard(images: Sequence[Path], pattern: tuple[int, int], square_m: float,
                           floor_image: Path | None = None, *, distance_m: float | None = None,
                           height_m: float = 1.2, tilt_deg: float = 0.0, fix_k3: bool = True) -> CalibrationResult:
    """Intrinsics and distortion from the board's images, the pose from the floor image.

    Without ``floor_image`` the camera is placed ``height_m`` high, looking down by ``tilt_deg``,
    ``distance_m`` (default 3 m) from the origin.

    Raises
    ------
    CalibrationError
        Fewer than three images with the board found, images of different sizes, no board in the
        floor image.
    """
    if not square_m > 0:
        raise CalibrationError(f"the square size must be > 0 m, got {square_m}")
    obj = board_points(pattern, square_m)
    files = list(images)
    if floor_image is not None:
        same = [f for f in files if f.resolve() == floor_image.resolve()]
        if same:
            floor_image = same[0]
        else:
            files.append(floor_image)
    size: tuple[int, int] | None = None
    found: dict[Path, NDArray[np.float32]] = {}
    skipped: list[str] = []
    for f in files:
        raw = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
        if raw is None:
            skipped.append(str(f))
            continue
        img = np.asarray(raw, np.uint8)
        s = (int(img.shape[1]), int(img.shape[0]))
        if size is None:
            size = s
        elif s != size:
            raise CalibrationError(f"{f} is {s[0]}x{s[1]}, the first image {size[0]}x{size[1]}: use one camera "
                                   f"resolution for all images")
        c = find_corners(img, pattern)
        if c is None:
            skipped.append(str(f))
        else:
            found[f] = c
    if floor_image is not None and floor_image not in found:
        raise CalibrationError(f"no {pattern[0]}x{pattern[1]} checkerboard found in the floor image {floor_image}")
    if len(found) < 3 or size is None:
        raise CalibrationError(f"the {pattern[0]}x{pattern[1]} checkerboard was found in {len(found)} of "
                               f"{len(files)} images; at least 3 are needed (vary the board's angle)")
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    rms, k_raw, dist_raw, _, _ = cv2.calibrateCamera([obj] * len(found), list(found.values()), size, None, None,
                                                     flags=flags)
    k = np.asarray(k_raw, np.float64)
    dist = np.asarray(dist_raw, np.float64).reshape(-1)[:5]
    floor_rms: float | None = None
    if floor_image is not None:
        cam, floor_rms, dist_m = floor_camera(k, dist, size, found[floor_image], pattern, square_m, distance_m)
    else:
        dist_m = DEFAULT_DISTANCE_M if distance_m is None else float(distance_m)
        target_y = height_m - dist_m * np.tan(np.radians(tilt_deg))
        cam = Camera(size[0], size[1], float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]),
                     pose=look_at((0.0, height_m, dist_m), (0.0, target_y, 0.0)), dist=dist)
    return CalibrationResult(camera=cam, rms_px=float(rms), floor_rms_px=floor_rms,
                             used=tuple(str(f) for f in found), skipped=tuple(skipped), distance_m=dist_m)
