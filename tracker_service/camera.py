"""Calibrated pinhole camera: intrinsics, extrinsics, optional radial distortion, vectorised projection.

Conventions
-----------
World: right-handed, Y up, metres. The camera frame follows pyrender/OpenGL: the camera looks
along its own **-Z** axis, +Y is up in the image, +X right. :attr:`Camera.pose` is the
camera-to-world transform in that convention (what ``pyrender.Scene.add(camera, pose=...)`` takes).

Image coordinates (2D code only) follow OpenCV: ``u`` to the right, ``v`` down, and the *centre*
of pixel ``(row i, column j)`` is at ``(u, v) = (j, i)``. A point ``X_c`` in camera coordinates at
depth ``d = -Z_c > 0`` projects to::

    x = X_c / d,  y = -Y_c / d,  s = 1 + k1 r^2 + k2 r^4 + k3 r^6  (r^2 = x^2 + y^2)
    x' = s x + 2 p1 x y + p2 (r^2 + 2 x^2),  y' = s y + p1 (r^2 + 2 y^2) + 2 p2 x y
    u = cx + fx * x',  v = cy + fy * y'

which is OpenCV's model (``cv2.projectPoints`` with ``dist_coeffs = (k1, k2, p1, p2, k3)``): ``(x, y)``
are OpenCV's normalised coordinates because OpenCV's camera frame is this one turned half a turn
about X (``X_cv = diag(1, -1, -1) X_c``: x right, y down, looking along +z).
:meth:`Camera.from_opencv` / :meth:`Camera.to_opencv` convert to and from OpenCV's terms, and
:func:`load_camera_file` / :func:`save_camera_file` read and write them as JSON.

The default camera is the paper's setup (Okada & Stenger §3): a 640×480 sensor down-sampled to
320×240, a webcam-like 62.7° horizontal field of view, 1.2 m above the floor, 3.0 m in front of
the subject who stands at the world origin facing +Z (towards the camera).
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "CV_FROM_GL",
    "DEFAULT_DISTANCE_M",
    "DEFAULT_HEIGHT_M",
    "SENSOR_FOCAL_PX",
    "SENSOR_SIZE",
    "Camera",
    "CameraFileError",
    "default_camera",
    "fit_box",
    "load_camera_file",
    "look_at",
    "placed_camera",
    "same_camera",
    "save_camera_file",
]

#: Native sensor resolution (width, height) of the paper's colour camera.
SENSOR_SIZE: tuple[int, int] = (640, 480)
#: Focal length of the native sensor in pixels (62.7° x 48.9° field of view).
SENSOR_FOCAL_PX: float = 525.0
#: Default camera height above the floor and distance to the subject, metres.
DEFAULT_HEIGHT_M: float = 1.2
DEFAULT_DISTANCE_M: float = 3.0
#: OpenCV's camera axes in this module's camera frame: ``X_cv = CV_FROM_GL @ X_gl`` (and back: it is
#: its own inverse). OpenCV: x right, y down, looking along +z; here: X right, Y up, looking along -Z.
CV_FROM_GL: NDArray[np.float64] = np.diag([1.0, -1.0, -1.0])
#: Keys of a camera file (:meth:`Camera.from_opencv`).
OPENCV_KEYS = ("image_size", "camera_matrix", "dist_coeffs", "rotation", "translation")


class CameraFileError(ValueError):
    """A camera file or dictionary that cannot be used; the message (one line) says what is wrong."""


def look_at(eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 1.0, 0.0)) -> NDArray[np.float64]:
    """Camera-to-world pose (OpenGL convention) of a camera at ``eye`` looking at ``target``.

    Parameters
    ----------
    eye, target : (3,) float
        World positions, metres.
    up : (3,) float
        World direction that should appear up in the image.

    Returns
    -------
    (4, 4) float64
        Columns 0-2 are the camera's X (right), Y (up) and Z (backwards) axes in world coordinates,
        column 3 the camera centre.
    """
    e = np.asarray(eye, dtype=np.float64)
    back = e - np.asarray(target, dtype=np.float64)
    n = np.linalg.norm(back)
    if n < 1e-12:
        raise ValueError("eye and target coincide")
    back /= n
    right = np.cross(np.asarray(up, dtype=np.float64), back)
    rn = np.linalg.norm(right)
    if rn < 1e-9:
        raise ValueError("up is parallel to the viewing direction")
    right /= rn
    pose = np.eye(4)
    pose[:3, 0] = right
    pose[:3, 1] = np.cross(back, right)
    pose[:3, 2] = back
    pose[:3, 3] = e
    return pose


@dataclass(frozen=True)
class Camera:
    """A calibrated pinhole camera.

    Attributes
    ----------
    width, height : int
        Image size in pixels.
    fx, fy : float
        Focal lengths in pixels.
    cx, cy : float
        Principal point, OpenCV pixel-centre convention (``(width - 1) / 2`` is the centre).
    pose : (4, 4) float64
        Camera-to-world transform, OpenGL convention (the camera looks along its -Z).
    dist : (2,) or (5,) float64
        Distortion of normalised coordinates: radial ``(k1, k2)``, or OpenCV's
        ``(k1, k2, p1, p2, k3)`` (zeros: none). Four values ``(k1, k2, p1, p2)`` are taken with
        ``k3 = 0``; five whose ``p1, p2, k3`` are zero are stored as ``(k1, k2)``.
    znear, zfar : float
        Clipping depths used by renderers, metres.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    pose: NDArray[np.float64] = field(default_factory=lambda: np.eye(4))
    dist: NDArray[np.float64] = field(default_factory=lambda: np.zeros(2))
    znear: float = 0.05
    zfar: float = 100.0

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError("focal lengths must be positive")
        pose = np.array(self.pose, dtype=np.float64)
        if pose.shape != (4, 4) or not np.allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-6):
            raise ValueError("pose must be a rigid (4, 4) transform")
        dist = np.array(self.dist, dtype=np.float64).reshape(-1)
        if dist.shape == (4,):
            dist = np.append(dist, 0.0)
        if dist.shape == (5,) and not np.any(dist[2:]):
            dist = dist[:2].copy()
        if dist.shape not in ((2,), (5,)):
            raise ValueError("dist must be (k1, k2) or (k1, k2, p1, p2, k3)")
        pose.setflags(write=False)
        dist.setflags(write=False)
        object.__setattr__(self, "pose", pose)
        object.__setattr__(self, "dist", dist)

    # ----------------------------------------------------------------------------- derived values
    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels."""
        return self.width, self.height

    @property
    def K(self) -> NDArray[np.float64]:
        """(3, 3) float64 intrinsic matrix (OpenCV convention)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def position(self) -> NDArray[np.float64]:
        """(3,) float64 camera centre in world coordinates."""
        return self.pose[:3, 3].copy()

    @property
    def world_to_camera(self) -> NDArray[np.float64]:
        """(4, 4) float64 inverse of :attr:`pose` (world -> OpenGL camera frame)."""
        r = self.pose[:3, :3]
        out = np.eye(4)
        out[:3, :3] = r.T
        out[:3, 3] = -r.T @ self.pose[:3, 3]
        return out

    @property
    def focal(self) -> float:
        """Geometric mean focal length in pixels (for isotropic sizes such as projected radii)."""
        return float(np.sqrt(self.fx * self.fy))

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.dist != 0.0))

    def gl_intrinsics(self) -> tuple[float, float, float, float]:
        """``(fx, fy, cx, cy)`` for ``pyrender.IntrinsicsCamera``.

        pyrender puts pixel centres at half-integers (pixel ``j`` spans ``[j, j + 1)``), hence the
        +0.5 shift of the principal point from this class's OpenCV convention.
        """
        return self.fx, self.fy, self.cx + 0.5, self.cy + 0.5

    # ----------------------------------------------------------------------------- projection
    def to_camera(self, points: ArrayLike) -> NDArray[np.float64]:
        """World points into the OpenGL camera frame.

        Parameters
        ----------
        points : (..., 3) float

        Returns
        -------
        (..., 3) float64
        """
        p = np.asarray(points, dtype=np.float64)
        r = self.pose[:3, :3]
        return (p - self.pose[:3, 3]) @ r

    def depth(self, points: ArrayLike) -> NDArray[np.float64]:
        """(...,) float64 depth along the optical axis (``-Z_c``; > 0 in front of the camera)."""
        return -self.to_camera(points)[..., 2]

    def project(self, points: ArrayLike) -> NDArray[np.float64]:
        """Pixel coordinates of world points.

        Parameters
        ----------
        points : (..., 3) float
            World positions, metres.

        Returns
        -------
        (..., 2) float64
            ``(u, v)``, OpenCV convention. Points behind the camera get NaN.
        """
        return self.project_with_depth(points)[0]

    def project_with_depth(self, points: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Pixel coordinates and depths of world points.

        Parameters
        ----------
        points : (..., 3) float

        Returns
        -------
        uv : (..., 2) float64
            NaN where the depth is not positive.
        depth : (...,) float64
            ``-Z_c`` in metres.
        """
        pc = self.to_camera(points)
        d = -pc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(d > 1e-9, 1.0 / d, np.nan)
            x = pc[..., 0] * inv
            y = -pc[..., 1] * inv
            s = self.radial_scale(x * x + y * y)
            xd, yd = s * x, s * y
            if self.dist.shape[0] == 5:
                p1, p2 = float(self.dist[2]), float(self.dist[3])
                r2, xy = x * x + y * y, x * y
                xd = xd + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
                yd = yd + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
        uv = np.stack([self.cx + self.fx * xd, self.cy + self.fy * yd], axis=-1)
        return uv, d

    def radial_scale(self, r2: NDArray[np.float64]) -> NDArray[np.float64]:
        """Radial distortion factor ``1 + k1 r^2 + k2 r^4 + k3 r^6`` for squared normalised radii
        ``r2`` (any shape); the tangential terms ``p1, p2`` are not in it."""
        k1, k2 = float(self.dist[0]), float(self.dist[1])
        s = 1.0 + k1 * r2 + k2 * r2 * r2
        if self.dist.shape[0] == 5:
            s = s + float(self.dist[4]) * r2 * r2 * r2
        return s

    def pixel_rays(self) -> NDArray[np.float64]:
        """(H, W, 3) float64 unit viewing ray of every pixel centre in world coordinates (no distortion)."""
        jj, ii = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        d = np.stack([(jj - self.cx) / self.fx, -(ii - self.cy) / self.fy, -np.ones_like(jj)], axis=-1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return d @ self.pose[:3, :3].T

    # ----------------------------------------------------------------------------- variants
    def scaled(self, factor: float) -> Camera:
        """The same camera with the image resampled by ``factor`` (0.5: half width and height).

        Pixel centres are kept consistent: ``u' = (u + 0.5) * factor - 0.5``.
        """
        if factor <= 0:
            raise ValueError("factor must be positive")
        w, h = round(self.width * factor), round(self.height * factor)
        return replace(self, width=int(w), height=int(h), fx=self.fx * factor, fy=self.fy * factor,
                       cx=(self.cx + 0.5) * factor - 0.5, cy=(self.cy + 0.5) * factor - 0.5)

    def shifted(self, du: float, dv: float) -> Camera:
        """The same camera with the image content moved by ``(du, dv)`` pixels (principal-point jitter)."""
        return replace(self, cx=self.cx + du, cy=self.cy + dv)

    def moved(self, pose: ArrayLike) -> Camera:
        """The same intrinsics at another camera-to-world ``pose`` (4, 4)."""
        return replace(self, pose=np.asarray(pose, dtype=np.float64))

    def fitted(self, size: tuple[int, int]) -> Camera:
        """The camera of this camera's frames once brought to ``size`` = ``(width, height)`` by
        :func:`tracker_service.sources.frame_source.fit_frame` (the centre of the aspect of ``size``
        cropped, :func:`fit_box`, then scaled to ``size``). ``self`` when the size is already right."""
        W, H = int(size[0]), int(size[1])
        if (W, H) == self.size:
            return self
        x0, y0, cw, ch, _ = fit_box((self.width, self.height), (W, H))
        sx, sy = W / cw, H / ch  # what cv2.resize of the crop to (W, H) does to pixel centres, per axis
        return replace(self, width=W, height=H, fx=self.fx * sx, fy=self.fy * sy,
                       cx=(self.cx + 0.5 - x0) * sx - 0.5, cy=(self.cy + 0.5 - y0) * sy - 0.5)

    # ----------------------------------------------------------------------------- placement figures
    @property
    def height_m(self) -> float:
        """Height of the camera centre above the floor (world ``y = 0``), metres."""
        return float(self.pose[1, 3])

    @property
    def tilt_deg(self) -> float:
        """Angle of the optical axis below the horizontal, degrees (positive: looking down)."""
        forward = -self.pose[:3, 2]
        return float(np.degrees(np.arcsin(np.clip(-forward[1], -1.0, 1.0))))

    @property
    def roll_deg(self) -> float:
        """Rotation of the image about the optical axis, degrees (0: the horizon is level)."""
        right, up = self.pose[:3, 0], self.pose[:3, 1]
        return float(np.degrees(np.arctan2(right[1], up[1])))

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view between the image's outer pixel edges, degrees (no distortion)."""
        left, right = (self.cx + 0.5) / self.fx, (self.width - 0.5 - self.cx) / self.fx
        return float(np.degrees(np.arctan(left) + np.arctan(right)))

    def summary(self) -> str:
        """One line: size, focal length, height, tilt, roll (when not level), horizontal fov, distortion."""
        out = (f"{self.width}x{self.height} f={self.fx:.1f}/{self.fy:.1f} px c=({self.cx:.1f}, {self.cy:.1f}), "
               f"{self.height_m:.2f} m high, tilt {self.tilt_deg:+.1f} deg")
        if abs(self.roll_deg) >= 0.05:
            out += f", roll {self.roll_deg:+.1f} deg"
        out += f", {self.hfov_deg:.1f} deg horizontal fov"
        if self.has_distortion:
            out += ", distortion (" + ", ".join(f"{v:.3g}" for v in self.dist) + ")"
        return out

    def digest(self) -> str:
        """A short hex digest of the camera (size, intrinsics, distortion, pose; rounded well below
        what changes a template) that names the database rendered for it."""
        def r(a: ArrayLike, nd: int) -> list[float]:
            return [round(float(v), nd) + 0.0 for v in np.asarray(a, np.float64).reshape(-1)]

        key = {"size": [self.width, self.height], "k": r([self.fx, self.fy, self.cx, self.cy], 3),
               "dist": r(self.dist, 6), "pose": r(self.pose[:3], 5)}
        return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:10]

    # ----------------------------------------------------------------------------- OpenCV's terms
    def to_opencv(self) -> dict[str, Any]:
        """The camera in OpenCV's terms (the camera file's format, see :meth:`from_opencv`).

        ``rotation`` / ``translation`` map world points into OpenCV's camera frame
        (``X_cv = R X_w + t``), so ``cv2.projectPoints(X_w, rvec(R), t, K, dist)`` equals
        :meth:`project` for points in front of the camera.
        """
        r_gl = self.pose[:3, :3]
        rot = CV_FROM_GL @ r_gl.T
        t = -rot @ self.pose[:3, 3]
        dist = np.zeros(5)
        dist[: self.dist.shape[0]] = self.dist
        return {"image_size": [self.width, self.height], "camera_matrix": self.K.tolist(),
                "dist_coeffs": [float(v) for v in dist], "rotation": rot.tolist(), "translation": t.tolist()}

    @classmethod
    def from_opencv(cls, data: Mapping[str, Any], *, what: str = "camera") -> Camera:
        """A camera from OpenCV's terms (world: Y up, metres, floor at ``y = 0``).

        Parameters
        ----------
        data : mapping
            ``image_size`` ``[W, H]``; ``camera_matrix`` ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``
            (pixel centres at integers, as OpenCV's calibration gives them); ``dist_coeffs``
            ``[k1, k2, p1, p2, k3]`` (also 0, 4, 8, 12 or 14 values, those past the fifth zero);
            ``rotation`` 3x3 world -> OpenCV camera (or a 3-vector Rodrigues rotation);
            ``translation`` ``[tx, ty, tz]`` world -> OpenCV camera, metres. Other keys are ignored.
        what : str
            How the message of an error names the input (e.g. ``camera file X``).

        Raises
        ------
        CameraFileError
            Missing keys, wrong shapes, non-finite numbers, skew, a rotation that is not orthonormal.
        """
        if not isinstance(data, Mapping):
            raise CameraFileError(f"{what}: expected a JSON object with keys {', '.join(OPENCV_KEYS)}")
        missing = [k for k in OPENCV_KEYS if k not in data]
        if missing:
            raise CameraFileError(f"{what}: missing key(s) {', '.join(missing)} (needs {', '.join(OPENCV_KEYS)})")
        size = _numbers(data["image_size"], "image_size", what, (2,))
        if not all(v >= 1 and float(v).is_integer() for v in size):
            raise CameraFileError(f"{what}: image_size must be two positive integers [width, height], "
                                  f"got {size.tolist()}")
        k = _numbers(data["camera_matrix"], "camera_matrix", what, (3, 3))
        if not (k[0, 0] > 0 and k[1, 1] > 0):
            raise CameraFileError(f"{what}: camera_matrix focal lengths must be positive, "
                                  f"got fx={k[0, 0]:g} fy={k[1, 1]:g}")
        if abs(k[0, 1]) > 1e-6 * k[0, 0] or np.any(np.abs(k[[1, 2, 2], [0, 0, 1]]) > 1e-9) or abs(k[2, 2] - 1.0) > 1e-9:
            raise CameraFileError(f"{what}: camera_matrix must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
        dist = _numbers(data["dist_coeffs"], "dist_coeffs", what, None).reshape(-1)
        if dist.size not in (0, 4, 5, 8, 12, 14):
            raise CameraFileError(f"{what}: dist_coeffs must have 4 or 5 values [k1, k2, p1, p2, k3], got {dist.size}")
        if dist.size > 5 and np.any(dist[5:]):
            raise CameraFileError(f"{what}: only the distortion model [k1, k2, p1, p2, k3] is supported "
                                  f"(the rational / thin-prism coefficients past the fifth must be 0)")
        d5 = np.zeros(5)
        d5[: min(dist.size, 5)] = dist[:5]
        rot = _numbers(data["rotation"], "rotation", what, None)
        if rot.size == 3:
            rot = _rodrigues(rot.reshape(3))
        if rot.shape != (3, 3):
            raise CameraFileError(f"{what}: rotation must be a 3x3 matrix (or a Rodrigues 3-vector), got shape "
                                  f"{list(rot.shape)}")
        err = float(np.abs(rot.T @ rot - np.eye(3)).max())
        if err > 1e-4:
            raise CameraFileError(f"{what}: rotation is not orthonormal (|R^T R - I| = {err:.2g})")
        if np.linalg.det(rot) < 0:
            raise CameraFileError(f"{what}: rotation is a reflection (determinant -1), not a rotation")
        u, _, vt = np.linalg.svd(rot)
        rot = u @ vt  # re-orthonormalised: files round their numbers
        t = _numbers(data["translation"], "translation", what, None).reshape(-1)
        if t.shape != (3,):
            raise CameraFileError(f"{what}: translation must be [tx, ty, tz] in metres, got {t.size} values")
        pose = np.eye(4)
        pose[:3, :3] = rot.T @ CV_FROM_GL  # camera (OpenGL axes) -> world
        pose[:3, 3] = -rot.T @ t  # camera centre
        return cls(int(size[0]), int(size[1]), float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2]),
                   pose=pose, dist=d5)


