"""Pre-processing of an observed silhouette (Okada & Stenger §2.2): image pyramid, distance
transforms, shape skeleton, the matching weights of eq. 9 / eq. 10 and their horizontal integral
images (eq. 12).

Every distance of :mod:`tracker_service.silhouette.distance` has the form (eq. 11 rearranged)

    d(S, T) = ( sum_{k: T(k)=1} A(k) + B ) / |w|

with a per-pixel image ``A`` and a constant ``B`` that depend only on the observation ``S``:

=========  ===================================  ==============================
distance   A                                    B
=========  ===================================  ==============================
XOR        1 - 2 S                              |S|
cwXOR      D(S) - alpha D(S̄)                    alpha * sum D(S̄)     (eq. 8-9)
nwXOR      D(S) - beta D(S̄)/(D(S̄)+D(S_skl))     beta * sum of that   (eq. 10-11)
=========  ===================================  ==============================

so only the horizontal integral image of ``A`` is needed to evaluate any template given as
horizontal runs (eq. 12).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from tracker_service.silhouette._kernels import xor_level_kernel

__all__ = [
    "DISTANCES",
    "LEVEL_SIZES",
    "Distance",
    "LevelFeatures",
    "core_weight",
    "distance_maps",
    "distance_transform",
    "match_image",
    "preprocess",
    "preprocess_reference",
    "pyramid",
    "shape_skeleton",
]

Distance = Literal["xor", "cwxor", "nwxor"]
DISTANCES: Final[tuple[str, ...]] = ("xor", "cwxor", "nwxor")
#: (width, height) of the pyramid levels used at tree levels 1..3 (paper §2.1).
LEVEL_SIZES: Final[tuple[tuple[int, int], ...]] = ((80, 60), (160, 120), (320, 240))


def pyramid(mask: NDArray[np.bool_], sizes: tuple[tuple[int, int], ...] = LEVEL_SIZES,
            coverage: float = 0.35) -> list[NDArray[np.bool_]]:
    """Down-sample a silhouette to each pyramid level by area averaging.

    Parameters
    ----------
    mask : (H, W) bool
    sizes : tuple of (width, height)
    coverage : float
        Fraction of a coarse pixel that must be covered. Below one half so that limbs thinner
        than a coarse pixel survive, as they do in templates rendered directly at that level.

    Returns
    -------
    list of (h_l, w_l) bool
    """
    m = mask.astype(np.float32)
    out = []
    for w, h in sizes:
        if (w, h) == (mask.shape[1], mask.shape[0]):
            out.append(mask.astype(bool))
        else:
            out.append(cv2.resize(m, (w, h), interpolation=cv2.INTER_AREA) >= coverage)
    return out


def distance_maps(mask: NDArray[np.bool_]) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Euclidean distance transforms of a silhouette.

    Parameters
    ----------
    mask : (H, W) bool
        Silhouette S.

    Returns
    -------
    d_s : (H, W) float32
        ``D(S)``: 0 inside S, distance to S outside.
    d_sbar : (H, W) float32
        ``D(S̄)``: 0 outside S, distance to the background inside (large on the core).
    """
    m = mask.astype(np.uint8)
    return distance_transform(1 - m, cv2.DIST_MASK_5), distance_transform(m, cv2.DIST_MASK_5)


def distance_transform(src: NDArray[np.uint8], mask_size: int = cv2.DIST_MASK_PRECISE) -> NDArray[np.float32]:
    """Euclidean distance of every non-zero pixel of ``src`` to the nearest zero pixel (OpenCV),
    the same for the same input on every call.

    OpenCV 5's ``distanceTransform`` gives results that differ in the last bit (1e-6 px) with the
    output buffer's address modulo 32 bytes (measured: a 60x80 image alternated between two
    results from call to call), which made whole tracking runs irreproducible once the filter's
    smallest weights differed. The output is therefore written into a 64-byte-aligned buffer.

    Parameters
    ----------
    src : (H, W) uint8
    mask_size : int
        ``cv2.DIST_MASK_PRECISE`` (exact) or ``cv2.DIST_MASK_3`` / ``cv2.DIST_MASK_5`` (chamfer).

    Returns
    -------
    (H, W) float32
    """
    src = np.ascontiguousarray(src, dtype=np.uint8)
    n = src.size
    buf = np.empty(n + 16, np.float32)
    start = (-buf.ctypes.data % 64) // 4
    out: NDArray[np.float32] = buf[start:start + n].reshape(src.shape)
    cv2.distanceTransform(src, cv2.DIST_L2, mask_size, dst=out)
    return out


