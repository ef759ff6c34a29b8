"""Domain randomisation of the synthetic scene: people, clothes, rooms, lights and sensors beyond
the default draw, one named axis at a time (or several), for the robustness matrix
(``bench/bench_robustness.py``) and for training views.

Each axis widens one thing the tracker must not depend on; with the same seed an axis gives the
same frames (its draws come from their own stream of the scene's seed):

=============  ==========================================================================
axis           what changes
=============  ==========================================================================
``body``       a child (1.10-1.45 m), a heavy (girths x1.25-1.45), thin (x0.80-0.88) or tall
               (1.92-2.05 m) adult, or an elderly person stooping (spine and neck flexed
               10-22 degrees in every frame)
``clothing``   a dress (one colour top to knee), clothes in the wall's colours, loose
               long sleeves, strong patterns
``appearance`` the darkest and palest skin tones, grey, red or blond hair, long hair on men
``backdrop``   a photographic backdrop (matplotlib's sample photograph and shaded
               relief maps, cropped and tinted) or a cluttered collage instead of the room
``lights``     dim, backlit (key light behind the person), strongly coloured, or changing
               (exposure swinging by up to 25 % over seconds)
``sensor``     three to six times the sensor noise, and motion blur along a random
               direction (3-9 px)
``compression`` every frame through H.264 (CRF 26-34, PyAV's libx264) or JPEG (quality
               35-70)
=============  ==========================================================================

Camera placement and frame size are the camera's options (``--camera-height`` and friends),
not axes here: a different camera needs templates for that camera.
"""

from __future__ import annotations

import functools
import io
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Final

import cv2
import numpy as np
from numpy.typing import NDArray

from tracker_service.scene import textures as tx
from tracker_service.scene.geometry import box_surface
from tracker_service.scene.room import BACK_WALL, FLOOR, Lighting, Room
from tracker_service.scene.subject import SubjectSpec

__all__ = [
    "AXES",
    "SceneVariation",
    "degrade_frame",
    "parse_axes",
    "photo_room",
    "vary_lighting",
    "vary_subject",
]

#: The axes, in the robustness matrix's row order.
AXES: Final[tuple[str, ...]] = ("body", "clothing", "appearance", "backdrop", "lights", "sensor", "compression")


def parse_axes(text: str) -> tuple[str, ...]:
    """``"body,lights"`` or ``"all"`` -> the axes (``ValueError`` names an unknown one)."""
    if text.strip() in ("", "none"):
        return ()
    names = AXES if text.strip() == "all" else tuple(a.strip() for a in text.split(",") if a.strip())
    if unknown := [a for a in names if a not in AXES]:
        raise ValueError(f"unknown variation axis {', '.join(unknown)}; choose from {', '.join(AXES)} or all")
    return tuple(dict.fromkeys(names))


@dataclass(frozen=True)
class SceneVariation:
    """What one scene varies, drawn from ``rng`` once per scene.

    Attributes
    ----------
    axes : tuple of str
    lights : str
        ``default``, ``dim``, ``backlit``, ``coloured`` or ``changing``.
    exposure_swing : float
        Relative amplitude of the slow exposure drift (the default scene's is 0.03).
    noise_scale : float
        Multiplier on the sensor noise's standard deviation.
    blur_px : float
        Motion blur length (pixels; 0: none); its direction is drawn per frame.
    codec : str
        ``none``, ``h264`` or ``jpeg``.
    quality : int
        CRF (H.264) or quality (JPEG).
    """

    axes: tuple[str, ...] = ()
    lights: str = "default"
    exposure_swing: float = 0.03
    noise_scale: float = 1.0
    blur_px: float = 0.0
    codec: str = "none"
    quality: int = 0

    @staticmethod
    def draw(axes: tuple[str, ...], rng: np.random.Generator) -> SceneVariation:
        """The scene-wide choices of ``axes`` (subject and room are varied by their own functions)."""
        v = SceneVariation(axes=axes)
        if "lights" in axes:
            kind = str(rng.choice(["dim", "backlit", "coloured", "changing"]))
            v = replace(v, lights=kind, exposure_swing=float(rng.uniform(0.15, 0.25)) if kind == "changing" else 0.03)
        if "sensor" in axes:
            v = replace(v, noise_scale=float(rng.uniform(3.0, 6.0)), blur_px=float(rng.uniform(3.0, 9.0)))
        if "compression" in axes:
            h264 = bool(rng.random() < 0.5)
            v = replace(v, codec="h264" if h264 else "jpeg",
                        quality=int(rng.integers(26, 35) if h264 else rng.integers(35, 71)))
        return v


