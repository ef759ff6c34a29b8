"""pyrender plumbing shared by the synthetic scene and the mesh-silhouette reference.

Importing this module selects the EGL platform for PyOpenGL (``PYOPENGL_PLATFORM=egl``, unless the
environment already chose one) *before* pyrender is imported: without it pyrender looks for an X
display. EGL works headless with Mesa's software rasteriser (llvmpipe).

:class:`MeshRasterizer` renders triangle meshes seen by a :class:`~tracker_service.camera.Camera`
into a binary silhouette or a part-label image (segmentation pass, one node per part,
depth-tested) -- the "true mesh silhouette" the fast capsule renderer is checked against.
"""

from __future__ import annotations

import logging
import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np
import pyrender
from numpy.typing import ArrayLike, NDArray
from OpenGL.GL import GL_ARRAY_BUFFER, glBindBuffer, glBufferSubData

from tracker_service.camera import Camera

__all__ = ["MeshRasterizer", "close_renderer", "deterministic_renderer", "gl_camera", "label_colours",
           "labels_from_seg", "primitive", "textured_material", "update_primitive"]

log = logging.getLogger(__name__)


def gl_camera(camera: Camera) -> pyrender.IntrinsicsCamera:
    """A ``pyrender.IntrinsicsCamera`` with the intrinsics of ``camera`` (distortion is not modelled)."""
    fx, fy, cx, cy = camera.gl_intrinsics()
    return pyrender.IntrinsicsCamera(fx, fy, cx, cy, znear=camera.znear, zfar=camera.zfar)


def label_colours(n: int) -> NDArray[np.uint8]:
    """(n, 3) uint8 segmentation colours encoding label ``k`` as red = ``k + 1`` (0 = background)."""
    if not 0 < n < 255:
        raise ValueError("between 1 and 254 labels")
    out = np.zeros((n, 3), np.uint8)
    out[:, 0] = np.arange(1, n + 1)
    return out


def labels_from_seg(seg: NDArray[np.uint8]) -> NDArray[np.int8]:
    """Decode a segmentation image made with :func:`label_colours`: (H, W, 3) uint8 -> (H, W) int8, -1 background."""
    return (seg[..., 0].astype(np.int16) - 1).astype(np.int8)


def primitive(vertices: ArrayLike, faces: ArrayLike, normals: ArrayLike | None = None,
              material: pyrender.Material | None = None, texcoords: ArrayLike | None = None,
              colors: ArrayLike | None = None) -> pyrender.Primitive:
    """A triangle primitive from arrays (float32 attributes; ``colors`` are RGBA per vertex)."""
    return pyrender.Primitive(
        positions=np.asarray(vertices, dtype=np.float32),
        normals=None if normals is None else np.asarray(normals, dtype=np.float32),
        texcoord_0=None if texcoords is None else np.asarray(texcoords, dtype=np.float32),
        color_0=None if colors is None else np.asarray(colors, dtype=np.float32),
        indices=np.asarray(faces), material=material, mode=pyrender.constants.GLTF.TRIANGLES)


def textured_material(texture: NDArray[np.uint8], roughness: float = 0.85,
                      emissive: float = 0.0) -> pyrender.MetallicRoughnessMaterial:
    """A matte (non-metallic) material with an ``(H, W, 3) uint8`` RGB texture.

    Texture rows are flipped on upload: the textures of :mod:`tracker_service.scene.textures` put
    ``v = 0`` on their first row, pyrender samples ``v = 0`` from the last.
    """
    tex = pyrender.Texture(source=np.ascontiguousarray(texture[::-1]), source_channels="RGB")
    return pyrender.MetallicRoughnessMaterial(
        baseColorTexture=tex, metallicFactor=0.0, roughnessFactor=roughness,
        emissiveTexture=tex if emissive > 0 else None,
        emissiveFactor=np.full(3, emissive) if emissive > 0 else None)


def deterministic_renderer(width: int, height: int) -> pyrender.OffscreenRenderer:
    """An offscreen renderer that draws opaque mesh nodes in the order of their names.

    pyrender draws opaque nodes sorted by their pose's distance from the camera and otherwise in
    the iteration order of a ``set`` (memory addresses): two renderings of the same scene built
    twice can then resolve coincident surfaces (z-fighting) differently. Naming the nodes and
    drawing them by name makes every frame reproducible.
    """
    r = pyrender.OffscreenRenderer(width, height)
    inner = r._renderer

    def ordered(scene: pyrender.Scene) -> list[pyrender.Node]:
        nodes = list(scene.mesh_nodes)
        solid = sorted((n for n in nodes if not n.mesh.is_transparent), key=lambda n: n.name or "")
        cam = scene.get_pose(scene.main_camera_node)[:3, 3]
        trans = sorted((n for n in nodes if n.mesh.is_transparent),
                       key=lambda n: -float(np.linalg.norm(scene.get_pose(n)[:3, 3] - cam)))
        return solid + trans

    inner._sorted_mesh_nodes = ordered
    return r