def shape_skeleton(d_sbar: NDArray[np.float32]) -> NDArray[np.bool_]:
    """The shape skeleton: the ridge of ``D(S̄)`` (pixels not smaller than any 8-neighbour).

    Parameters
    ----------
    d_sbar : (H, W) float32

    Returns
    -------
    (H, W) bool
    """
    ridge = (d_sbar >= cv2.dilate(d_sbar, np.ones((3, 3), np.uint8)) - 1e-6) & (d_sbar > 0)
    if not ridge.any() and (d_sbar > 0).any():  # degenerate: a single peak region
        ridge = d_sbar >= d_sbar.max()
    return ridge


def core_weight(mask: NDArray[np.bool_], distance: Distance = "nwxor", alpha: float = 5.0,
                beta: float = 1.0) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """``D(S)`` and the inner (core) term of the weight ``g`` of a distance.

    Parameters
    ----------
    mask : (H, W) bool
    distance : {'xor', 'cwxor', 'nwxor'}
    alpha, beta : float

    Returns
    -------
    d_s : (H, W) float32
        ``D(S)`` (for XOR: 1 outside S).
    inner : (H, W) float32
        XOR: 1 inside S; cwXOR: ``alpha D(S̄)`` (eq. 9); nwXOR: ``beta D(S̄) / (D(S̄) + D(S_skl))``
        (eq. 10); 0 outside S. So ``g = d_s + inner``.
    """
    s = np.asarray(mask, dtype=bool)
    if distance == "xor":
        return (~s).astype(np.float32), s.astype(np.float32)
    d_s, d_sbar = distance_maps(s)
    if distance == "cwxor":
        return d_s, (alpha * d_sbar).astype(np.float32)  # eq. 9
    if distance == "nwxor":
        skl = shape_skeleton(d_sbar)
        d_skl = distance_transform((~skl).astype(np.uint8), cv2.DIST_MASK_5)
        inner = np.where(s, beta * d_sbar / np.maximum(d_sbar + d_skl, 1e-6), 0.0)  # eq. 10
        return d_s, inner.astype(np.float32)
    raise ValueError(f"unknown distance {distance!r}; use one of {DISTANCES}")


def match_image(mask: NDArray[np.bool_], distance: Distance = "nwxor", alpha: float = 5.0,
                beta: float = 1.0) -> tuple[NDArray[np.float32], float]:
    """The per-pixel image ``A = D(S) - inner`` and constant ``B = sum(inner)`` of eq. 11.

    Parameters
    ----------
    mask : (H, W) bool
        Observed silhouette S.
    distance : {'xor', 'cwxor', 'nwxor'}
    alpha : float
        Core weight of eq. 9 (paper: 5).
    beta : float
        Weight of the normalised term of eq. 10 (paper: 1).

    Returns
    -------
    a : (H, W) float32
    b : float
    """
    d_s, inner = core_weight(mask, distance, alpha, beta)
    return (d_s - inner).astype(np.float32), float(inner.sum(dtype=np.float64))