def vary_subject(spec: SubjectSpec, axes: tuple[str, ...], rng: np.random.Generator) -> SubjectSpec:
    """The person of ``spec`` varied along the ``body``, ``clothing`` and ``appearance`` axes."""
    if "body" in axes:
        kind = str(rng.choice(["child", "heavy", "thin", "tall", "elderly"]))
        if kind == "child":
            h = float(rng.uniform(1.10, 1.45))
            chest = 0.50 * h + 0.02
            spec = replace(spec, group="children", height=h, chest=chest, waist=chest - 0.01, hip=chest + 0.02,
                           skirt=False, long_hair=bool(rng.random() < 0.4),
                           shoulder_frac=float(rng.uniform(0.18, 0.2)))
        elif kind in ("heavy", "thin"):
            k = float(rng.uniform(1.25, 1.45) if kind == "heavy" else rng.uniform(0.80, 0.88))
            waist = spec.waist * (k * 1.08 if kind == "heavy" else k)  # a heavy build widens at the waist
            spec = replace(spec, chest=spec.chest * k, waist=waist, hip=spec.hip * k)
        elif kind == "tall":
            h = float(rng.uniform(1.92, 2.05))
            k = h / spec.height
            spec = replace(spec, group="men", height=h, chest=spec.chest * k, waist=spec.waist * k, hip=spec.hip * k,
                           skirt=False, shoulder_frac=float(rng.uniform(0.195, 0.215)))
        else:  # elderly: stooping, grey hair
            spec = replace(spec, hair=(175, 172, 168), stoop=float(np.radians(rng.uniform(10.0, 22.0))))
    if "clothing" in axes:
        kind = str(rng.choice(["dress", "wall", "loose", "patterns"]))
        if kind == "dress" and spec.group != "children":
            dress = tx_colour(rng)
            spec = replace(spec, skirt=True, shirt=dress, lower=dress, shirt_pattern="plain", lower_pattern="plain")
        elif kind == "wall":  # the paint's range of the room's walls, a little darker or lighter
            paint = rng.uniform([200, 190, 170], [240, 235, 225]) * rng.uniform(0.85, 1.05)
            paint2 = np.clip(paint * rng.uniform(0.9, 1.05), 0, 255)
            spec = replace(spec, shirt=_int3(paint), lower=_int3(paint2), shirt_pattern="plain", lower_pattern="plain")
        elif kind == "loose":
            spec = replace(spec, long_sleeves=True, chest=spec.chest * 1.08, waist=spec.waist * 1.1)
        else:
            spec = replace(spec, shirt_pattern=str(rng.choice(["stripes", "checks"])),
                           lower_pattern="plain" if spec.skirt else "denim")
    if "appearance" in axes:
        skin = [(250, 220, 200), (70, 45, 32), (55, 38, 30), (235, 190, 160)][int(rng.integers(4))]
        hair = [(150, 150, 150), (150, 60, 30), (200, 170, 110), (15, 12, 10)][int(rng.integers(4))]
        spec = replace(spec, skin=skin, hair=hair, long_hair=bool(rng.random() < 0.6))
    return spec


def tx_colour(rng: np.random.Generator) -> tuple[int, int, int]:
    """A saturated garment colour."""
    hsv = np.array([[[rng.integers(0, 180), rng.integers(120, 230), rng.integers(90, 220)]]], np.uint8)
    return _int3(np.asarray(cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB))[0, 0].astype(np.float64))


def _int3(c: NDArray[np.float64]) -> tuple[int, int, int]:
    return int(c[0]), int(c[1]), int(c[2])


def vary_lighting(lighting: Lighting, kind: str, rng: np.random.Generator) -> Lighting:
    """``lighting`` made dim, backlit or coloured (``changing`` is the exposure's: unchanged here)."""
    if kind == "dim":
        k = float(rng.uniform(0.3, 0.45))
        return replace(lighting, key_intensity=lighting.key_intensity * k, fill_intensity=lighting.fill_intensity * k,
                       ambient=lighting.ambient * k)
    if kind == "backlit":  # the key light from behind the person, toward the camera; the front only filled
        d = lighting.key_dir * np.array([1.0, 1.0, -1.0])
        return replace(lighting, key_dir=d, key_intensity=lighting.key_intensity * 1.2,
                       fill_intensity=lighting.fill_intensity * 0.6)
    if kind == "coloured":
        tint = rng.uniform(0.45, 1.0, 3)
        tint /= tint.max()
        return replace(lighting, key_colour=tint)
    return lighting


@functools.cache
def _photographs() -> tuple[NDArray[np.uint8], ...]:
    """RGB photographs that ship with matplotlib (a dependency): a portrait and two relief maps
    rendered with hill shading (read and shaded once per process; read-only)."""
    import matplotlib
    from matplotlib.colors import LightSource

    out: list[NDArray[np.uint8]] = []
    root = Path(matplotlib.get_data_path()) / "sample_data"
    img = cv2.imread(str(root / "grace_hopper.jpg"), cv2.IMREAD_COLOR)
    if img is not None:
        out.append(np.ascontiguousarray(img[..., ::-1]))
    reliefs = (("jacksboro_fault_dem.npz", "elevation", "gist_earth"), ("topobathy.npz", "topo", "terrain"))
    for name, key, cmap in reliefs:
        path = root / name
        if not path.exists():
            continue
        with np.load(path) as d:
            z = np.asarray(d[key], np.float64)
        rgb = LightSource(azdeg=315, altdeg=45).shade(z, cmap=matplotlib.colormaps[cmap], vert_exag=0.05,
                                                     blend_mode="soft")
        out.append((np.asarray(rgb)[..., :3] * 255).astype(np.uint8))
    for img in out:
        img.flags.writeable = False
    return tuple(out)


