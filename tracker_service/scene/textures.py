"""Procedural textures for the synthetic scene: wood floor, painted walls, fabrics, skin, a face
and hair, book spines, a painting, a window view. Every function is deterministic for its
``np.random.Generator`` and returns an ``(H, W, 3) uint8`` RGB image (pyrender's channel order).

Texture coordinates follow glTF: ``u`` along image columns, ``v`` along rows from the top.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "books_texture",
    "fabric_texture",
    "fbm",
    "head_texture",
    "painting_texture",
    "plain_texture",
    "rug_texture",
    "skin_texture",
    "wall_texture",
    "window_texture",
    "wood_texture",
]

Image = NDArray[np.uint8]


def fbm(rng: np.random.Generator, shape: tuple[int, int], base: int = 4, octaves: int = 4,
        gain: float = 0.5) -> NDArray[np.float32]:
    """Fractal value noise in about ``[-1, 1]``: ``octaves`` layers of bicubically upsampled random
    grids, the first ``base`` cells across, each twice as fine and ``gain`` times as strong.

    Returns
    -------
    (H, W) float32
    """
    h, w = shape
    out = np.zeros((h, w), np.float32)
    amp, total, cells = 1.0, 0.0, base
    for _ in range(octaves):
        grid = rng.standard_normal((max(2, cells * h // max(h, w) + 2), cells + 2)).astype(np.float32)
        out += amp * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= gain
        cells *= 2
    return np.clip(out / (total * 1.2), -1.0, 1.0)


def _to_u8(rgb: NDArray[np.float32]) -> Image:
    return np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)


def _colour(c: ArrayLike) -> NDArray[np.float32]:
    a = np.asarray(c, dtype=np.float32)
    return a / 255.0 if a.max() > 1.0 else a


def plain_texture(rng: np.random.Generator, colour: ArrayLike, size: int = 64, variation: float = 0.03) -> Image:
    """A colour with a faint blotchy variation (paint, plastic)."""
    n = fbm(rng, (size, size), base=3, octaves=3)
    return _to_u8(_colour(colour)[None, None, :] * (1.0 + variation * n[..., None]))


def wall_texture(rng: np.random.Generator, colour: ArrayLike, size: int = 256) -> Image:
    """Painted plaster: soft blotches and fine roller grain; darker towards the bottom rows
    (the floor side of a wall mapped with ``v = 1`` at the floor)."""
    n = 0.035 * fbm(rng, (size, size), base=3, octaves=5, gain=0.6)
    grain = 0.012 * rng.standard_normal((size, size)).astype(np.float32)
    ao = 1.0 - 0.10 * np.linspace(0.0, 1.0, size, dtype=np.float32)[:, None] ** 6
    return _to_u8(_colour(colour)[None, None, :] * ((1.0 + n + grain) * ao)[..., None])


def wood_texture(rng: np.random.Generator, size: int = 512, planks: int = 6, tone: ArrayLike = (150, 105, 65)) -> Image:
    """Wooden floor boards running along ``v`` (rows): per-board tone, grain streaks, dark seams."""
    base = _colour(tone)
    img = np.zeros((size, size, 3), np.float32)
    width = size // planks
    for k in range(planks):
        x0 = k * width
        tone_k = base * rng.uniform(0.8, 1.15) * (1.0 + rng.uniform(-0.05, 0.05, 3)).astype(np.float32)
        grain = fbm(rng, (size * 4, width), base=2, octaves=4)
        grain = np.asarray(cv2.resize(grain, (width, size), interpolation=cv2.INTER_AREA), np.float32)
        streak = np.sin(np.linspace(0, rng.uniform(20, 40), width, dtype=np.float32)[None, :] + 6 * grain)
        shade = 1.0 + 0.10 * grain + 0.04 * streak
        img[:, x0:x0 + width] = tone_k[None, None, :] * shade[..., None]
        img[:, x0:x0 + 2] *= 0.55  # seam between boards
        cut = int(rng.integers(0, size))
        img[cut:cut + 2, x0:x0 + width] *= 0.6  # board end joint
    return _to_u8(img)


def fabric_texture(rng: np.random.Generator, colour: ArrayLike, pattern: str = "plain", size: int = 128,
                   colour2: ArrayLike | None = None) -> Image:
    """Woven cloth: ``"plain"``, ``"stripes"``, ``"checks"`` or ``"denim"`` (diagonal twill)."""
    c1 = _colour(colour)
    c2 = _colour(colour2) if colour2 is not None else np.clip(c1 * 0.55 + 0.35, 0, 1)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    weave = 0.04 * np.sin(xx * np.pi) * np.sin(yy * np.pi) + 0.03 * fbm(rng, (size, size), base=6, octaves=3)
    if pattern == "stripes":
        period = float(rng.integers(6, 14))
        t = (np.sin(2 * np.pi * yy / period) > 0.3).astype(np.float32)[..., None]
    elif pattern == "checks":
        period = float(rng.integers(12, 24))
        a = (np.sin(2 * np.pi * yy / period) > 0.2).astype(np.float32)
        b = (np.sin(2 * np.pi * xx / period) > 0.2).astype(np.float32)
        t = (0.5 * (a + b))[..., None]
    elif pattern == "denim":
        twill = 0.08 * np.sin((xx + yy) * np.pi / 2.0)
        fleck = 0.10 * (rng.random((size, size)).astype(np.float32) > 0.85)
        return _to_u8(c1[None, None, :] * (1.0 + weave + twill)[..., None] + fleck[..., None] * 0.5)
    else:
        t = np.zeros((size, size, 1), np.float32)
    rgb = (1 - t) * c1[None, None, :] + t * c2[None, None, :]
    return _to_u8(rgb * (1.0 + weave)[..., None])


def skin_texture(rng: np.random.Generator, tone: ArrayLike, size: int = 64) -> Image:
    """Skin: a tone with faint blotches."""
    n = 0.04 * fbm(rng, (size, size), base=4, octaves=3)
    return _to_u8(_colour(tone)[None, None, :] * (1.0 + n)[..., None])


def head_texture(rng: np.random.Generator, skin: ArrayLike, hair: ArrayLike, long_hair: bool,
                 size: int = 256) -> Image:
    """Face and hair on a longitude/latitude map: ``u = 0.5 + atan2(x, z) / 2 pi`` (0.5 = the face,
    +Z), ``v`` = 0 at the crown to 1 at the chin."""
    img = np.asarray(skin_texture(rng, skin, size), np.float32) / 255.0
    hair_c = _colour(hair)
    uu, vv = np.meshgrid(np.linspace(0, 1, size, dtype=np.float32), np.linspace(0, 1, size, dtype=np.float32))
    du = np.abs(uu - 0.5)  # angular distance from the face centre line (0.5 = back of the head)
    fringe = 0.36 + 0.03 * np.cos(du * 40.0)
    back_limit = 0.62 if long_hair else 0.56
    mask = (vv < fringe) | ((du > 0.17) & (vv < back_limit + 0.25 * np.clip((du - 0.17) / 0.2, 0, 1)))
    mask &= ~((du < 0.2) & (du > 0.16) & (vv > 0.40))  # ears stay skin
    streaks = cv2.resize(fbm(rng, (size // 8, size), base=24, octaves=2), (size, size), interpolation=cv2.INTER_CUBIC)
    strands = 1.0 + 0.25 * np.asarray(streaks, np.float32)
    img[mask] = hair_c[None, :] * strands[mask][:, None]
    dark = np.array([0.12, 0.08, 0.07], np.float32)
    for side in (-1, 1):  # eyes, brows
        cu = 0.5 + side * 0.055
        cv2.ellipse(img, (int(cu * size), int(0.50 * size)), (int(0.018 * size), int(0.009 * size)), 0, 0, 360,
                    dark.tolist(), -1, cv2.LINE_AA)
        cv2.ellipse(img, (int(cu * size), int(0.455 * size)), (int(0.026 * size), int(0.006 * size)), 0, 0, 360,
                    (hair_c * 0.8).tolist(), -1, cv2.LINE_AA)
    lips = _colour(skin) * np.array([0.85, 0.6, 0.6], np.float32)
    cv2.ellipse(img, (size // 2, int(0.70 * size)), (int(0.035 * size), int(0.010 * size)), 0, 0, 360,
                lips.tolist(), -1, cv2.LINE_AA)
    nose = (vv > 0.52) & (vv < 0.64) & (np.abs(uu - 0.5) < 0.012)
    img[nose] *= 0.9
    return _to_u8(img)


def books_texture(rng: np.random.Generator, size: int = 256) -> Image:
    """Rows of book spines for a bookshelf front (four shelves)."""
    img = np.zeros((size, size, 3), np.float32)
    shelf_h = size // 4
    palette = np.array([[120, 30, 30], [30, 60, 110], [200, 180, 140], [40, 90, 50], [150, 120, 60],
                        [90, 40, 90], [220, 220, 210], [30, 30, 35], [180, 90, 40]], np.float32) / 255.0
    for s in range(4):
        y0 = s * shelf_h
        img[y0:y0 + shelf_h] = (0.18, 0.12, 0.08)  # back of the shelf
        x = int(rng.integers(0, 6))
        while x < size - 4:
            wd = int(rng.integers(5, 14))
            ht = int(rng.integers(int(shelf_h * 0.6), shelf_h - 4))
            if rng.random() < 0.12:  # a gap
                x += wd * 2
                continue
            col = palette[rng.integers(len(palette))] * rng.uniform(0.75, 1.1)
            img[y0 + shelf_h - ht - 3:y0 + shelf_h - 3, x:min(x + wd, size)] = col
            img[y0 + shelf_h - ht + 4:y0 + shelf_h - ht + 6, x + 1:min(x + wd - 1, size)] *= 0.6
            x += wd + int(rng.integers(0, 2))
        img[y0 + shelf_h - 3:y0 + shelf_h] = (0.45, 0.32, 0.2)  # shelf board edge
    return _to_u8(img * (1.0 + 0.04 * fbm(rng, (size, size))[..., None]))


def painting_texture(rng: np.random.Generator, size: int = 128) -> Image:
    """An abstract landscape painting: sky gradient, hills, a few blobs, inside a light mat."""
    yy = np.linspace(0, 1, size, dtype=np.float32)[:, None, None]
    sky = np.array(rng.uniform([0.45, 0.6, 0.75], [0.65, 0.8, 0.95]), np.float32)
    img = np.broadcast_to(sky * (0.8 + 0.3 * (1 - yy)), (size, size, 3)).copy()
    for k in range(3):
        horizon = 0.45 + 0.15 * k + 0.08 * fbm(rng, (1, size), base=3, octaves=2)[0]
        col = np.array(rng.uniform([0.15, 0.3, 0.1], [0.45, 0.6, 0.3]), np.float32) * (1 - 0.2 * k)
        below = np.linspace(0, 1, size, dtype=np.float32)[:, None] > horizon[None, :]
        img[below] = col
    img *= 1.0 + 0.08 * fbm(rng, (size, size), base=8)[..., None]
    m = size // 12
    img[:m], img[-m:], img[:, :m], img[:, -m:] = 0.92, 0.92, 0.92, 0.92
    return _to_u8(img)


def window_texture(rng: np.random.Generator, size: int = 128) -> Image:
    """A bright window: sky and a blurred tree line seen through four panes with a white frame."""
    yy = np.linspace(0, 1, size, dtype=np.float32)[:, None]
    img = np.ones((size, size, 3), np.float32)
    img[:] = np.array([0.80, 0.88, 0.97], np.float32) * (1.05 - 0.15 * yy)[..., None]
    line = 0.65 + 0.1 * fbm(rng, (1, size), base=6, octaves=3)[0]
    trees = yy > line[None, :]
    img[trees] = np.array([0.45, 0.55, 0.40], np.float32) * (1 + 0.2 * fbm(rng, (size, size), base=10)[trees])[:, None]
    img = np.asarray(cv2.GaussianBlur(img, (0, 0), 1.5), np.float32)
    f = max(size // 20, 2)
    for c in (0, size // 2 - f // 2, size - f):
        img[:, c:c + f] = 0.95
        img[c:c + f, :] = 0.95
    return _to_u8(img)


def rug_texture(rng: np.random.Generator, size: int = 256) -> Image:
    """A patterned rug: border bands, a central medallion, wool noise."""
    c1 = np.array(rng.uniform([0.45, 0.1, 0.1], [0.65, 0.25, 0.2]), np.float32)
    c2 = np.array(rng.uniform([0.75, 0.65, 0.45], [0.9, 0.8, 0.6]), np.float32)
    c3 = np.array(rng.uniform([0.1, 0.15, 0.3], [0.2, 0.25, 0.45]), np.float32)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32) / size
    d = np.maximum(np.abs(xx - 0.5), np.abs(yy - 0.5))
    img = np.where((d > 0.42)[..., None], c3, np.where((d > 0.38)[..., None], c2, c1))
    r = np.hypot(xx - 0.5, yy - 0.5)
    img = np.where(((r < 0.18) & (r > 0.12))[..., None], c2, img)
    img = np.where((r < 0.06)[..., None], c3, img)
    img *= 1.0 + 0.10 * fbm(rng, (size, size), base=16, octaves=2)[..., None]
    return _to_u8(img)