def close_renderer(renderer: pyrender.OffscreenRenderer | None) -> None:
    """Free a renderer's GL objects and its context without ``eglTerminate``.

    pyrender's own ``OffscreenRenderer.delete`` terminates the EGL display, which every context of
    the process shares: any other live renderer (another scene, a :class:`MeshRasterizer`) would
    fail with ``EGL_BAD_DISPLAY`` afterwards. This destroys only this renderer's context.
    """
    if renderer is None or getattr(renderer, "_platform", None) is None:
        return
    plat = renderer._platform
    display, context = getattr(plat, "_egl_display", None), getattr(plat, "_egl_context", None)
    if display is None or context is None:  # not EGL: pyrender's own clean-up is fine
        renderer.delete()
        return
    from OpenGL.EGL import EGL_NO_CONTEXT, EGL_NO_SURFACE, eglDestroyContext, eglMakeCurrent

    plat.make_current()
    if renderer._renderer is not None:
        renderer._renderer.delete()
    eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT)
    eglDestroyContext(display, context)
    plat._egl_context = None
    plat._egl_display = None
    renderer._renderer = None
    renderer._platform = None


def update_primitive(renderer: pyrender.OffscreenRenderer, prim: pyrender.Primitive, positions: ArrayLike,
                     normals: ArrayLike | None = None, texcoords: ArrayLike | None = None,
                     colors: ArrayLike | None = None) -> None:
    """Rewrite a primitive's vertices in place (same count and attributes as when it was made).

    Once pyrender has uploaded the primitive, its interleaved vertex buffer (positions, normals,
    texture coordinates, colours -- pyrender's layout) is overwritten with ``glBufferSubData``;
    re-creating the mesh every frame instead costs a vertex array and four buffers per primitive.
    Before the first upload the arrays are simply replaced. The primitive's ``positions`` (and so
    its bounds) keep their first values afterwards; rendering with an explicit camera never uses them.
    """
    cols = [np.asarray(c, np.float32) for c in (positions, normals, texcoords, colors) if c is not None]
    vao = getattr(prim, "_vaid", None)
    buffers = getattr(prim, "_buffers", None)
    if vao is None or not buffers:
        prim.positions = cols[0]
        if normals is not None:
            prim.normals = np.asarray(normals, np.float32)
        if colors is not None:
            prim.color_0 = np.asarray(colors, np.float32)
        return
    data = np.ascontiguousarray(np.hstack(cols) if len(cols) > 1 else cols[0])
    renderer._platform.make_current()
    glBindBuffer(GL_ARRAY_BUFFER, buffers[0])
    glBufferSubData(GL_ARRAY_BUFFER, 0, data.nbytes, data)
    glBindBuffer(GL_ARRAY_BUFFER, 0)


class MeshRasterizer:
    """Offscreen renderer of posed meshes into silhouettes and part labels.

    Parameters
    ----------
    camera : Camera
        Image size, intrinsics and pose (distortion is ignored).

    Notes
    -----
    Holds one ``pyrender.OffscreenRenderer`` (an EGL context); call :meth:`close` or use it as a
    context manager. Not thread-safe: use it from the thread that made it.
    """

    def __init__(self, camera: Camera) -> None:
        self.camera = camera
        self._renderer = deterministic_renderer(camera.width, camera.height)
        self._scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 0.0], ambient_light=[1.0, 1.0, 1.0])
        self._cam_node = self._scene.add(gl_camera(camera), pose=camera.pose)
        self._nodes: list[pyrender.Node] = []

    def __enter__(self) -> MeshRasterizer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Release the GL context."""
        close_renderer(self._renderer)
        self._renderer = None

    def set_camera(self, camera: Camera) -> None:
        """Move the camera / change intrinsics (the image size must stay the same)."""
        if camera.size != self.camera.size:
            raise ValueError("image size cannot change; make a new MeshRasterizer")
        self._scene.remove_node(self._cam_node)
        self._cam_node = self._scene.add(gl_camera(camera), pose=camera.pose)
        self.camera = camera

    def silhouette(self, vertices: ArrayLike, faces: ArrayLike) -> NDArray[np.bool_]:
        """(H, W) bool silhouette of one mesh: pixels whose centre the mesh covers.

        Uses the segmentation pass, which pyrender draws without multisampling; a depth-only pass
        resolves its 4x multisampled depth with sample 0, which is a quarter pixel off the centre.
        """
        return self.labels(vertices, faces, np.zeros(len(np.asarray(faces)), np.int64), 1) >= 0

    def labels(self, vertices: ArrayLike, faces: ArrayLike, face_label: ArrayLike,
               n_labels: int) -> NDArray[np.int8]:
        """Nearest-surface label of every pixel.

        Parameters
        ----------
        vertices : (V, 3) float
        faces : (F, 3) int
        face_label : (F,) int
            Label in ``[0, n_labels)`` of every face.
        n_labels : int

        Returns
        -------
        (H, W) int8
            Label of the front-most face at each pixel centre, -1 for background.
        """
        v = np.asarray(vertices, np.float64)
        f = np.asarray(faces, np.int64)
        fl = np.asarray(face_label, np.int64)
        groups = [(v, f[fl == k]) for k in range(n_labels)]
        for node in self._nodes:
            self._scene.remove_node(node)
        colours = label_colours(n_labels)
        seg_map: dict[pyrender.Node, NDArray[np.uint8]] = {}
        self._nodes = []
        for k, (vv, ff) in enumerate(groups):
            if len(ff):
                node = self._scene.add(pyrender.Mesh([primitive(vv, ff)]), name=f"label_{k:03d}")
                self._nodes.append(node)
                seg_map[node] = colours[k]
        assert self._renderer is not None, "renderer closed"
        seg, _ = self._renderer.render(self._scene, pyrender.RenderFlags.SEG, seg_node_map=seg_map)
        return labels_from_seg(np.asarray(seg))
