"""Where the camera is, from what it sees: its tilt and roll from the room's vertical edges, its
height from a person standing on the floor. Used to tell a user whose camera is not where the
tracker assumes it (the default: 1.2 m high, level) what to pass (``--camera-height``,
``--camera-tilt``); the tracker keeps the camera it was given.

**Tilt and roll** (single-view metrology: Criminisi, Reid & Zisserman, "Single view metrology",
IJCV 2000). The room's vertical edges (door and window frames, shelves, corners) are parallel in
the world, so in the image they meet at the vertical vanishing point ``v = K R u`` (``u`` the world's
up, ``R`` world to camera). A level camera sees them parallel; tilted down by ``t`` they converge
below the image at ``cy + fy cot t``. The tilt and roll are found by a grid search that minimises
the angles between each near-vertical line segment of the background image and the direction from
its midpoint to ``v`` (truncated quadratic: a slanted edge in the room costs a constant), each
segment weighted by its length.

**Height.** With the tilt known, a ray through image row ``y`` leaves the camera at
``a(y) = t + atan((y - cy) / fy)`` below the horizontal. A person of stature ``H`` standing upright
at horizontal distance ``Z`` has their feet (row ``y_f``) at ``h = Z tan a_f`` below the camera and
their head top (row ``y_h``) at ``h - H = Z tan a_h``, so

    h = H tan a_f / (tan a_f - tan a_h).

A picture is the same for a world scaled by any factor, so the height is known only relative to
the person's stature: ``H`` is the user's own (``--measurements height=...``) or 1.70 m, and the
height's error is the stature's in proportion (about 6 % for adults 1.60-1.80 m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from tracker_service.camera import Camera

__all__ = ["ASSUMED_STATURE_M", "CameraEstimate", "camera_height", "differs", "level_tilt", "room_estimate",
           "silhouette_rows", "vertical_segments", "with_height"]

#: The stature taken for a person who did not give theirs.
ASSUMED_STATURE_M = 1.70
#: Adults' statures (1.50-1.95 m) lie within this fraction of the assumed one: a camera height
#: measured for the assumed stature is that uncertain.
STATURE_SPREAD = 0.15
#: Camera heights a measurement may give; outside, the silhouette was not a whole person standing.
PLAUSIBLE_HEIGHT_M = (0.2, 4.0)


@dataclass(frozen=True)
class CameraEstimate:
    """The camera's placement as measured from its images.

    Attributes
    ----------
    tilt_deg, roll_deg : float
        Looking down (positive) or up; rolled clockwise in the image (positive). NaN: too few
        vertical edges in the room.
    height_m : float
        Above the floor, for a person of ``stature_m``; NaN: not measured yet.
    stature_m : float
        The stature the height assumes.
    segments : int
        Vertical line segments the tilt was measured from.
    """

    tilt_deg: float = float("nan")
    roll_deg: float = float("nan")
    height_m: float = float("nan")
    stature_m: float = ASSUMED_STATURE_M
    segments: int = 0

    def as_dict(self) -> dict[str, float]:
        """The finite values (``tilt_deg``, ``roll_deg``, ``height_m``, ``stature_m``) for
        :attr:`protocol.wire.messages.TrackerStatus.camera`."""
        items = {"tilt_deg": self.tilt_deg, "roll_deg": self.roll_deg, "height_m": self.height_m}
        out = {k: round(float(v), 3) for k, v in items.items() if math.isfinite(v)}
        if "height_m" in out:
            out["stature_m"] = round(float(self.stature_m), 3)
        return out


def vertical_segments(bright: NDArray[np.floating], min_length_frac: float = 0.1, max_lean_deg: float = 25.0
                      ) -> NDArray[np.float64]:
    """Near-vertical straight edges of an image.

    Parameters
    ----------
    bright : (H, W) float or uint8
        Brightness (the background model's mean: the empty room).
    min_length_frac : float
        Shortest segment kept, as a fraction of the image height.
    max_lean_deg : float
        Largest angle from the image's vertical.

    Returns
    -------
    (N, 4) float64
        ``x1, y1, x2, y2`` per segment, pixels.
    """
    img = np.clip(np.asarray(bright, np.float32), 0, 255).astype(np.uint8)
    edges = cv2.Canny(cv2.GaussianBlur(img, (0, 0), 1.0), 30, 90)
    h = img.shape[0]
    min_len = max(int(min_length_frac * h), 8)
    lines = cv2.HoughLinesP(edges, 1, np.pi / 360, threshold=max(min_len // 2, 8), minLineLength=min_len,
                            maxLineGap=3)
    if lines is None:
        return np.zeros((0, 4))
    seg = lines.reshape(-1, 4).astype(np.float64)
    dx, dy = seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]
    lean = np.degrees(np.arctan2(np.abs(dx), np.abs(dy)))
    return seg[lean <= max_lean_deg]


def _up_in_camera(tilt: NDArray[np.float64], roll: NDArray[np.float64]) -> NDArray[np.float64]:
    """The world's up direction in OpenCV camera coordinates (x right, y down, z forward) for
    cameras tilted down by ``tilt`` and rolled by ``roll`` (radians, broadcast): (..., 3)."""
    ux, uy, uz = np.zeros_like(tilt), -np.cos(tilt), -np.sin(tilt)
    c, s = np.cos(roll), np.sin(roll)  # roll: the image turns clockwise, up leans to the left
    return np.stack(np.broadcast_arrays(c * ux - s * uy, s * ux + c * uy, uz), axis=-1)


def _cost(segments: NDArray[np.float64], camera: Camera, tilts: NDArray[np.float64], rolls: NDArray[np.float64],
          cutoff: float) -> NDArray[np.float64]:
    """The truncated, length-weighted squared angles of ``segments`` to the vertical vanishing point of
    every ``(tilt, roll)`` (radians): (T, R)."""
    up = _up_in_camera(tilts[:, None], rolls[None, :])  # (T, R, 3)
    vx = camera.fx * up[..., 0] + camera.cx * up[..., 2]  # K @ up, homogeneous
    vy = camera.fy * up[..., 1] + camera.cy * up[..., 2]
    vz = up[..., 2]
    mx, my = (segments[:, 0] + segments[:, 2]) / 2.0, (segments[:, 1] + segments[:, 3]) / 2.0
    sx, sy = segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1]
    # direction from each midpoint to the vanishing point (valid at infinity too): (T, R, N)
    dx = vx[..., None] - mx * vz[..., None]
    dy = vy[..., None] - my * vz[..., None]
    angle = np.arctan2(np.abs(dx * sy - dy * sx), np.abs(dx * sx + dy * sy))  # 0..pi/2: lines
    return np.asarray((np.minimum(angle, cutoff) ** 2 * np.hypot(sx, sy)).sum(axis=-1), np.float64)


def level_tilt(segments: NDArray[np.float64], camera: Camera, *, tilt_range_deg: float = 35.0,
               roll_range_deg: float = 10.0, step_deg: float = 0.1, cutoff_deg: float = 2.0,
               min_segments: int = 4) -> tuple[float, float]:
    """The camera's tilt and roll from vertical edges of the room (module docstring).

    Parameters
    ----------
    segments : (N, 4) float64
        :func:`vertical_segments` of the empty room, in ``camera``'s pixels (undistorted).
    camera : Camera
        Its intrinsics are used; its pose is not.
    tilt_range_deg, roll_range_deg, step_deg : float
        The grid searched: 1-degree steps over the ranges, then ``step_deg`` within 1.5 degrees of
        the best.
    cutoff_deg : float
        Angle beyond which a segment is not a vertical of the room (its cost stops growing).
    min_segments : int
        Fewer: ``(nan, nan)``.

    Returns
    -------
    tilt_deg, roll_deg : float
    """
    if len(segments) < min_segments:
        return float("nan"), float("nan")
    cut = math.radians(cutoff_deg)
    tilts = np.arange(-tilt_range_deg, tilt_range_deg + 1e-9, 1.0)
    rolls = np.arange(-roll_range_deg, roll_range_deg + 1e-9, 1.0)
    cost = _cost(segments, camera, np.radians(tilts), np.radians(rolls), cut)
    i, j = np.unravel_index(int(np.argmin(cost)), cost.shape)
    fine = np.arange(-1.5, 1.5 + 1e-9, step_deg)
    tilts, rolls = tilts[i] + fine, rolls[j] + fine
    cost = _cost(segments, camera, np.radians(tilts), np.radians(rolls), cut)
    i, j = np.unravel_index(int(np.argmin(cost)), cost.shape)
    return float(tilts[i]), float(rolls[j])


def camera_height(feet_row: float, head_row: float, camera: Camera, tilt_deg: float,
                  stature_m: float = ASSUMED_STATURE_M) -> float:
    """The camera's height over the floor from an upright person's feet and head top rows.

    Parameters
    ----------
    feet_row, head_row : float
        Image rows (pixels, y down) of the soles and the top of the head, at the image's centre
        column (a person near the centre; the tilt's rays are those of the principal column).
    camera : Camera
        Its intrinsics.
    tilt_deg : float
        The camera's tilt (:func:`level_tilt`), down positive.
    stature_m : float

    Returns
    -------
    float
        Metres; NaN when the feet are not below the horizon or the head not above the feet.
    """
    t = math.radians(tilt_deg)
    a_f = t + math.atan((feet_row - camera.cy) / camera.fy)
    a_h = t + math.atan((head_row - camera.cy) / camera.fy)
    if not (0.0 < a_f < math.pi / 2 and a_h < a_f and a_h > -math.pi / 2):
        return float("nan")
    return float(stature_m * math.tan(a_f) / (math.tan(a_f) - math.tan(a_h)))


def room_estimate(bright: NDArray[np.floating], camera: Camera) -> CameraEstimate:
    """The tilt and roll from the empty room's vertical edges (lens distortion removed first).

    Parameters
    ----------
    bright : (H, W) float
        The background model's brightness.
    camera : Camera
        The working camera (its intrinsics and distortion).

    Returns
    -------
    CameraEstimate
        Without a height.
    """
    segs = vertical_segments(bright)
    if camera.has_distortion and len(segs):
        dist = np.zeros(5)
        dist[: len(camera.dist)] = camera.dist
        pts = cv2.undistortPoints(segs.reshape(-1, 1, 2), camera.K, dist, P=camera.K)
        segs = np.asarray(pts, np.float64).reshape(-1, 4)
    tilt, roll = level_tilt(segs, camera)
    return CameraEstimate(tilt_deg=tilt, roll_deg=roll, segments=len(segs))


def silhouette_rows(mask: NDArray[np.bool_]) -> tuple[float, float] | None:
    """``(feet_row, head_row)``: the pixel edges below the silhouette's lowest row and above its
    highest (None for an empty mask)."""
    ys = np.flatnonzero(mask.any(axis=1))
    if not len(ys):
        return None
    return float(ys[-1]) + 0.5, float(ys[0]) - 0.5


def with_height(estimate: CameraEstimate, rows: list[tuple[float, float]], camera: Camera,
                stature_m: float = ASSUMED_STATURE_M) -> CameraEstimate:
    """``estimate`` with the height from a standing person's silhouette rows (medians over frames).

    Parameters
    ----------
    estimate : CameraEstimate
        With a tilt (else returned unchanged).
    rows : list of (float, float)
        :func:`silhouette_rows` of frames where the person stands upright near the image centre.
    camera : Camera
    stature_m : float
        The person's stature.

    Returns
    -------
    CameraEstimate
    """
    if not rows or not math.isfinite(estimate.tilt_deg):
        return estimate
    feet, head = np.median(np.asarray(rows, np.float64), axis=0)
    h = camera_height(float(feet), float(head), camera, estimate.tilt_deg, stature_m)
    if not PLAUSIBLE_HEIGHT_M[0] <= h <= PLAUSIBLE_HEIGHT_M[1]:  # not a whole person standing (a partial silhouette)
        h = float("nan")
    return CameraEstimate(estimate.tilt_deg, estimate.roll_deg, h, stature_m, estimate.segments)


def differs(estimate: CameraEstimate, camera: Camera, tilt_tol_deg: float = 3.0, height_tol_m: float = 0.15,
            stature_known: bool = True) -> bool:
    """Whether the measured placement is clearly not ``camera``'s (tilt or roll more than
    ``tilt_tol_deg`` apart, height more than ``height_tol_m``). The height scales with the stature
    it was measured for: with an assumed one (``stature_known`` False) it must also be more than
    :data:`STATURE_SPREAD` of the camera's height apart, what adults' statures alone explain."""
    h_tol = height_tol_m if stature_known else max(height_tol_m, STATURE_SPREAD * camera.height_m)
    checks = [(estimate.tilt_deg, camera.tilt_deg, tilt_tol_deg), (estimate.roll_deg, camera.roll_deg, tilt_tol_deg),
              (estimate.height_m, camera.height_m, h_tol)]
    return any(math.isfinite(m) and abs(m - c) > tol for m, c, tol in checks)