def fit_box(frame_size: tuple[int, int], size: tuple[int, int]) -> tuple[int, int, int, int, int]:
    """The part of a frame of ``frame_size`` = ``(w, h)`` that becomes a frame of ``size`` = ``(W, H)``
    (:func:`tracker_service.sources.frame_source.fit_frame`): the centre with the aspect of ``size``
    (a 16:9 frame loses its sides for a 4:3 size), trimmed to a multiple of the largest power of
    two ``k`` by which it is at least ``size``, so that it can be halved exactly ``log2 k`` times
    before the rest of the scaling (less than a factor of two).

    Parameters
    ----------
    frame_size, size : (int, int)
        ``(width, height)`` in pixels.

    Returns
    -------
    x0, y0, cw, ch, k : int
        The crop's top-left pixel and size; ``k`` a power of two (1: no halving).
    """
    w, h = int(frame_size[0]), int(frame_size[1])
    W, H = int(size[0]), int(size[1])
    s = max(W / w, H / h)  # the scale at which the frame covers ``size``
    cw, ch = min(w, max(1, round(W / s))), min(h, max(1, round(H / s)))
    k = 1
    while cw >= 2 * k * W and ch >= 2 * k * H:
        k *= 2
    cw, ch = cw - cw % k, ch - ch % k
    return (w - cw) // 2, (h - ch) // 2, cw, ch, k


