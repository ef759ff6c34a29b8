"""The synthetic scene's static room: a furnished living room (wooden floor, painted walls,
bookshelf, sofa, painting, window, rug, lamp, plant, cabinet), its lighting, and planar soft
shadows on the floor and the back wall.

The room is rendered once per scene (at twice the output size, then area-downsampled for clean
edges) together with a surface map telling which pixels show the floor or the back wall -- the two
planes that receive the person's shadow at run time (:func:`planar_shadow`). The person stands near
the origin; everything is placed behind it (``z < -0.8``) or against the side walls, so nothing
in the room occludes the person.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pyrender
from numpy.typing import ArrayLike, NDArray

from tracker_service.camera import Camera, look_at
from tracker_service.scene import textures as tx
from tracker_service.scene.geometry import Surface, box_surface, ring_surface, tube_rings
from tracker_service.scene.gl import gl_camera, label_colours, labels_from_seg, primitive, textured_material

__all__ = ["BACK_WALL", "FLOOR", "Lighting", "Room", "build_room", "planar_shadow", "random_lighting",
           "render_background", "shadow_strength_map"]

#: Surface-map codes.
FLOOR, BACK_WALL = 1, 2


@dataclass(frozen=True)
class Lighting:
    """Key (directional, casts the planar shadows) and fill lights plus ambient light.

    ``key_dir`` is the unit direction the key light travels (from the light into the scene).
    """

    key_dir: NDArray[np.float64]
    key_colour: NDArray[np.float64]
    key_intensity: float
    fill_dir: NDArray[np.float64]
    fill_intensity: float
    ambient: float
    shadow_strength: float


@dataclass(frozen=True)
class Room:
    """Textured room geometry: ``items`` of (surface, texture, surface code, emissive)."""

    items: tuple[tuple[Surface, NDArray[np.uint8], int, float], ...]
    back_z: float
    half_width: float


def random_lighting(rng: np.random.Generator) -> Lighting:
    """Key light from the front-left or front-right and above, warm to neutral; a weaker fill."""
    side = 1.0 if rng.random() < 0.5 else -1.0
    az = np.radians(rng.uniform(20, 50)) * side
    el = np.radians(rng.uniform(30, 50))
    key = -np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    fill = -np.array([-np.sin(az) * 0.8, 0.4, 0.6])
    warm = rng.uniform(0.0, 0.12)
    return Lighting(key_dir=key, key_colour=np.array([1.0, 1.0 - 0.3 * warm, 1.0 - warm]),
                    key_intensity=float(rng.uniform(2.6, 3.6)), fill_dir=fill / np.linalg.norm(fill),
                    fill_intensity=float(rng.uniform(0.6, 1.1)), ambient=float(rng.uniform(0.25, 0.4)),
                    shadow_strength=float(rng.uniform(0.35, 0.5)))


def _cylinder(centre: ArrayLike, radius: float, height: float, top_radius: float | None = None) -> Surface:
    c = np.asarray(centre, np.float64)
    r1 = radius if top_radius is None else top_radius
    prof = [(0.0, 0.0, 0.0), (0.0, radius, radius), (height, r1, r1), (height, 0.0, 0.0)]
    return ring_surface(tube_rings(c, (0, 1, 0), (1, 0, 0), prof, 20), u_repeat=2.0, v_scale=0.5)


def build_room(rng: np.random.Generator) -> Room:
    """A furnished room with random colours, textures and small layout jitter."""
    back, hw, depth_front, ceil = -float(rng.uniform(1.6, 1.9)), 2.7, 3.6, 2.7
    items: list[tuple[Surface, NDArray[np.uint8], int, float]] = []
    paint = rng.uniform([200, 190, 170], [240, 235, 225]) * rng.uniform(0.8, 1.0)
    accent = rng.uniform([120, 140, 150], [200, 200, 190])
    wall_tex = tx.wall_texture(rng, paint)
    wood = tx.wood_texture(rng, tone=rng.uniform([120, 80, 45], [180, 130, 85]))

    def add(s: Surface, tex: NDArray[np.uint8], code: int = 0, emissive: float = 0.0) -> None:
        items.append((s, tex, code, emissive))

    add(box_surface((-hw, -0.05, back), (hw, 0.0, depth_front), 1.6), wood, FLOOR)
    add(box_surface((-hw, 0.0, back - 0.1), (hw, ceil, back), None), wall_tex, BACK_WALL)
    side_tex = tx.wall_texture(rng, accent if rng.random() < 0.5 else paint)
    add(box_surface((-hw - 0.1, 0.0, back), (-hw, ceil, depth_front), None), side_tex)
    add(box_surface((hw, 0.0, back), (hw + 0.1, ceil, depth_front), None), side_tex)
    add(box_surface((-hw, ceil, back), (hw, ceil + 0.05, depth_front), None), tx.plain_texture(rng, (235, 235, 230)))
    trim = tx.plain_texture(rng, (235, 232, 225))
    add(box_surface((-hw, 0.0, back), (hw, 0.08, back + 0.015)), trim)  # skirting boards
    add(box_surface((-hw, 0.0, back), (-hw + 0.015, 0.08, depth_front)), trim)
    add(box_surface((hw - 0.015, 0.0, back), (hw, 0.08, depth_front)), trim)
    # bookshelf (back left)
    x0 = -hw + float(rng.uniform(0.15, 0.4))
    shelf_wood = tx.wood_texture(rng, size=128, planks=2, tone=rng.uniform([70, 45, 30], [150, 110, 70]))
    add(box_surface((x0, 0.0, back), (x0 + 1.0, 1.95, back + 0.36)), shelf_wood)
    add(box_surface((x0 + 0.04, 0.08, back + 0.36), (x0 + 0.96, 1.9, back + 0.365)), tx.books_texture(rng))
    # window and painting on the back wall
    wx = float(rng.uniform(-1.2, -0.9))
    add(box_surface((wx, 0.95, back), (wx + 0.8, 2.15, back + 0.02)), tx.window_texture(rng), 0, 0.6)
    add(box_surface((wx - 0.04, 0.9, back), (wx + 0.84, 0.95, back + 0.06)), trim)  # sill
    px = float(rng.uniform(0.3, 0.6))
    add(box_surface((px, 1.35, back), (px + 0.65, 1.85, back + 0.03)), tx.painting_texture(rng))
    # sofa (back right)
    fabric = tx.fabric_texture(rng, rng.uniform([60, 60, 60], [170, 150, 140]), "plain")
    sx0, sx1, sz1 = 0.6 + float(rng.uniform(0, 0.2)), hw - 0.6, back + 0.85
    add(box_surface((sx0, 0.08, back + 0.05), (sx1, 0.45, sz1), 0.5), fabric)
    add(box_surface((sx0, 0.45, back + 0.05), (sx1, 0.85, back + 0.28), 0.5), fabric)
    for ax0 in (sx0 - 0.15, sx1):
        add(box_surface((ax0, 0.08, back + 0.05), (ax0 + 0.15, 0.62, sz1), 0.5), fabric)
    cushion = tx.fabric_texture(rng, rng.uniform([120, 40, 40], [230, 200, 120]), "checks")
    add(box_surface((sx0 + 0.1, 0.45, back + 0.3), (sx0 + 0.5, 0.8, back + 0.42)), cushion)
    # rug, cabinet with a lamp, floor lamp, plant
    add(box_surface((-1.3, 0.0, back + 0.9), (1.3, 0.008, 1.4)), tx.rug_texture(rng), FLOOR)
    cab = tx.plain_texture(rng, rng.uniform([180, 170, 150], [240, 235, 220]))
    cz = back + 1.0 + float(rng.uniform(0.0, 0.3))
    add(box_surface((-hw, 0.0, cz), (-hw + 0.45, 0.7, cz + 0.7)), cab)
    add(_cylinder((-hw + 0.22, 0.7, cz + 0.35), 0.07, 0.35, 0.02), tx.plain_texture(rng, (60, 60, 65)))
    add(_cylinder((-hw + 0.22, 1.0, cz + 0.35), 0.18, 0.22, 0.12), tx.plain_texture(rng, (245, 235, 210)), 0, 0.3)
    lx, lz = hw - 0.3, back + 0.35
    metal = tx.plain_texture(rng, (40, 40, 40))
    add(_cylinder((lx, 0.0, lz), 0.15, 0.03), metal)
    add(_cylinder((lx, 0.0, lz), 0.015, 1.55), metal)
    add(_cylinder((lx, 1.5, lz), 0.25, 0.3, 0.15), tx.plain_texture(rng, (240, 230, 200)), 0, 0.35)
    px2 = float(rng.uniform(-0.6, 0.2))
    add(_cylinder((px2, 0.0, back + 0.3), 0.17, 0.38, 0.2), tx.plain_texture(rng, (170, 90, 60)))
    leaves = tx.fabric_texture(rng, (50, 110, 45), "plain")
    for _ in range(5):
        off = rng.uniform([-0.15, 0.0, -0.1], [0.15, 0.5, 0.15])
        c = np.array([px2, 0.55, back + 0.3]) + off
        prof = [(0.0, 0.0, 0.0), (0.05, 0.12, 0.1), (0.25, 0.16, 0.13), (0.45, 0.1, 0.08), (0.55, 0.0, 0.0)]
        add(ring_surface(tube_rings(c, (0, 1, 0), (1, 0, 0), prof, 12)), leaves)
    if rng.random() < 0.5:  # mirror the layout left / right
        flip = np.array([-1.0, 1.0, 1.0])
        items = [(Surface(sf.vertices * flip, sf.faces[:, ::-1].copy(), sf.normals * flip, sf.uv), t, c, e)
                 for sf, t, c, e in items]
    return Room(tuple(items), back, hw)


def planar_shadow(vertices: ArrayLike, light_dir: ArrayLike,
                  back_z: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Project points along ``light_dir`` onto the floor (``y = 0.001``) and the back wall
    (``z = back_z + 0.001``).

    Returns
    -------
    floor, wall : (V, 3) float64
    """
    v = np.asarray(vertices, dtype=np.float64)
    d = np.asarray(light_dir, dtype=np.float64)
    floor = v - ((v[:, 1:2] - 0.001) / d[1]) * d
    wall = v - ((v[:, 2:3] - back_z - 0.001) / d[2]) * d
    return floor, wall


