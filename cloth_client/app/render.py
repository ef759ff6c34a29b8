"""Offscreen pyrender view of the avatar and its garment, written to PNG / GIF / MP4.

The OpenGL platform is chosen here, before pyrender is imported: EGL (headless GPU or Mesa) by
default; set ``PYOPENGL_PLATFORM=osmesa`` in the environment to use OSMesa instead.

The avatar is one smooth skinned surface around the body's capsules
(:mod:`cloth_client.avatar.skin_mesh`), posed per frame on the capsules the cloth was simulated on
(or, with ``skinned=False``, the capsules themselves, each meshed once and moved); the cloth mesh
is rebuilt per frame with smooth vertex normals and a double-sided material. The camera keeps the
avatar in frame: it looks at the body from a fixed angle relative to its facing direction, far
enough that the floor and the head or the raised hands fit, all smoothed so that turns, steps and
raised arms do not shake the picture.
"""

from __future__ import annotations

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import logging
import math
from pathlib import Path
from types import TracebackType
from typing import Any

import cv2
import numpy as np
import pyrender
import trimesh
from numpy.typing import NDArray

from cloth_client.avatar.capsules import avatar_capsules, capsule_endpoints
from cloth_client.avatar.limb_clearance import LIMB_CLEARANCE
from cloth_client.avatar.skin_mesh import SkinnedMesh, build_skinned_mesh, pose_vertices
from cloth_client.solver.garment import Garment
from protocol.formats.video import GifFrames
from protocol.skeleton import Body

__all__ = ["ClothRenderer", "FrameWriter", "round_cone_mesh", "vertex_normals"]

log = logging.getLogger(__name__)
F64 = NDArray[np.float64]
_CLOTH_COLOUR = {"cape": (0.62, 0.08, 0.10, 1.0), "skirt": (0.13, 0.30, 0.62, 1.0)}
_SKIN = (0.80, 0.68, 0.58, 1.0)
#: Camera azimuth relative to the body's facing direction, degrees (0 = in front).
_VIEW_AZIMUTH = {"cape": 145.0, "skirt": 35.0}


def round_cone_mesh(length: float, ra: float, rb: float, sections: int = 24) -> trimesh.Trimesh:
    """Closed mesh of the round cone from ``(0, 0, 0)`` (radius ``ra``) to ``(0, 0, length)`` (``rb``)."""
    sin_phi = float(np.clip((ra - rb) / max(length, 1e-9), -0.999, 0.999))
    phi = math.asin(sin_phi)
    # profile (radius, z): from the bottom pole over sphere a, along the side, over sphere b
    ang_a = np.linspace(-math.pi / 2, phi, 8)
    ang_b = np.linspace(phi, math.pi / 2, 8)
    prof = np.concatenate([
        np.stack([ra * np.cos(ang_a), ra * np.sin(ang_a)], 1),
        np.stack([rb * np.cos(ang_b), length + rb * np.sin(ang_b)], 1),
    ])
    prof[0, 0] = prof[-1, 0] = 0.0
    return trimesh.creation.revolve(prof, sections=sections)


def _align_z(a: F64, b: F64) -> F64:
    """4x4 pose mapping the +Z axis onto the segment ``a -> b`` with its origin at ``a``."""
    d = b - a
    z = d / max(float(np.linalg.norm(d)), 1e-12)
    ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(ref, z)
    x /= np.linalg.norm(x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, np.cross(z, x), z, a
    return m


def vertex_normals(x: F64, tris: NDArray[np.int64]) -> F64:
    """Area-weighted unit vertex normals ``(N, 3)`` of a triangle mesh."""
    c = np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]])
    n = np.stack([np.bincount(tris.ravel(), np.repeat(c[:, d], 3), len(x)) for d in range(3)], 1)
    out: F64 = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return out


def _look_at(eye: F64, target: F64) -> F64:
    f = target - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, [0.0, 1.0, 0.0])
    r /= max(float(np.linalg.norm(r)), 1e-9)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = r, np.cross(r, f), -f, eye
    return m