def default_camera(width: int = 320, height: int = 240, *, distance_m: float = DEFAULT_DISTANCE_M,
                   height_m: float = DEFAULT_HEIGHT_M, target_height_m: float | None = None,
                   dist: ArrayLike = (0.0, 0.0)) -> Camera:
    """The paper's camera: a 640×480 sensor down-sampled to ``width`` × ``height`` (default 320×240).

    Parameters
    ----------
    width, height : int
        Output image size; must have the sensor's 4:3 aspect ratio.
    distance_m : float
        Distance from the camera to the subject's standing position (the world origin), metres.
    height_m : float
        Camera height above the floor, metres.
    target_height_m : float, optional
        Height of the point looked at above the origin (default: ``height_m``, a level camera).
    dist : (2,) float
        Radial distortion ``(k1, k2)``.

    Returns
    -------
    Camera
    """
    sw, sh = SENSOR_SIZE
    if width * sh != height * sw:
        raise ValueError(f"{width}x{height} is not 4:3 like the {sw}x{sh} sensor")
    native = Camera(sw, sh, SENSOR_FOCAL_PX, SENSOR_FOCAL_PX, (sw - 1) / 2.0, (sh - 1) / 2.0,
                    dist=np.asarray(dist, dtype=np.float64))
    cam = native.scaled(width / sw)
    th = height_m if target_height_m is None else target_height_m
    return cam.moved(look_at((0.0, height_m, distance_m), (0.0, th, 0.0)))


