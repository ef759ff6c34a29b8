"""Calibrated pinhole camera: intrinsics, extrinsics, optional radial distortion, vectorised projection.

Conventions
-----------
World: right-handed, Y up, metres. The camera frame follows pyrender/OpenGL: the camera looks
along its own **-Z** axis, +Y is up in the image, +X right. :attr:`Camera.pose` is the
camera-to-world transform in that convention (what ``pyrender.Scene.add(camera, pose=...)`` takes).

Image coordinates (2D code only) follow OpenCV: ``u`` to the right, ``v`` down, and the *centre*
of pixel ``(row i, column j)`` is at ``(u, v) = (j, i)``. A point ``X_c`` in camera coordinates at
depth ``d = -Z_c > 0`` projects to::

    x = X_c / d,  y = -Y_c / d,  s = 1 + k1 r^2 + k2 r^4  (r^2 = x^2 + y^2)
    u = cx + fx * s * x,  v = cy + fy * s * y

The default camera is the paper's setup (Okada & Stenger §3): a 640×480 sensor down-sampled to
320×240, a webcam-like 62.7° horizontal field of view, 1.2 m above the floor, 3.0 m in front of
the subject who stands at the world origin facing +Z (towards the camera).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "DEFAULT_DISTANCE_M",
    "DEFAULT_HEIGHT_M",
    "SENSOR_FOCAL_PX",
    "SENSOR_SIZE",
    "Camera",
    "default_camera",
    "look_at",
]

#: Native sensor resolution (width, height) of the paper's colour camera.
SENSOR_SIZE: tuple[int, int] = (640, 480)
#: Focal length of the native sensor in pixels (62.7° x 48.9° field of view).
SENSOR_FOCAL_PX: float = 525.0
#: Default camera height above the floor and distance to the subject, metres.
DEFAULT_HEIGHT_M: float = 1.2
DEFAULT_DISTANCE_M: float = 3.0


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
    dist : (2,) float64
        Radial distortion ``(k1, k2)`` applied to normalised coordinates (zeros: none).
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
        if dist.shape != (2,):
            raise ValueError("dist must be (k1, k2)")
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
        uv = np.stack([self.cx + self.fx * s * x, self.cy + self.fy * s * y], axis=-1)
        return uv, d

    def radial_scale(self, r2: NDArray[np.float64]) -> NDArray[np.float64]:
        """Distortion factor ``1 + k1 r^2 + k2 r^4`` for squared normalised radii ``r2`` (any shape)."""
        k1, k2 = float(self.dist[0]), float(self.dist[1])
        return 1.0 + k1 * r2 + k2 * r2 * r2

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