class ClothRenderer:
    """Render the avatar and its garment offscreen.

    Parameters
    ----------
    body : Body
    garment : Garment
    width, height : int
        Image size in pixels.
    azimuth_deg : float, optional
        Camera angle around the body relative to its facing (default: from behind-left for a cape,
        front-right for a skirt).
    limb_clearance : float or None
        The driver's :attr:`~cloth_client.solver.driver.DriverConfig.limb_clearance`, so the avatar drawn
        is the one simulated.
    skinned : bool
        Draw the avatar as one smooth skinned surface around its capsules
        (:mod:`cloth_client.avatar.skin_mesh`, built once per body in about half a second) rather
        than as the capsules themselves.
    """

    def __init__(self, body: Body, garment: Garment, width: int = 640, height: int = 480,
                 azimuth_deg: float | None = None, limb_clearance: float | None = LIMB_CLEARANCE,
                 skinned: bool = True) -> None:
        self.body, self.garment = body, garment
        self.limb_clearance = limb_clearance
        self.size = (int(width), int(height))
        self.azimuth = math.radians(_VIEW_AZIMUTH.get(garment.kind, 30.0) if azimuth_deg is None else azimuth_deg)
        self.scene = pyrender.Scene(bg_color=(0.93, 0.94, 0.96, 1.0), ambient_light=(0.18, 0.18, 0.18))
        skin = pyrender.MetallicRoughnessMaterial(baseColorFactor=_SKIN, roughnessFactor=0.8)
        self.cloth_material = pyrender.MetallicRoughnessMaterial(
            baseColorFactor=_CLOTH_COLOUR.get(garment.kind, (0.5, 0.5, 0.5, 1.0)), roughnessFactor=0.9,
            doubleSided=True)
        self.skin_material = skin
        self.capsule_nodes = []
        self.skin: SkinnedMesh | None = build_skinned_mesh(body) if skinned else None
        self.skin_node: Any = None
        if self.skin is None:
            a, b = capsule_endpoints(body, garment.pose)
            for c in range(len(a)):
                length = float(np.linalg.norm(b[c] - a[c]))
                mesh = round_cone_mesh(length, float(body.capsule_radii[c, 0]), float(body.capsule_radii[c, 1]))
                self.capsule_nodes.append(self.scene.add(pyrender.Mesh.from_trimesh(mesh, material=skin, smooth=True)))
        floor = trimesh.creation.box(extents=(40.0, 0.02, 40.0))
        floor.apply_translation((0.0, -0.01, 0.0))
        floor_mat = pyrender.MetallicRoughnessMaterial(baseColorFactor=(0.72, 0.72, 0.70, 1.0), roughnessFactor=1.0)
        self.scene.add(pyrender.Mesh.from_trimesh(floor, material=floor_mat, smooth=False))
        self.camera = pyrender.PerspectiveCamera(yfov=math.radians(40.0), aspectRatio=width / height)
        self.camera_node = self.scene.add(self.camera, pose=np.eye(4))
        self.key_light = self.scene.add(pyrender.DirectionalLight(intensity=3.5), pose=np.eye(4))
        self.fill_light = self.scene.add(pyrender.DirectionalLight(intensity=1.0), pose=np.eye(4))
        self.cloth_node: Any = None
        self._target: F64 | None = None
        self._yaw: float | None = None
        self._span: float | None = None
        self.renderer = pyrender.OffscreenRenderer(width, height)

    def _frame_camera(self, pose: F64, top: float) -> None:
        """Aim at the body: ``top`` is the avatar's highest point (raised hands stay in the picture)."""
        root = pose[:3]
        fwd = trimesh.transformations.rotation_matrix(float(np.linalg.norm(pose[3:6])), pose[3:6] + 1e-12)[:3, :3]
        facing = fwd @ np.array([0.0, 0.0, 1.0])
        yaw = math.atan2(facing[0], facing[2])
        if self._yaw is None or self._target is None:
            self._yaw, self._target = yaw, root.copy()
        else:  # low-pass follow (about 1 s for the angle, 0.3 s for the position at 30 fps)
            self._yaw += 0.03 * math.remainder(yaw - self._yaw, 2 * math.pi)
            self._target = self._target + 0.12 * (root - self._target)
        span = max(1.05 * self.body.height, top + 0.08)  # floor to above the head or the raised hands
        # the framing grows at once when a hand goes up and shrinks back in about a second
        self._span = span if self._span is None or span > self._span else self._span + 0.05 * (span - self._span)
        dist = self._span / (2.0 * math.tan(self.camera.yfov / 2.0)) + 0.3
        ang = self._yaw + self.azimuth
        target = np.array([self._target[0], 0.5 * self._span, self._target[2]])
        eye = target + dist * np.array([math.sin(ang) * math.cos(0.2), math.sin(0.2), math.cos(ang) * math.cos(0.2)])
        self.scene.set_pose(self.camera_node, _look_at(eye, target))
        side = np.array([math.cos(ang), 0.0, -math.sin(ang)])  # to the camera's right
        self.scene.set_pose(self.key_light, _look_at(eye + 1.5 * side + np.array([0.0, 3.0, 0.0]), target))
        self.scene.set_pose(self.fill_light, _look_at(2 * target - eye + np.array([0.0, 2.0, 0.0]), target))

    def render(self, pose: F64, cloth_x: F64, capsules: tuple[F64, F64] | None = None) -> NDArray[np.uint8]:
        """RGB image ``(H, W, 3) uint8`` of the avatar at ``pose (P,)`` wearing cloth ``cloth_x (N, 3)``.

        ``capsules`` (two ``(C, 3)`` endpoint arrays) are the avatar the cloth was simulated on
        (:attr:`cloth_client.solver.driver.ClothDriver.body_capsules`, whose sunk-limb corrections carry
        over from frame to frame); None computes them from ``pose`` alone."""
        a, b = capsules if capsules is not None else avatar_capsules(self.body, pose, self.limb_clearance)
        for c, node in enumerate(self.capsule_nodes):
            self.scene.set_pose(node, _align_z(a[c], b[c]))
        if self.skin is not None:
            if self.skin_node is not None:
                self.scene.remove_node(self.skin_node)
            v = pose_vertices(self.skin, self.body, pose, a, b)
            body_mesh = trimesh.Trimesh(v, self.skin.faces, vertex_normals=vertex_normals(v, self.skin.faces),
                                        process=False)
            self.skin_node = self.scene.add(pyrender.Mesh.from_trimesh(body_mesh, material=self.skin_material,
                                                                       smooth=True))
        if self.cloth_node is not None:
            self.scene.remove_node(self.cloth_node)
        tris = self.garment.triangles
        mesh = trimesh.Trimesh(cloth_x, tris, vertex_normals=vertex_normals(cloth_x, tris), process=False)
        self.cloth_node = self.scene.add(pyrender.Mesh.from_trimesh(mesh, material=self.cloth_material, smooth=True))
        self._frame_camera(pose, float(max(a[:, 1].max(), b[:, 1].max()) + self.body.capsule_radii.max()))
        colour, _ = self.renderer.render(self.scene)
        return np.ascontiguousarray(colour[..., :3])

    def close(self) -> None:
        """Release the OpenGL context."""
        self.renderer.delete()

    def __enter__(self) -> ClothRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class FrameWriter:
    """Write RGB frames to a video (``.mp4``: H.264 through :class:`protocol.formats.video.VideoWriter`;
    ``.gif`` via imageio, at most 400 frames however long the session,
    :class:`protocol.formats.video.GifFrames`) or, for any other path, as numbered PNG files in that
    directory.

    Parameters
    ----------
    path : str or Path
    fps : float
        Frame rate of the video.
    """

    def __init__(self, path: str | Path, fps: float) -> None:
        self.path = Path(path)
        self.fps = float(fps)
        self.count = 0
        self._video: Any = None
        self._gif = GifFrames()  # bounded: thinned as frames come
        self.kind = {".mp4": "mp4", ".gif": "gif"}.get(self.path.suffix.lower(), "png")
        (self.path if self.kind == "png" else self.path.parent).mkdir(parents=True, exist_ok=True)

    def write(self, rgb: NDArray[np.uint8]) -> None:
        """Append one ``(H, W, 3) uint8`` frame."""
        if self.kind == "mp4":
            if self._video is None:
                from protocol.formats.video import VideoWriter

                self._video = VideoWriter(self.path, self.fps)
            self._video.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        elif self.kind == "gif":
            self._gif.add(rgb)
        else:
            cv2.imwrite(str(self.path / f"frame_{self.count:05d}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        self.count += 1

    def close(self) -> None:
        """Finish the file (GIF frames are encoded here)."""
        if self._video is not None:
            self._video.close()
            self._video = None
        if self.kind == "gif" and self._gif.frames:
            import imageio.v2 as imageio  # pyrender's own dependency

            # imageio 2.28 and later take the frame duration in milliseconds
            imageio.mimsave(self.path, list(self._gif.frames), duration=round(1000 * self._gif.duration_s(self.fps)),
                            loop=0)
            self._gif = GifFrames()

    def __enter__(self) -> FrameWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