def placed_camera(height_m: float = DEFAULT_HEIGHT_M, tilt_deg: float = 0.0, hfov_deg: float | None = None,
                  width: int = 320, height: int = 240, distance_m: float = DEFAULT_DISTANCE_M) -> Camera:
    """The usual set-up from three figures: a camera ``height_m`` above the floor, ``distance_m`` in
    front of the origin (where the person stands, facing +Z), looking down by ``tilt_deg`` (negative:
    up), no roll, with a horizontal field of view of ``hfov_deg`` (None: the default camera's
    62.7 deg, f = 262.5 px at 320 px), square pixels, the principal point at the image centre.

    With the defaults it is :func:`default_camera` exactly.
    """
    if not height_m > 0:
        raise ValueError(f"camera height must be > 0 m, got {height_m}")
    if not -80.0 <= tilt_deg <= 80.0:
        raise ValueError(f"camera tilt must be within +-80 degrees, got {tilt_deg}")
    if hfov_deg is None:
        f = SENSOR_FOCAL_PX * width / SENSOR_SIZE[0]
    elif 5.0 <= hfov_deg <= 170.0:
        f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    else:
        raise ValueError(f"horizontal field of view must be within 5 and 170 degrees, got {hfov_deg}")
    cam = Camera(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)
    target_y = height_m - distance_m * math.tan(math.radians(tilt_deg))
    return cam.moved(look_at((0.0, height_m, distance_m), (0.0, target_y, 0.0)))


