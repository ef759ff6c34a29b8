"""The appearance network's readings turned from the frame it reads in into the camera's axes.

The network was trained on views from a level camera only (:mod:`tracker_service.build.appearance_train`:
the default camera, 1.2 m high, no tilt, no roll, the person near the image's centre). What it
reads is the body in the **view frame**: ``y`` the world's up, ``z`` the horizontal line of sight
from the person back to the camera, ``x = y × z``. Measured on its pooled readings of 6 held-out
takes (seed 7, 120 frames; the mean distance of the joints from the true ones, the subject 1.64 m
tall), each turn fitted by a scan of angles:

* **Tilt and roll**: on a camera 1.8 m high tilted 15° down, it still reads an upright body in the
  camera's axes — a body leaning 15° away in the world. Turning the reading about the camera's
  x axis fits best near the camera's *tilt* (12–13°; −4° for one 0.8 m high tilted 5° up), not
  near the tilt of the ray to the person: the network keeps the world's up, it does not read the
  viewpoint. Turned by the tilt, the readings' error is 11.38 → 6.79 cm and 6.22 → 5.61 cm (5.52 cm
  on 12 takes at the default camera).
* **Heading**: on a level camera turned 15° away from the person (who then stands 15° right of the
  image's centre), the turn about the vertical that fits best is −15°: 6.69 → 5.18 cm. The crop
  shows the person from the side of the line of sight, and the network reads the heading
  relative to that line. Turned in each frame by the azimuth of the silhouette's median pixel
  (:func:`tracker_service.cues.appearance.silhouette_median`): 5.19 cm there, and 5.52 → 5.51 cm
  at the default camera, where the person stays within 5° of the centre (by the true pelvis's
  azimuth 5.18 and 5.49; by the silhouette box's centre, which an arm held out moves, 5.21 and
  5.57).

So the reading is taken in the view frame and :func:`view_to_camera` gives the rotation into the
camera's axes: the level frame's (:func:`level_to_camera`, the camera's heading with its tilt and
roll removed; the identity for a level camera) after a turn by the line of sight's azimuth in it.
Its numbers are the camera's pose and the person's pixel only: no fitted constant. A rolled camera
(or a tilted one, away from the image's centre column) also shows the world's up slanted in the
image, which no training view did: :func:`upright_angle` gives the turn of the crop
(:func:`tracker_service.cues.appearance.person_crop`) that makes it point up again.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from tracker_service.camera import Camera

__all__ = ["level_to_camera", "rotate_reading", "upright_angle", "view_to_camera"]

F64 = NDArray[np.float64]
#: Below this the rotation is taken as the identity (a level camera's pose, up to rounding).
_IDENTITY_TOL = 1e-9


def level_to_camera(camera: Camera) -> F64 | None:
    """Rotation taking a vector from the camera's level frame (its heading, with the tilt and roll
    removed: ``y`` the world's up, ``z`` the horizontal part of the camera's backward axis) into
    its axes.

    Parameters
    ----------
    camera : Camera

    Returns
    -------
    (3, 3) float64 or None
        ``M`` with ``v_camera = M @ v_level``; None when the camera is level and unrolled (the
        identity to :data:`_IDENTITY_TOL`) or looks straight up or down (no heading to keep).
    """
    r = np.asarray(camera.pose[:3, :3], np.float64)  # camera to world: its columns are the camera's axes
    back = r[:, 2]
    z = np.array([back[0], 0.0, back[2]])
    n = float(np.hypot(z[0], z[2]))
    if n < 1e-6:
        return None
    z /= n
    y = np.array([0.0, 1.0, 0.0])
    level = np.stack([np.cross(y, z), y, z], axis=1)  # the level frame's axes in the world
    m = r.T @ level
    return None if np.abs(m - np.eye(3)).max() < _IDENTITY_TOL else m


def _ray(camera: Camera, u: float, v: float) -> F64:
    """Direction of pixel ``(u, v)``'s ray in the camera's axes (the pinhole, no distortion)."""
    return np.array([(u - camera.cx) / camera.fx, -(v - camera.cy) / camera.fy, -1.0])


def view_to_camera(camera: Camera, u: float, v: float) -> F64:
    """Rotation taking the network's reading of a person seen at pixel ``(u, v)`` from the view
    frame into the camera's axes (module doc).

    Parameters
    ----------
    camera : Camera
    u, v : float
        The person's pixel (the centre of the silhouette's box, OpenCV's convention).

    Returns
    -------
    (3, 3) float64
        ``M R_y(-azimuth)``: ``M`` from :func:`level_to_camera` (the identity for a level camera),
        the azimuth of the pixel's ray in the level frame (positive to the right).
    """
    m = level_to_camera(camera)
    base = np.eye(3) if m is None else m
    d = base.T @ _ray(camera, u, v)
    az = math.atan2(float(d[0]), float(-d[2]))
    c, s = math.cos(az), math.sin(az)
    turn = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])  # R_y(-azimuth)
    return base @ turn


def rotate_reading(mu: F64, var: F64, rotation: F64) -> tuple[F64, F64]:
    """A reading of independent Gaussian coordinates expressed in rotated axes.

    Parameters
    ----------
    mu, var : (J, 3) float64
        Each joint's mean and per-coordinate variance in the view frame.
    rotation : (3, 3) float64
        :func:`view_to_camera`.

    Returns
    -------
    mu, var : (J, 3) float64
        In the camera's axes; the variance is the diagonal of ``M diag(var) M^T`` (the rotated
        covariance's off-diagonal terms are dropped, as the cue keeps one variance per
        coordinate).
    """
    m = np.asarray(rotation, np.float64)
    return mu @ m.T, var @ (m * m).T


def upright_angle(camera: Camera, u: float, v: float) -> float:
    """How far to turn the image about pixel ``(u, v)`` so that the world's up points up there.

    Parameters
    ----------
    camera : Camera
    u, v : float
        The pixel (OpenCV's convention), e.g. the centre of the person's box.

    Returns
    -------
    float
        Degrees, counter-clockwise as seen (``cv2.getRotationMatrix2D``'s sense); exactly 0 for a
        level, unrolled camera (:func:`level_to_camera` None). The image of a short upward step
        from a point 3 m along the pixel's ray (the pinhole, without distortion).
    """
    if level_to_camera(camera) is None:
        return 0.0
    up = np.asarray(camera.pose[:3, :3], np.float64).T @ np.array([0.0, 1.0, 0.0])  # the world's up, camera axes
    p = 3.0 * _ray(camera, u, v)
    q = p + 0.05 * up

    def pixel(x: F64) -> tuple[float, float]:
        return camera.cx + camera.fx * x[0] / -x[2], camera.cy - camera.fy * x[1] / -x[2]

    (u0, v0), (u1, v1) = pixel(p), pixel(q)
    return float(np.degrees(np.arctan2(u1 - u0, v0 - v1)))  # the step's clockwise angle from the image's up
