"""The appearance network's readings turned from a level camera's axes into the actual camera's.

The network was trained on views from level cameras only (:mod:`tracker_service.build.appearance_train`:
the default camera, 1.2 m high, no tilt, no roll): in every view it learned from, the camera's up
was the world's up. Shown a camera tilted 15° down, it still reads an upright body *in the camera's axes*,
which is a body leaning 15° away in the world. Measured on the pooled readings of held-out
takes (seed 7, 120 frames; the mean distance of the joints from the true ones in the camera's
axes, the subject 1.64 m tall): turning the reading about the camera's x axis fits best near the
camera's *tilt* (12–13° for a camera 1.8 m high tilted 15° down, about −4° for one 0.8 m high
tilted 5° up), not near the tilt of the ray to the person (which would mean the network reads
the viewpoint). Turned by the tilt, the readings' error is 11.38 → 6.79 cm and 6.22 → 5.61 cm on
6 takes (5.52 cm on 12 takes at the default camera).

So the reading is taken to be in the **level frame** of the camera — the camera's heading with its
tilt and roll removed: ``y`` the world's up, ``z`` the horizontal part of the camera's backward
axis, ``x = y × z`` — and :func:`level_to_camera` gives the rotation into the camera's axes
(the identity for a level camera). Its numbers are the camera's pose only: no fitted constant.
A rolled camera (or a tilted one, away from the image's centre column) also shows the world's up
slanted in the image, which no training view did: :func:`upright_angle` gives the turn of the crop
(:func:`tracker_service.cues.appearance.person_crop`) that makes it point up again.

The heading is *not* turned toward the line of sight. The network does not resolve a near-frontal
person's heading within about 15°: it reads them as facing along the camera's axis, as the
near-frontal people of its training views did. Seen 15° right of the image's centre while facing
the camera, the reading fits best turned by −15° (6.69 → 5.19 cm, turned by each frame's azimuth
of the silhouette's median pixel); but a person who steps aside facing the room's front
(``protocol/scripts/step_aside.toml``, like the game's side steps) is read right as it is, and
the same turn costs them: readings 5–15° off centre 1.24 → 2.71 and 1.47 → 2.82 cm, the tracker
over the whole script 2.50 → 3.79 and 2.37 → 3.56 cm (two subjects). People stepping about in
front of a camera mostly face the room's front, so the reading's heading stays the camera's
(docs/TRACKER.md, "Alternatives measured").
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from tracker_service.camera import Camera

__all__ = ["level_to_camera", "rotate_reading", "upright_angle"]

F64 = NDArray[np.float64]
#: Below this the rotation is taken as the identity (a level camera's pose, up to rounding): the
#: reading is then used as it is, bit for bit.
_IDENTITY_TOL = 1e-9


def level_to_camera(camera: Camera) -> F64 | None:
    """Rotation taking a vector from the camera's level frame into its axes (module doc).

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


def rotate_reading(mu: F64, var: F64, rotation: F64) -> tuple[F64, F64]:
    """A reading of independent Gaussian coordinates expressed in rotated axes.

    Parameters
    ----------
    mu, var : (J, 3) float64
        Each joint's mean and per-coordinate variance in the level frame.
    rotation : (3, 3) float64
        :func:`level_to_camera`.

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
    p = 3.0 * np.array([(u - camera.cx) / camera.fx, -(v - camera.cy) / camera.fy, -1.0])
    q = p + 0.05 * up

    def pixel(x: F64) -> tuple[float, float]:
        return camera.cx + camera.fx * x[0] / -x[2], camera.cy - camera.fy * x[1] / -x[2]

    (u0, v0), (u1, v1) = pixel(p), pixel(q)
    return float(np.degrees(np.arctan2(u1 - u0, v0 - v1)))  # the step's clockwise angle from the image's up