def same_camera(a: Camera, b: Camera, tol_px: float = 0.5) -> bool:
    """Whether two cameras give the same templates: the same image size, and points of the space a
    person fills (2.4 m wide, 2.2 m high, 2 m deep about the origin) project within ``tol_px``."""
    if a.size != b.size:
        return False
    g = np.stack(np.meshgrid(np.linspace(-1.2, 1.2, 7), np.linspace(0.0, 2.2, 7), np.linspace(-1.0, 1.0, 5),
                             indexing="ij"), axis=-1).reshape(-1, 3)
    ua, ub = a.project(g), b.project(g)
    na, nb = np.isnan(ua[:, 0]), np.isnan(ub[:, 0])
    if np.any(na != nb):
        return False
    ok = ~na
    return bool(np.all(np.abs(ua[ok] - ub[ok]) <= tol_px))


def load_camera_file(path: str | Path) -> Camera:
    """Read a camera file (JSON in OpenCV's terms, :meth:`Camera.from_opencv`).

    Raises
    ------
    CameraFileError
        The file is missing, unreadable, not JSON, or its content is wrong (one-line message).
    """
    p = Path(path)
    what = f"camera file {p}"
    try:
        text = p.read_text()
    except FileNotFoundError:
        raise CameraFileError(f"{what}: no such file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise CameraFileError(f"{what}: cannot read it ({e})") from None
    try:
        data = json.loads(text)
    except ValueError as e:
        raise CameraFileError(f"{what}: not valid JSON ({e})") from None
    return Camera.from_opencv(data, what=what)


def save_camera_file(camera: Camera, path: str | Path, extra: Mapping[str, Any] | None = None) -> Path:
    """Write ``camera`` as a camera file; ``extra`` keys (a summary, the calibration's error) are
    written after the five the format needs and ignored when it is read."""
    p = Path(path)
    data = camera.to_opencv() | {"height_m": round(camera.height_m, 4), "tilt_deg": round(camera.tilt_deg, 3),
                                 "hfov_deg": round(camera.hfov_deg, 3)} | dict(extra or {})
    if p.parent != Path():
        p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(data, indent=1) + "\n")
    return p


def _numbers(value: Any, key: str, what: str, shape: tuple[int, ...] | None) -> NDArray[np.float64]:
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CameraFileError(f"{what}: {key} must be numbers, got {str(value)[:60]}") from None
    if shape is not None and a.shape != shape:
        raise CameraFileError(f"{what}: {key} must have shape {list(shape)}, got {list(a.shape)}")
    if a.dtype == object or not np.all(np.isfinite(a)):
        raise CameraFileError(f"{what}: {key} has non-finite numbers")
    return a


def _rodrigues(rvec: NDArray[np.float64]) -> NDArray[np.float64]:
    theta = float(np.linalg.norm(rvec))
    if theta < 1e-15:
        return np.eye(3)
    k = rvec / theta
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(theta) * kx + (1.0 - math.cos(theta)) * kx @ kx