def shadow_strength_map(floor_hit: NDArray[np.bool_], wall_hit: NDArray[np.bool_], surface: NDArray[np.uint8],
                        sigma_px: float) -> NDArray[np.float32]:
    """Soft shadow coverage in [0, 1]: the projected shadow where it lands on its own plane, blurred."""
    hit = ((floor_hit & (surface == FLOOR)) | (wall_hit & (surface == BACK_WALL))).astype(np.float32)
    if sigma_px > 0:
        hit = cv2.GaussianBlur(hit, (0, 0), sigma_px)
    return hit


def add_lights(scene: pyrender.Scene, lighting: Lighting) -> None:
    """Add the key and fill lights to a pyrender scene (directional lights shine along their -Z)."""
    for d, inten, col in ((lighting.key_dir, lighting.key_intensity, lighting.key_colour),
                          (lighting.fill_dir, lighting.fill_intensity, np.ones(3))):
        pose = look_at(-np.asarray(d), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0) if abs(d[1]) < 0.99 else (0.0, 0.0, 1.0))
        scene.add(pyrender.DirectionalLight(color=col, intensity=inten), pose=pose)


def render_background(room: Room, lighting: Lighting, camera: Camera, renderer: pyrender.OffscreenRenderer,
                      supersample: int = 2) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
    """Render the empty room once, with ``renderer`` temporarily resized to ``supersample`` times
    the camera's size (restored afterwards).

    Returns
    -------
    image : (H, W, 3) float32
        RGB in [0, 1], with the furniture's planar shadows on floor and back wall.
    surface : (H, W) uint8
        :data:`FLOOR`, :data:`BACK_WALL` or 0 for every pixel.
    """
    big = camera.scaled(supersample)
    amb = lighting.ambient
    scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 1.0], ambient_light=[amb, amb, amb])
    scene.add(gl_camera(big), pose=big.pose)
    add_lights(scene, lighting)
    seg_map: dict[pyrender.Node, NDArray[np.uint8]] = {}
    colours = label_colours(3)
    casters: list[Surface] = []
    for k, (surf, tex, code, emissive) in enumerate(room.items):
        mat = textured_material(tex, emissive=emissive)
        node = scene.add(pyrender.Mesh([primitive(surf.vertices, surf.faces, surf.normals, mat, surf.uv)]),
                         name=f"room_{k:03d}")
        seg_map[node] = colours[code]
        if code == 0 and emissive == 0 and surf.vertices[:, 1].max() < 2.5 and np.ptp(surf.vertices[:, 0]) < 2.0:
            casters.append(surf)
    size = renderer.viewport_width, renderer.viewport_height
    renderer.viewport_width, renderer.viewport_height = big.width, big.height
    try:
        colour, _ = renderer.render(scene)
        seg, _ = renderer.render(scene, pyrender.RenderFlags.SEG, seg_node_map=seg_map)
        surface_big = np.maximum(labels_from_seg(np.asarray(seg)), 0).astype(np.uint8)  # label = code
        # furniture shadows: flattened casters drawn over the room's depth
        shadow_nodes = []
        for k, surf in enumerate(casters):
            fl, wl = planar_shadow(surf.vertices, lighting.key_dir, room.back_z)
            for j, (pts, col) in enumerate(((fl, colours[1]), (wl, colours[2]))):
                n = scene.add(pyrender.Mesh([primitive(pts, surf.faces)]), name=f"shadow_{k:03d}_{j}")
                shadow_nodes.append((n, col))
        sm = {n: c for n, c in shadow_nodes}
        sseg, _ = renderer.render(scene, pyrender.RenderFlags.SEG, seg_node_map=sm)
    finally:
        renderer.viewport_width, renderer.viewport_height = size
    lab = labels_from_seg(np.asarray(sseg))
    shade = shadow_strength_map(lab == 1, lab == 2, surface_big, 2.5 * supersample)
    img = np.asarray(colour, np.float32) / 255.0 * (1.0 - lighting.shadow_strength * shade[..., None])
    img = np.asarray(cv2.resize(img, (camera.width, camera.height), interpolation=cv2.INTER_AREA), np.float32)
    surface = np.asarray(cv2.resize(surface_big, (camera.width, camera.height), interpolation=cv2.INTER_NEAREST),
                         np.uint8)
    return img, surface
