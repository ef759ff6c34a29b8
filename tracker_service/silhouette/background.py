"""Background subtraction (Okada & Stenger §2.2): a per-pixel Gaussian model of intensity-normalised
colour learned from empty frames, a Mahalanobis threshold, morphological clean-up and the largest
connected component.

Chromaticity ``(r, g) = (R, G) / (R + G + B)`` does not change under shadows and global exposure
changes, which is why the paper normalises by intensity. It cannot see dark or grey clothing in
front of a grey wall, so a brightness test completes it: a pixel is foreground when its chromaticity
is far from the model (Mahalanobis distance above ``chroma_threshold``) *or* its brightness ratio
to the model leaves ``[shadow_ratio, highlight_ratio]`` by more than the pixel's noise. Shadows
(darker, same chromaticity) and lighting jitter stay background. In dark pixels chromaticity is
noise, so only brightness counts there.

A camera's automatic exposure brightens or darkens the whole frame (15-25 % within seconds). The
model adapts to it only slowly and never next to the person, so the wall round them would turn
foreground and the silhouette grow a halo that keeps growing; the brightness test therefore compares
each frame with the model times the frame's exposure gain: the median brightness ratio of the frame
to the model over the image (:func:`measured_exposure`; the person covers far less than half of it),
beyond the 5 % that the shadow and highlight bounds absorb by themselves (:func:`exposure_gain`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from tracker_service.silhouette._kernels import foreground_kernel, update_background_kernel

__all__ = [
    "NOISY_BRIGHT_STD",
    "BackgroundModel",
    "BackgroundParams",
    "clean_mask",
    "clean_mask_reference",
    "exposure_gain",
    "learn_background",
    "measured_exposure",
    "raw_foreground",
    "raw_foreground_reference",
    "smoothed",
    "smoothing_for",
    "subtract",
    "update_background",
    "update_background_reference",
]

_EPS = 1e-6


@dataclass(frozen=True)
class BackgroundParams:
    """Thresholds of :func:`subtract`. Defaults from a grid search on the synthetic scene (3 subjects,
    rooms and lightings; 36 frames): mean silhouette IoU 0.93 (worst frame 0.88) against the
    scene's true silhouette, versus 0.76 for the first guess (chroma 4, brightness 4 sigma,
    shadows down to 0.45); then the chroma threshold raised from 3 to 6 for compressed frames (a
    webcam's MJPEG bleeds the person's colour into the room around them): on frames through JPEG
    at quality 70, IoU against the true silhouette 0.55 -> 0.69 and the tracker's MPJPE 10.9 ->
    7.6 cm (6 held-out takes), while on lossless frames IoU 0.81 -> 0.79 and MPJPE 6.52 -> 6.50 cm.

    Attributes
    ----------
    chroma_threshold : float
        Mahalanobis distance on chromaticity above which a pixel is foreground.
    chroma_threshold_subsampled : float
        The same for a camera whose colour is subsampled (MJPEG, H.264, YUV 4:2:0 or 4:2:2: its
        colour bleeds across the person's outline; :func:`chroma_subsampled`).
    shadow_ratio, highlight_ratio : float
        Brightness ratios (frame / model) still explained by shadows and highlights.
    brightness_sigmas : float
        Noise margin on the brightness ratio, in standard deviations of the pixel's brightness.
    dark_level : float
        Model brightness (0-255) under which chromaticity is ignored.
    min_area_frac : float
        The largest component must cover at least this fraction of the image, else empty mask.
    open_px, close_px : int
        Morphological opening / closing kernel sizes (pixels at the working resolution).
    part_frac, part_reach : float
        Other components kept as parts of the person: at least ``part_frac`` of the largest's area,
        within ``part_reach`` of its height above or below its box (a third of that sideways);
        ``part_frac`` 1: the largest component alone.
    reconstruct : bool
        Opening by reconstruction: the raw foreground's pieces within 2 pixels of the kept
        silhouette come back (a thin arm the opening erased; specks elsewhere stay out), looked for
        within ``part_reach`` of its height round its box.
    exposure : bool
        The brightness test follows the frame's exposure (:func:`exposure_gain`); False: the
        model's brightness as learned.
    exposure_tolerance : float
        The exposure change the shadow and highlight bounds absorb by themselves (they were chosen
        on frames that drift by 3 %): only the change beyond it is followed. Following every
        percent pushed the scene's floor shadows, at 0.6 of the lit floor, past ``shadow_ratio``
        (robustness matrix +0.15 cm on rows without exposure drift).
    """

    chroma_threshold: float = 6.0
    chroma_threshold_subsampled: float = 9.0
    shadow_ratio: float = 0.6
    highlight_ratio: float = 1.2
    brightness_sigmas: float = 2.0
    dark_level: float = 25.0
    min_area_frac: float = 0.002
    open_px: int = 3
    close_px: int = 5
    part_frac: float = 0.01
    part_reach: float = 0.5
    reconstruct: bool = True
    exposure: bool = True
    exposure_tolerance: float = 0.05


@dataclass(frozen=True)
class BackgroundModel:
    """Per-pixel Gaussian background model.

    Attributes
    ----------
    chroma_mean : (H, W, 2) float32
        Mean chromaticity ``(r, g)``.
    chroma_inv_var : (H, W, 2) float32
        Inverse variances (diagonal covariance) of the chromaticity.
    bright_mean : (H, W) float32
        Mean brightness ``(R + G + B) / 3``.
    bright_std : (H, W) float32
        Standard deviation of the brightness.
    n_frames : int
        Frames the model was learned from.
    smooth_sigma : float
        Gaussian smoothing (pixels) applied to every frame before it is compared with the model,
        and to the frames it was learned from; 0 for a quiet camera (:func:`smoothing_for`).
    subsampled : bool
        The learning frames' colour is subsampled (:func:`chroma_subsampled`): the chroma test uses
        ``BackgroundParams.chroma_threshold_subsampled``.
    """

    chroma_mean: NDArray[np.float32]
    chroma_inv_var: NDArray[np.float32]
    bright_mean: NDArray[np.float32]
    bright_std: NDArray[np.float32]
    n_frames: int
    smooth_sigma: float = 0.0
    subsampled: bool = False

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.bright_mean.shape[0]), int(self.bright_mean.shape[1]))


def _chroma_bright(frame: NDArray[np.uint8]) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    f = frame.astype(np.float32)
    s = f.sum(axis=-1)
    chroma = f[..., 1:3] / np.maximum(s, _EPS)[..., None]  # BGR: (G, R) / sum
    return chroma, s / 3.0


#: A camera whose median per-pixel brightness noise (0-255) over the learning frames is above this
#: is noisy: its frames are smoothed before subtraction (the synthetic scene's own camera: 2.0).
NOISY_BRIGHT_STD = 2.6


def smoothing_for(bright_std: NDArray[np.floating]) -> float:
    """The pre-smoothing (Gaussian sigma, pixels) for a camera with this per-pixel brightness noise
    ``(H, W)``: 0 up to :data:`NOISY_BRIGHT_STD`, then growing with the noise (1 px at 3x the
    scene's noise, at most 1.5 px). Averaging n pixels divides the noise by about sqrt(n); the
    person's limbs (3-8 px wide at 320x240) survive a sigma of 1.5."""
    noise = float(np.median(bright_std))
    if noise <= NOISY_BRIGHT_STD:
        return 0.0
    return float(np.clip(0.4 * noise - 0.2, 0.7, 1.5))


def smoothed(frame: NDArray[np.uint8], sigma: float) -> NDArray[np.uint8]:
    """``frame`` (..., H, W, 3) uint8 smoothed by a Gaussian of ``sigma`` pixels (0: unchanged)."""
    if sigma <= 0:
        return frame
    if frame.ndim == 4:
        return np.stack([smoothed(f, sigma) for f in frame])
    return np.asarray(cv2.GaussianBlur(frame, (0, 0), sigma), np.uint8)


#: Chroma detail over luma detail (:func:`chroma_detail`) under which the colour is subsampled: the
#: synthetic scene's full-resolution colour measures 0.5-0.85, the same frames through JPEG
#: (q50-90) 0.10-0.14 and through H.264 (CRF 18-34) 0.19-0.39.
SUBSAMPLED_CHROMA_DETAIL = 0.44


def chroma_detail(frame: NDArray[np.uint8]) -> float:
    """Fine detail of the colour relative to the brightness's: the mean absolute difference of
    Cr and Cb from their Gaussian blur (sigma 1 px) over the same for Y. Codecs and cameras that
    keep colour at half resolution (4:2:0, 4:2:2) score far lower than full-resolution colour.

    Parameters
    ----------
    frame : (H, W, 3) uint8
        BGR.
    """
    ycc = cv2.cvtColor(np.ascontiguousarray(frame, np.uint8), cv2.COLOR_BGR2YCrCb).astype(np.float32)

    def detail(c: NDArray[np.float32]) -> float:
        return float(np.abs(c - cv2.GaussianBlur(c, (0, 0), 1.0)).mean())

    return 0.5 * (detail(ycc[..., 1]) + detail(ycc[..., 2])) / max(detail(ycc[..., 0]), 1e-6)


def chroma_subsampled(frames: NDArray[np.uint8]) -> bool:
    """Whether the frames' ``(N, H, W, 3)`` colour is subsampled (the median of up to 5 frames'
    :func:`chroma_detail` under :data:`SUBSAMPLED_CHROMA_DETAIL`)."""
    pick = frames[np.linspace(0, len(frames) - 1, min(5, len(frames))).astype(int)]
    return bool(np.median([chroma_detail(f) for f in pick]) < SUBSAMPLED_CHROMA_DETAIL)


def _learned(frames: NDArray[np.uint8], learn: Callable[[NDArray[np.uint8]], BackgroundModel],
             noise: NDArray[np.floating] | None = None) -> BackgroundModel:
    """``learn(frames)``, and for a noisy camera (``noise``, default the model's brightness spread)
    again on smoothed frames (``smooth_sigma`` set); ``subsampled`` measured."""
    model = replace(learn(frames), subsampled=chroma_subsampled(frames))
    sigma = smoothing_for(model.bright_std if noise is None else noise)
    if sigma <= 0:
        return model
    return replace(learn(smoothed(frames, sigma)), smooth_sigma=sigma, subsampled=model.subsampled)


def chroma_threshold_of(model: BackgroundModel, params: BackgroundParams) -> float:
    """The chroma test's threshold for this camera (higher when its colour is subsampled)."""
    return params.chroma_threshold_subsampled if model.subsampled else params.chroma_threshold


def learn_background(frames: NDArray[np.uint8], chroma_std_floor: float = 0.004,
                     bright_std_floor: float = 2.0) -> BackgroundModel:
    """Learn the model from frames of the empty scene.

    Parameters
    ----------
    frames : (N, H, W, 3) uint8
        BGR frames without the subject (N >= 2; 10-30 recommended).
    chroma_std_floor, bright_std_floor : float
        Lower bounds of the standard deviations (a static synthetic scene has none).

    Returns
    -------
    BackgroundModel
    """
    f = np.asarray(frames)
    if f.ndim != 4 or f.shape[-1] != 3 or f.shape[0] < 2:
        raise ValueError(f"need (N >= 2, H, W, 3) frames, got {f.shape}")

    def learn(g: NDArray[np.uint8]) -> BackgroundModel:
        c, b = _chroma_bright(g)
        return _model(c.mean(axis=0), c.std(axis=0), b.mean(axis=0), b.std(axis=0), int(g.shape[0]),
                      chroma_std_floor, bright_std_floor)

    return _learned(f, learn)


def _model(c_mean: NDArray[np.floating], c_std: NDArray[np.floating], b_mean: NDArray[np.floating],
           b_std: NDArray[np.floating], n: int, chroma_std_floor: float, bright_std_floor: float) -> BackgroundModel:
    """The model from per-pixel centres and spreads of chromaticity and brightness (spreads floored)."""
    c_std = np.maximum(c_std, chroma_std_floor)
    b_std = np.maximum(b_std, bright_std_floor)
    return BackgroundModel(
        chroma_mean=np.asarray(c_mean).astype(np.float32),
        chroma_inv_var=(1.0 / c_std**2).astype(np.float32),
        bright_mean=np.asarray(b_mean).astype(np.float32),
        bright_std=b_std.astype(np.float32),
        n_frames=n,
    )


def learn_background_robust(frames: NDArray[np.uint8], chroma_std_floor: float = 0.004,
                            bright_std_floor: float = 2.0) -> BackgroundModel:
    """Learn the model from frames that may show a moving person (no empty room needed).

    Each pixel's chromaticity and brightness are the medians over the frames, and their spread the
    scaled median absolute deviation (1.4826 MAD), so that a person covering a pixel in fewer than
    half of the frames does not enter the model: the room behind them is learned as they move.

    Parameters
    ----------
    frames : (N, H, W, 3) uint8
        BGR frames spread over a few seconds (N >= 3).
    chroma_std_floor, bright_std_floor : float
        Lower bounds of the standard deviations.

    Returns
    -------
    BackgroundModel
    """
    f = np.asarray(frames)
    if f.ndim != 4 or f.shape[-1] != 3 or f.shape[0] < 3:
        raise ValueError(f"need (N >= 3, H, W, 3) frames, got {f.shape}")

    def learn(g: NDArray[np.uint8]) -> BackgroundModel:
        c, b = _chroma_bright(g)
        c_med, b_med = np.median(c, axis=0), np.median(b, axis=0)
        c_mad, b_mad = np.median(np.abs(c - c_med), axis=0), np.median(np.abs(b - b_med), axis=0)
        return _model(c_med, 1.4826 * c_mad, b_med, 1.4826 * b_mad, int(g.shape[0]), chroma_std_floor,
                      bright_std_floor)

    # the camera's noise from frame-to-frame differences: the spread over seconds also holds the
    # exposure drift, which would take a quiet camera for a noisy one (and smooth its frames)
    _, b = _chroma_bright(f)
    noise = 1.4826 * np.median(np.abs(np.diff(b, axis=0)), axis=0) / np.sqrt(2.0)
    return _learned(f, learn, noise)


def measured_exposure(model: BackgroundModel, frame: NDArray[np.uint8],
                      params: BackgroundParams = BackgroundParams(), step: int = 4) -> float:
    """The frame's exposure relative to the model's: the median ratio of the frame's brightness to the
    model's over every ``step``-th pixel of every ``step``-th row.

    Only pixels that measure it count: the model's brightness above ``params.dark_level`` (noise
    below) and both brightnesses under 240 (a clipped pixel cannot brighten). A person covering
    less than half of the image moves the median by a fraction of the camera's noise.

    Parameters
    ----------
    model : BackgroundModel
    frame : (H, W, 3) uint8
    params : BackgroundParams
    step : int

    Returns
    -------
    float
        In [0.5, 2]; 1 when ``params.exposure`` is off or fewer than 64 pixels measure it.
    """
    if not params.exposure:
        return 1.0
    b = frame[::step, ::step].sum(axis=-1, dtype=np.float32) / np.float32(3.0)  # a median needs no smoothing
    bm = model.bright_mean[::step, ::step]
    ok = (bm > params.dark_level) & (bm < 240.0) & (b < 240.0) & (b > 0.5 * params.dark_level)
    if int(np.count_nonzero(ok)) < 64:
        return 1.0
    return float(np.clip(np.median(b[ok] / bm[ok]), 0.5, 2.0))


def exposure_gain(model: BackgroundModel, frame: NDArray[np.uint8], params: BackgroundParams = BackgroundParams()
                  ) -> float:
    """The gain the brightness test applies to the model: the frame's :func:`measured_exposure` beyond
    ``params.exposure_tolerance`` (1 within it; 1.35 with a tolerance of 0.05 gives 1.35 / 1.05).

    Parameters
    ----------
    model : BackgroundModel
    frame : (H, W, 3) uint8
    params : BackgroundParams

    Returns
    -------
    float
    """
    g = measured_exposure(model, frame, params)
    tol = params.exposure_tolerance
    return float(g / np.clip(g, 1.0 - tol, 1.0 + tol))


def raw_foreground(model: BackgroundModel, frame: NDArray[np.uint8],
                   params: BackgroundParams = BackgroundParams(), gain: float | None = None) -> NDArray[np.bool_]:
    """Per-pixel classification before clean-up (numba kernel; reference :func:`raw_foreground_reference`).

    Parameters
    ----------
    model : BackgroundModel
    frame : (H, W, 3) uint8
    params : BackgroundParams
    gain : float, optional
        The frame's exposure gain (default: :func:`exposure_gain`).

    Returns
    -------
    (H, W) bool
    """
    if frame.shape[:2] != model.shape or frame.ndim != 3:
        raise ValueError(f"frame {frame.shape} does not match the background model {model.shape}")
    g = exposure_gain(model, frame, params) if gain is None else float(gain)
    out = np.empty(model.shape, bool)
    f32 = np.float32
    frame = smoothed(frame, model.smooth_sigma)
    foreground_kernel(np.ascontiguousarray(frame, np.uint8), np.ascontiguousarray(model.chroma_mean, f32),
                      np.ascontiguousarray(model.chroma_inv_var, f32), np.ascontiguousarray(model.bright_mean, f32),
                      np.ascontiguousarray(model.bright_std, f32), chroma_threshold_of(model, params),
                      params.shadow_ratio,
                      params.highlight_ratio, params.brightness_sigmas, params.dark_level, out, g)
    return out


def raw_foreground_reference(model: BackgroundModel, frame: NDArray[np.uint8],
                   params: BackgroundParams = BackgroundParams(), gain: float | None = None) -> NDArray[np.bool_]:
    """Plain-numpy reference of :func:`raw_foreground` (a test holds the two equal).

    Parameters
    ----------
    model : BackgroundModel
    frame : (H, W, 3) uint8
    params : BackgroundParams
    gain : float, optional

    Returns
    -------
    (H, W) bool
    """
    if frame.shape[:2] != model.shape or frame.ndim != 3:
        raise ValueError(f"frame {frame.shape} does not match the background model {model.shape}")
    g = np.float32(exposure_gain(model, frame, params) if gain is None else gain)
    c, b = _chroma_bright(smoothed(frame, model.smooth_sigma))
    d = c - model.chroma_mean
    maha = np.sqrt((d * d * model.chroma_inv_var).sum(axis=-1))
    ratio = b / (np.maximum(model.bright_mean, 1.0) * g)
    margin = params.brightness_sigmas * model.bright_std / np.maximum(model.bright_mean, 1.0)
    bright_fg = (ratio < params.shadow_ratio - margin) | (ratio > params.highlight_ratio + margin)
    lit = (model.bright_mean > params.dark_level) & (b > params.dark_level)
    return bright_fg | (lit & (maha > chroma_threshold_of(model, params)))


def clean_mask(mask: NDArray[np.bool_], params: BackgroundParams = BackgroundParams()) -> NDArray[np.bool_]:
    """Opening, closing, largest connected component, holes filled.

    After the opening everything happens in the box round what is left, grown by the closing's
    size plus one pixel: the result is the same as on the whole image (outside the box the closed
    mask is empty, and every background pixel there reaches the image border), and the
    connected-component pass, the costliest step (0.5 ms of a 320 x 240 frame, 0.15 ms on the
    box), sees a few times fewer pixels. :func:`clean_mask_reference` is the whole-image form.

    Parameters
    ----------
    mask : (H, W) bool

    Returns
    -------
    (H, W) bool
        Empty if the largest component is smaller than ``min_area_frac`` of the image.
    """
    m = _opened(mask, params)
    out = np.zeros(mask.shape, bool)
    x, y, w, h = cv2.boundingRect(m)
    if w == 0 or h == 0:
        return out
    pad = max(params.close_px, 0) + 1
    ys = slice(max(y - pad, 0), min(y + h + pad, m.shape[0]))
    xs = slice(max(x - pad, 0), min(x + w + pad, m.shape[1]))
    box = _largest_filled(np.ascontiguousarray(m[ys, xs]), params, mask.size)
    if box is not None:
        out[ys, xs] = box
    return _reconstructed(mask, out, params)


def clean_mask_reference(mask: NDArray[np.bool_], params: BackgroundParams = BackgroundParams()) -> NDArray[np.bool_]:
    """:func:`clean_mask` on the whole image (a test holds the two equal); ``mask (H, W) bool``
    -> ``(H, W) bool``."""
    m = _opened(mask, params)
    box = _largest_filled(m, params, mask.size)
    return _reconstructed(mask, np.zeros(mask.shape, bool) if box is None else box, params)


def _reconstructed(raw: NDArray[np.bool_], kept: NDArray[np.bool_], params: BackgroundParams) -> NDArray[np.bool_]:
    """``kept`` with the 8-connected pieces of ``raw`` within 2 pixels of it added (looked for within
    ``part_reach`` of its box's height round it), when ``params.reconstruct``;
    ``raw, kept (H, W) bool -> (H, W) bool``."""
    if not params.reconstruct or not kept.any():
        return kept
    x, y, w, h = cv2.boundingRect(kept.view(np.uint8))
    reach = params.part_reach * h
    y0, y1 = max(int(y - reach), 0), min(int(y + h + reach) + 1, raw.shape[0])
    x0, x1 = max(int(x - reach), 0), min(int(x + w + reach) + 1, raw.shape[1])  # arms reach out sideways
    r = np.ascontiguousarray(raw[y0:y1, x0:x1] | kept[y0:y1, x0:x1]).view(np.uint8)
    n, labels = cv2.connectedComponents(r, connectivity=8)
    near = cv2.dilate(kept[y0:y1, x0:x1].view(np.uint8), _ellipse(5)).view(bool)  # a gap of 2 px bridged
    touching = np.zeros(n, bool)  # a lookup table of the labels to keep
    touching[labels[near]] = True
    touching[0] = False
    out = kept.copy()
    out[y0:y1, x0:x1] |= touching[labels]
    return out


def _opened(mask: NDArray[np.bool_], params: BackgroundParams) -> NDArray[np.uint8]:
    m = np.asarray(mask, dtype=np.uint8)
    if params.open_px > 1:
        m = np.asarray(cv2.morphologyEx(m, cv2.MORPH_OPEN, _ellipse(params.open_px)), dtype=np.uint8)
    return m


def _ellipse(size: int) -> NDArray[np.uint8]:
    return np.asarray(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)), dtype=np.uint8)