def backdrop_texture(rng: np.random.Generator, size: tuple[int, int] = (512, 384)) -> NDArray[np.uint8]:
    """A photograph (cropped, flipped, tinted) or a cluttered collage of photo crops and shapes."""
    w, h = size
    photos = _photographs()
    if rng.random() < 0.6 and photos:
        p = photos[int(rng.integers(len(photos)))]
        ch, cw = int(p.shape[0] * rng.uniform(0.6, 1.0)), int(p.shape[1] * rng.uniform(0.6, 1.0))
        y0, x0 = int(rng.integers(0, p.shape[0] - ch + 1)), int(rng.integers(0, p.shape[1] - cw + 1))
        img = cv2.resize(p[y0:y0 + ch, x0:x0 + cw], (w, h), interpolation=cv2.INTER_AREA)
        if rng.random() < 0.5:
            img = img[:, ::-1]
    else:
        img = np.asarray(tx.fbm(rng, (h, w)) [..., None] * rng.uniform(60, 200, 3), np.float32).astype(np.uint8)
        for _ in range(int(rng.integers(12, 30))):
            x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
            c = tuple(int(v) for v in rng.integers(0, 256, 3))
            if photos and rng.random() < 0.4:
                p = photos[int(rng.integers(len(photos)))]
                pw, ph = int(rng.integers(40, 160)), int(rng.integers(40, 160))
                crop = cv2.resize(p, (pw, ph), interpolation=cv2.INTER_AREA)
                x1, y1 = min(w, x + pw), min(h, y + ph)
                img[y:y1, x:x1] = crop[:y1 - y, :x1 - x]
            elif rng.random() < 0.5:
                cv2.rectangle(img, (x, y), (x + int(rng.integers(10, 120)), y + int(rng.integers(10, 120))), c, -1)
            else:
                cv2.circle(img, (x, y), int(rng.integers(5, 50)), c, -1)
    tint = rng.uniform(0.8, 1.1, 3)
    return np.clip(np.ascontiguousarray(img) * tint, 0, 255).astype(np.uint8)


def photo_room(room: Room, rng: np.random.Generator) -> Room:
    """``room``'s floor and side walls with a photographic backdrop (a wall-high print) covering the
    back wall and its furniture."""
    z = room.back_z + 0.45  # in front of the shelf, the sofa and the plant
    wall = box_surface((-room.half_width, 0.0, z - 0.02), (room.half_width, 2.7, z), None)
    keep = tuple(it for it in room.items if it[2] == FLOOR or _is_side(it, room))
    return Room((*keep, (wall, backdrop_texture(rng), BACK_WALL, 0.0)), z, room.half_width)


def _is_side(item: tuple[object, ...], room: Room) -> bool:
    v = item[0].vertices  # type: ignore[attr-defined]
    return bool(np.abs(v[:, 0]).min() >= room.half_width - 1e-6)


def degrade_frame(bgr: NDArray[np.uint8], variation: SceneVariation, rng: np.random.Generator) -> NDArray[np.uint8]:
    """Motion blur and compression of a finished frame (BGR uint8), as the variation says."""
    out = bgr
    if variation.blur_px > 0:
        n = max(3, round(variation.blur_px) | 1)
        k = np.zeros((n, n), np.float32)
        a = rng.uniform(0.0, np.pi)
        c = (n - 1) / 2
        dx, dy = c * np.cos(a), c * np.sin(a)
        cv2.line(k, (round(c - dx), round(c - dy)), (round(c + dx), round(c + dy)), 1.0, 1)
        out = np.asarray(cv2.filter2D(out, -1, k / k.sum()), np.uint8)
    if variation.codec == "jpeg":
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(variation.quality)])
        if ok:
            out = np.asarray(cv2.imdecode(buf, cv2.IMREAD_COLOR), np.uint8)
    elif variation.codec == "h264":
        out = h264_roundtrip(out, int(variation.quality))
    return out


def h264_roundtrip(bgr: NDArray[np.uint8], crf: int) -> NDArray[np.uint8]:
    """One frame encoded with libx264 at ``crf`` (an intra frame, yuv420p) and decoded again."""
    import av

    h, w = bgr.shape[:2]
    buf = io.BytesIO()
    with av.open(buf, "w", format="mp4") as box:
        stream = box.add_stream("libx264", rate=30)
        stream.width, stream.height = w - w % 2, h - h % 2
        stream.pix_fmt = "yuv420p"
        stream.options = {"crf": str(crf), "preset": "veryfast", "tune": "zerolatency"}
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(bgr[:h - h % 2, :w - w % 2]), format="bgr24")
        for packet in stream.encode(frame):
            box.mux(packet)
        for packet in stream.encode(None):
            box.mux(packet)
    buf.seek(0)
    with av.open(buf, "r") as box:
        for decoded in box.decode(video=0):
            img = decoded.to_ndarray(format="bgr24")
            out = bgr.copy()
            out[:img.shape[0], :img.shape[1]] = img
            return out
    return bgr