@dataclass(frozen=True)
class LevelFeatures:
    """Everything the likelihood needs at one pyramid level.

    Attributes
    ----------
    integral : (h, w + 1) float64
        Horizontal integral image of ``A``: ``integral[y, x] = sum(A[y, :x])`` (eq. 12).
    b : float
        The constant term ``B``.
    window_area : float
        ``|w|``: area (pixels) of the fixed bounding window, the silhouette's bounding box grown by
        25 % each way; normalises distances across sizes and levels.
    shape : (int, int)
        ``(h, w)`` of the level.
    sat : (h + 1, w + 1) float64 or None
        Summed-area table of ``A`` (``sat[y, x] = sum(A[:y, :x])``), only where ``A`` is
        integer-valued (XOR: every rectangle's sum is exact, so the distance kernel reads a run's
        rows in four lookups and gets the same number; see
        :func:`tracker_service.silhouette._kernels.eval_rects_sat_kernel`). None for cwXOR / nwXOR. Made
        from the same ``A`` as ``integral`` by :func:`preprocess`; a copy that changes one must
        change (or drop) the other.
    """

    integral: NDArray[np.float64]
    b: float
    window_area: float
    shape: tuple[int, int]
    sat: NDArray[np.float64] | None = None


def preprocess(mask: NDArray[np.bool_], distance: Distance = "nwxor", alpha: float = 5.0, beta: float = 1.0,
               sizes: tuple[tuple[int, int], ...] = LEVEL_SIZES) -> list[LevelFeatures]:
    """Pyramid and integral images of an observed silhouette, coarse to fine.

    Parameters
    ----------
    mask : (H, W) bool
        Full-resolution silhouette (320x240 by default).
    distance, alpha, beta
        See :func:`match_image`.
    sizes : tuple of (width, height)

    Returns
    -------
    list of LevelFeatures, one per level.
    """
    if distance == "xor":  # one numba pass per level (the numpy path below is its reference)
        out = []
        for lvl in pyramid(mask, sizes):
            h, w = lvl.shape
            integral = np.empty((h, w + 1))
            sat = np.empty((h + 1, w + 1))
            count, y0, y1, x0, x1 = xor_level_kernel(np.ascontiguousarray(lvl), integral, sat)
            area = _window_area((y0, y1, x0, x1) if count else None, lvl.size)
            out.append(LevelFeatures(integral, float(count), area, (h, w), sat))
        return out
    return preprocess_reference(mask, distance, alpha, beta, sizes)


def _window_area(box: tuple[int, int, int, int] | None, size: int) -> float:
    """Area ``|w|`` of the matching window: the silhouette's bounding box ``(y0, y1, x0, x1)``
    (inclusive) grown 1.5x each way; the whole level (``size`` pixels) when the silhouette is empty
    (``box`` None); at least 1."""
    if box is None:
        return max(float(size), 1.0)
    y0, y1, x0, x1 = box
    return max(float(((y1 - y0 + 1) * 1.5) * ((x1 - x0 + 1) * 1.5)), 1.0)


def preprocess_reference(mask: NDArray[np.bool_], distance: Distance = "nwxor", alpha: float = 5.0,
                         beta: float = 1.0, sizes: tuple[tuple[int, int], ...] = LEVEL_SIZES
                         ) -> list[LevelFeatures]:
    """:func:`preprocess` in numpy: :func:`match_image`, its row sums and, for XOR (``A`` in
    {-1, +1}: exact sums over any rectangle), the summed-area table. The path of cwXOR and nwXOR,
    and the reference of XOR's kernel."""
    out = []
    for lvl in pyramid(mask, sizes):
        a, b = match_image(lvl, distance, alpha, beta)
        integral = np.zeros((a.shape[0], a.shape[1] + 1))
        np.cumsum(a, axis=1, dtype=np.float64, out=integral[:, 1:])
        ys, xs = np.nonzero(lvl)
        area = _window_area((int(ys.min()), int(ys.max()), int(xs.min()), int(xs.max())) if len(ys) else None,
                            lvl.size)
        sat = None
        if distance == "xor":
            sat = np.zeros((a.shape[0] + 1, a.shape[1] + 1))
            np.cumsum(integral, axis=0, out=sat[1:])
        out.append(LevelFeatures(integral, b, area, (lvl.shape[0], lvl.shape[1]), sat))
    return out