def _largest_filled(m: NDArray[np.uint8], params: BackgroundParams, image_size: int) -> NDArray[np.bool_] | None:
    """Closing, the largest 8-connected component with the parts that belong to it, and holes
    filled, of the opened ``m`` ``(h, w) uint8``; None if the largest component is under
    ``min_area_frac`` of ``image_size`` pixels.

    A person whose shirt or hair matches the wall behind falls apart into pieces (legs below a
    missing waist, a head above a missing neck): a component of at least ``part_frac`` of the
    largest's area whose box touches the largest's box grown by ``part_reach`` of its height (sideways
    a third of that) is a part of the same person and kept, if it lies above or below a kept piece
    (within its columns, at most ``part_reach`` of the largest's height away) or beside one (within
    its rows, at most a third of that away): not off their corners (a backlit person's shadow on the
    wall above and beside their head was kept as a head and measured a 1.56 m man at 2.11 m). Each
    kept piece counts for the next, so an arm beside a torso that is itself a piece above the legs
    stays."""
    if params.close_px > 1:
        m = np.asarray(cv2.morphologyEx(m, cv2.MORPH_CLOSE, _ellipse(params.close_px)), dtype=np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n <= 1:
        return None
    areas = stats[1:, cv2.CC_STAT_AREA]
    k = 1 + int(np.argmax(areas))
    if stats[k, cv2.CC_STAT_AREA] < params.min_area_frac * image_size:
        return None
    keep = labels == k
    if params.part_frac < 1.0 and n > 2:
        x, y, w, h = (int(v) for v in stats[k, :4])
        reach = params.part_reach * h
        x0, x1 = x - reach / 3, x + w + reach / 3
        y0, y1 = y - reach, y + h + reach
        min_area = params.part_frac * stats[k, cv2.CC_STAT_AREA]
        near = [j for j in range(1, n) if j != k and stats[j, cv2.CC_STAT_AREA] >= min_area
                and stats[j, 0] < x1 and stats[j, 0] + stats[j, 2] > x0 and stats[j, 1] < y1
                and stats[j, 1] + stats[j, 3] > y0]  # within the largest's box grown by the reach
        # of those, the pieces above or below a kept piece (within its columns, ``reach`` away at most) or
        # beside one (within its rows, a third of that), each kept piece joining the reference: not off
        # their corners (a shadow up on the wall above and beside the head is no head)
        kept = [(x, y, x + w, y + h)]
        grew = True
        while grew and near:
            grew = False
            for j in list(near):
                xj, yj, wj, hj = (int(v) for v in stats[j, :4])
                if any((xj < bx1 and xj + wj > bx0 and max(by0 - yj - hj, yj - by1) <= reach)
                       or (yj < by1 and yj + hj > by0 and max(bx0 - xj - wj, xj - bx1) <= reach / 3)
                       for bx0, by0, bx1, by1 in kept):
                    keep |= labels == j
                    kept.append((xj, yj, xj + wj, yj + hj))
                    near.remove(j)
                    grew = True
    # fill holes: background regions not 4-connected to the border (flood the background from a
    # one-pixel frame around the image; what the flood does not reach is inside the body)
    hh, ww = m.shape
    outside = np.zeros((hh + 2, ww + 2), np.uint8)
    outside[1:-1, 1:-1] = keep
    cv2.floodFill(outside, None, (0, 0), 2, flags=4)
    filled: NDArray[np.bool_] = outside[1:-1, 1:-1] != 2
    return filled


def subtract(model: BackgroundModel, frame: NDArray[np.uint8],
             params: BackgroundParams = BackgroundParams()) -> NDArray[np.bool_]:
    """The subject's silhouette in a frame.

    Parameters
    ----------
    model : BackgroundModel
    frame : (H, W, 3) uint8
        BGR frame at the model's resolution.
    params : BackgroundParams

    Returns
    -------
    (H, W) bool
    """
    return clean_mask(raw_foreground(model, frame, params), params)


def update_background(model: BackgroundModel, frame: NDArray[np.uint8], foreground: NDArray[np.bool_],
                      rate: float = 0.01, rows: tuple[int, int] = (0, 1)) -> BackgroundModel:
    """Slow adaptive update of the background pixels (running mean and variance; numba kernel,
    reference :func:`update_background_reference`).

    Parameters
    ----------
    model : BackgroundModel
    frame : (H, W, 3) uint8
    foreground : (H, W) bool
        Pixels to leave untouched (the subject, dilated by the caller if desired).
    rate : float
        Learning rate in (0, 1).
    rows : (int, int)
        ``(first, step)``: only every ``step``-th row from ``first`` is updated (the pipeline
        updates alternate rows at twice the rate: the same time constant at half the cost).

    Returns
    -------
    BackgroundModel
        New arrays; ``model`` is not changed.
    """
    if not 0 < rate < 1:
        raise ValueError("rate must be in (0, 1)")
    cm, cinv = model.chroma_mean.copy(), model.chroma_inv_var.copy()
    bm, bs = model.bright_mean.copy(), model.bright_std.copy()
    update_background_kernel(np.ascontiguousarray(smoothed(frame, model.smooth_sigma)),
                             np.ascontiguousarray(foreground, dtype=np.bool_), float(rate), cm, cinv, bm, bs,
                             int(rows[0]), int(rows[1]))
    return replace(model, chroma_mean=cm, chroma_inv_var=cinv, bright_mean=bm, bright_std=bs)


def update_background_reference(model: BackgroundModel, frame: NDArray[np.uint8], foreground: NDArray[np.bool_],
                                rate: float = 0.01, rows: tuple[int, int] = (0, 1)) -> BackgroundModel:
    """Numpy reference of :func:`update_background`."""
    if not 0 < rate < 1:
        raise ValueError("rate must be in (0, 1)")
    c, b = _chroma_bright(smoothed(frame, model.smooth_sigma))
    skip = np.ones(foreground.shape, bool)
    skip[rows[0]::rows[1]] = False
    w = np.where(foreground | skip, 0.0, rate).astype(np.float32)
    cm = model.chroma_mean + w[..., None] * (c - model.chroma_mean)
    c_var = 1.0 / model.chroma_inv_var
    c_var = c_var + w[..., None] * ((c - cm) ** 2 - c_var)
    bm = model.bright_mean + w * (b - model.bright_mean)
    b_var = model.bright_std**2 + w * ((b - bm) ** 2 - model.bright_std**2)
    return replace(
        model,
        chroma_mean=cm.astype(np.float32),
        chroma_inv_var=(1.0 / np.maximum(c_var, 0.004**2)).astype(np.float32),
        bright_mean=bm.astype(np.float32),
        bright_std=np.sqrt(np.maximum(b_var, 4.0)).astype(np.float32),
    )
