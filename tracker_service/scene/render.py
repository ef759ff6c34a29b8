"""Per-frame rendering of the synthetic scene (see :mod:`tracker_service.scene.synthetic`): the person's
lit colour pass and segmentation pass in pyrender, planar soft shadows, compositing over the
pre-rendered room, and the camera's exposure, vignetting, sensor noise and lens distortion.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pyrender
from numpy.typing import NDArray

from protocol.skeleton import JOINT_INDEX, N_PARTS
from tracker_service.camera import Camera
from tracker_service.scene import textures as tx
from tracker_service.scene.gl import (
    close_renderer,
    deterministic_renderer,
    gl_camera,
    label_colours,
    labels_from_seg,
    primitive,
    textured_material,
    update_primitive,
)
from tracker_service.scene.room import (
    FLOOR,
    add_lights,
    build_room,
    planar_shadow,
    random_lighting,
    render_background,
    shadow_strength_map,
)
from tracker_service.scene.subject import MATERIALS, ClothedSubject
from tracker_service.scene.variation import SceneVariation, photo_room, vary_lighting

__all__ = ["SHADOW_FLOOR", "SHADOW_WALL", "SceneRenderer"]

log = logging.getLogger(__name__)

#: Segmentation labels of the person's shadow on the floor and on the back wall.
SHADOW_FLOOR, SHADOW_WALL = N_PARTS, N_PARTS + 1
_FEET = [JOINT_INDEX[n] for n in ("l_ankle", "l_toe", "r_ankle", "r_toe")]
_NOISE_PAD = 1 << 17  # the per-frame noise is a window of a fixed Gaussian bank at a random offset


def _groups(faces: NDArray[np.int64], key: NDArray[np.int64],
            n: int) -> list[tuple[NDArray[np.int64], NDArray[np.int64]]]:
    """Per key value: the vertices its faces use and the faces re-indexed into that subset."""
    out = []
    for k in range(n):
        f = faces[key == k]
        verts, inv = np.unique(f.reshape(-1), return_inverse=True)
        out.append((verts, inv.reshape(-1, 3).astype(np.int64)))
    return out


class SceneRenderer:
    """GL state of one synthetic scene.

    Parameters
    ----------
    subject : ClothedSubject
    camera : Camera
        The undisturbed camera (frames may shift its principal point).
    rng : np.random.Generator
        Draws the room, the lighting and the textures.
    variation : SceneVariation, optional
        Lights and backdrop varied (:mod:`tracker_service.scene.variation`), noise scaled.
    vary : np.random.Generator, optional
        Draws the variation's lights and backdrop (its own stream: the default draw stays the same).
    """

    def __init__(self, subject: ClothedSubject, camera: Camera, rng: np.random.Generator,
                 variation: SceneVariation | None = None, vary: np.random.Generator | None = None) -> None:
        self.subject = subject
        self.camera = camera
        self.lighting = random_lighting(rng)
        self.room = build_room(rng)
        self.noise_scale = 1.0
        if variation is not None and variation.axes:
            vary = vary if vary is not None else np.random.default_rng()
            self.lighting = vary_lighting(self.lighting, variation.lights, vary)
            if "backdrop" in variation.axes:
                self.room = photo_room(self.room, vary)
            self.noise_scale = variation.noise_scale
        self._renderer = deterministic_renderer(camera.width, camera.height)
        self.background, self.surface = render_background(self.room, self.lighting, camera, self._renderer)
        spec = subject.spec
        textures = {
            "skin": tx.skin_texture(rng, spec.skin), "head": tx.head_texture(rng, spec.skin, spec.hair, spec.long_hair),
            "shirt": tx.fabric_texture(rng, spec.shirt, spec.shirt_pattern),
            "lower": tx.fabric_texture(rng, spec.lower, spec.lower_pattern),
            "shoes": tx.plain_texture(rng, spec.shoes), "hair": tx.fabric_texture(rng, spec.hair, "plain")}
        self._materials = [textured_material(textures[m], roughness=0.9 if m != "shoes" else 0.6) for m in MATERIALS]
        faces = subject.surface.faces
        self._by_material = _groups(faces, subject.face_material, len(MATERIALS))
        self._by_part = _groups(faces, subject.face_part, N_PARTS)
        self._colours = label_colours(N_PARTS + 2)
        amb = self.lighting.ambient
        self._scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 0.0], ambient_light=[amb, amb, amb])
        self._cam = gl_camera(camera)
        self._scene.add(self._cam, pose=camera.pose)
        add_lights(self._scene, self.lighting)
        # persistent nodes whose vertex buffers are rewritten every frame
        v0, uv0 = subject.surface.vertices, subject.surface.uv
        ones = np.ones((len(v0), 4), np.float32)
        self._lit_prims = [(vi, primitive(v0[vi], f, None, self._materials[k], uv0[vi], ones[vi]))
                           for k, (vi, f) in enumerate(self._by_material) if len(f)]
        self._scene.add(pyrender.Mesh([p for _, p in self._lit_prims]), name="person")
        self._seg_map: dict[pyrender.Node, NDArray[np.uint8]] = {}
        self._seg_prims: list[tuple[NDArray[np.int64] | None, int, pyrender.Primitive]] = []
        for k, (vi, f) in enumerate(self._by_part):
            if len(f):
                self._add_seg(vi, k, primitive(v0[vi], f))
        for code in (SHADOW_FLOOR, SHADOW_WALL):
            self._add_seg(None, code, primitive(v0, faces))
        h, w = camera.height, camera.width
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((xx - camera.cx) ** 2 + (yy - camera.cy) ** 2) / (camera.fx**2)
        self._vignette = (1.0 / (1.0 + 0.35 * r2) ** 2).astype(np.float32)[..., None]
        self._maps = self._distortion_maps() if camera.has_distortion else None
        n_px = camera.height * camera.width * 3
        self._noise_bank = rng.standard_normal(n_px + _NOISE_PAD, dtype=np.float32)
        self._bg_cache: tuple[tuple[float, float], NDArray[np.float32]] | None = None

    def _add_seg(self, vi: NDArray[np.int64] | None, code: int, prim: pyrender.Primitive) -> None:
        node = self._scene.add(pyrender.Mesh([prim], is_visible=False), name=f"seg_{code:03d}")
        self._seg_map[node] = self._colours[code]
        self._seg_prims.append((vi, code, prim))

    def close(self) -> None:
        """Release the GL context (idempotent)."""
        close_renderer(self._renderer)
        self._renderer = None

    # ------------------------------------------------------------------------------ per frame
    def _shifted_background(self, cam: Camera) -> NDArray[np.float32]:
        shift = (cam.cx - self.camera.cx, cam.cy - self.camera.cy)
        if shift == (0.0, 0.0):
            return self.background
        if self._bg_cache is not None and self._bg_cache[0] == shift:
            return self._bg_cache[1]
        m = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]], np.float32)
        size = (cam.width, cam.height)
        bg = np.asarray(cv2.warpAffine(self.background, m, size, flags=cv2.INTER_LINEAR,
                                       borderMode=cv2.BORDER_REPLICATE), np.float32)
        self._bg_cache = (shift, bg)
        return bg

    def empty(self, cam: Camera) -> NDArray[np.float32]:
        """The empty room seen by ``cam`` (float32 RGB in [0, 1])."""
        return self._shifted_background(cam).copy()

    def render(self, pose: NDArray[np.float64],
               cam: Camera) -> tuple[NDArray[np.float32], NDArray[np.uint8], NDArray[np.float64]]:
        """The person in ``pose`` composited into the room.

        Returns
        -------
        image : (H, W, 3) float32
            RGB in [0, 1] before exposure and noise.
        seg : (H, W, 3) uint8
            Segmentation image (:func:`~tracker_service.scene.gl.label_colours` codes: parts, then
            :data:`SHADOW_FLOOR`, :data:`SHADOW_WALL`).
        joints : (J, 3) float64
        """
        assert self._renderer is not None, "renderer closed"
        verts, normals, joints = self.subject.pose_mesh(pose)
        uv = self.subject.surface.uv
        shade = self._vertex_shade(normals)
        for vi, prim in self._lit_prims:
            update_primitive(self._renderer, prim, verts[vi], None, uv[vi], shade[vi])
        floor, wall = planar_shadow(verts, self.lighting.key_dir, self.room.back_z)
        for sub_idx, code, prim in self._seg_prims:
            pts = floor if sub_idx is None else verts[sub_idx]
            if code == SHADOW_WALL:
                pts = wall
            update_primitive(self._renderer, prim, pts)
        seg_map = self._seg_map
        self._cam.cx, self._cam.cy = cam.gl_intrinsics()[2:]
        colour, _ = self._renderer.render(self._scene, pyrender.RenderFlags.RGBA | pyrender.RenderFlags.FLAT)
        for node in seg_map:
            node.mesh.is_visible = True
        seg, _ = self._renderer.render(self._scene, pyrender.RenderFlags.SEG, seg_node_map=seg_map)
        for node in seg_map:
            node.mesh.is_visible = False
        seg = np.asarray(seg)
        lab = labels_from_seg(seg)
        shade = shadow_strength_map(lab == SHADOW_FLOOR, lab == SHADOW_WALL, self.surface, 2.0)
        shade = np.maximum(shade, self._contact_shadow(joints, cam))
        bg = self._shifted_background(cam) * (1.0 - self.lighting.shadow_strength * shade[..., None])
        rgba = np.asarray(colour, np.float32) * (1.0 / 255.0)
        image = rgba[..., :3] + (1.0 - rgba[..., 3:4]) * bg
        return image, seg, joints

    def _vertex_shade(self, normals: NDArray[np.float64]) -> NDArray[np.float32]:
        """Per-vertex diffuse lighting as a display-space colour multiplier, RGBA (V, 4) float32.

        Lambert terms of the key and fill lights plus the ambient light with the constants of
        pyrender's metallic-roughness shader for a matte dielectric (``0.96 / pi`` per unit
        intensity), so the person matches the room rendered with that shader; then gamma 1/2.2
        because the flat shader multiplies the sRGB texture directly. Cheaper than per-pixel
        shading on the software rasteriser and indistinguishable at this resolution.
        """
        lt = self.lighting
        k = 0.96 / np.pi
        key = np.clip(normals @ -lt.key_dir, 0.0, None)[:, None] * (k * lt.key_intensity * lt.key_colour)[None, :]
        fill = np.clip(normals @ -lt.fill_dir, 0.0, None)[:, None] * (k * lt.fill_intensity)
        lin = lt.ambient + key + fill
        out = np.ones((len(normals), 4), np.float32)
        out[:, :3] = np.power(lin, 1.0 / 2.2)
        return out

    def _contact_shadow(self, joints: NDArray[np.float64], cam: Camera) -> NDArray[np.float32]:
        """Soft dark blobs on the floor under feet that are close to it (ambient occlusion)."""
        out = np.zeros((cam.height, cam.width), np.float32)
        for j in _FEET:
            height = joints[j, 1]
            if height > 0.2:
                continue
            p = np.array([joints[j, 0], 0.0, joints[j, 2]])
            (u, v), d = cam.project_with_depth(p)
            if not (np.isfinite(u) and d > 0.1):
                continue
            ax = cam.fx * 0.09 / d
            ay = ax * max(cam.position[1] / max(d, 1e-3), 0.15)
            strength = 0.6 * (1.0 - height / 0.2)
            cv2.ellipse(out, (round(u * 4), round(v * 4)), (int(ax * 4), max(int(ay * 4), 1)), 0, 0, 360,
                        float(strength), -1, cv2.LINE_AA, shift=2)
        out = np.asarray(cv2.GaussianBlur(out, (0, 0), 2.0), np.float32)
        return np.where(self.surface == FLOOR, out, 0.0).astype(np.float32)

    def finish(self, image: NDArray[np.float32], gain: NDArray[np.float32],
               rng: np.random.Generator | None) -> NDArray[np.uint8]:
        """Exposure gain, vignetting and sensor noise; returns BGR uint8.

        Noise is read noise (sigma 1.2 / 255) plus shot noise (variance proportional to the signal,
        sigma 3.5 / 255 at mid grey): a window of a fixed Gaussian bank at an offset drawn from
        ``rng`` (None: no noise, no vignetting)."""
        if rng is None:
            out = image
        else:
            out = image * (gain[None, None, :] * self._vignette)
            var = np.maximum(out, 0.0)
            var *= np.float32(2.0 * (3.5 / 255.0) ** 2)
            var += np.float32((1.2 / 255.0) ** 2)
            off = int(rng.integers(_NOISE_PAD))
            noise = self._noise_bank[off:off + out.size].reshape(out.shape)
            out += np.sqrt(var, out=var) * (noise if self.noise_scale == 1.0 else noise * np.float32(self.noise_scale))
        u8 = np.clip(out * 255.0 + 0.5, 0, 255).astype(np.uint8)
        return np.ascontiguousarray(u8[..., ::-1])

    # ------------------------------------------------------------------------------ distortion
    def _distortion_maps(self) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """For every pixel of the distorted image, where to sample the undistorted render."""
        c = self.camera
        yy, xx = np.mgrid[0:c.height, 0:c.width].astype(np.float64)
        xd, yd = (xx - c.cx) / c.fx, (yy - c.cy) / c.fy
        xu, yu = xd.copy(), yd.copy()
        for _ in range(8):  # fixed point of x_d = x_u * s(r_u^2)
            s = c.radial_scale(xu * xu + yu * yu)
            xu, yu = xd / s, yd / s
        return (xu * c.fx + c.cx).astype(np.float32), (yu * c.fy + c.cy).astype(np.float32)

    def distort(self, image: NDArray[np.uint8], labels: NDArray[np.int8]) -> tuple[NDArray[np.uint8], NDArray[np.int8]]:
        """Apply the camera's radial distortion to an image and its label map (no-op without)."""
        if self._maps is None:
            return image, labels
        mx, my = self._maps
        img = np.asarray(cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), np.uint8)
        lab = cv2.remap(labels.astype(np.int16), mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                        borderValue=-1)
        return img, lab.astype(np.int8)
