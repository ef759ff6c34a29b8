"""Ghost detection: is the silhouette a person, or the hole a person left in a background that was
learned with them in view?

A background learned while the person stood in view holds their picture. Once they move, background
subtraction reports two things as foreground: the person where they are now, and a *ghost* where
they were (the room, now seen, differs from the model's picture of them). The two have opposite
edge signatures along the silhouette's outline: a real person's outline lies on an edge of the
**current frame** (their own contour against the room), a ghost's outline lies on an edge of the
**background model** (the contour of the person it holds) while the current frame shows the room
there. This is the edge test of ghost detection in the background-subtraction literature
(Cucchiara et al., "Detecting moving objects, ghosts, and shadows in video streams", PAMI 2003),
made robust to textured rooms by looking only at the gradient *across* the outline: at each outline
pixel, for each image,

    e = |g . n| - |g x n|

with ``g`` the image's gradient and ``n`` the outline's normal: an edge along the outline gives a
large ``e``, texture (gradients pointing anywhere) a small one of either sign. A pixel votes
*ghost* when the background's ``e`` exceeds ``dominance`` times the frame's by ``margin``, *person*
the other way round, and neither where both images have the edge (the outline of clothes the
colour of the wall follows the room's own edges) or neither has one:

    ghost fraction = ghost votes / (ghost votes + person votes)

The pipeline judges the median of the last few frames' fractions
(:class:`GhostParams`, :func:`tracker_service.pipeline.process.process_frame`).

Edges alone cannot tell a ghost from *camouflage*: a shirt the colour of the wall in front of a dark
object (a plant) shows only where it covers the object, so that piece of the silhouette is bounded
by the object's outline -- on the model's edges, none in the frame, exactly a ghost's signature
(a subject in such a shirt before a plant was withheld and had the room learned again over and over:
11 of 51 takes never tracked). Against the first background, learned from an empty-looking room, a
pixel therefore votes *ghost* only with one of two further facts: the model's brightness spread
there is above the camera's noise (a person learned into the background moved while it was learned;
a room object did not), or the pixel lies outside the convex hull of the outline that votes
*person* (one who stood still and then stepped away left their ghost apart from where they are; the
object's piece of shirt lies within the person's outline). Where the person votes are sparse (a
blurred, noisy camera), that piece can bulge a few pixels out of their hull; a ghost vote there
still counts as the person's when it lies close to the hull (:attr:`GhostParams.notch_margin`) on
a short stretch of the contour between two person votes (:attr:`GhostParams.notch_run`): a notch in
the person, where a ghost left apart has its whole far side. A background learned again (a robust
median while the person moves about) is judged by edges alone.

Measured by edges alone on the synthetic scene (4 held-out takes × 2 subjects × 7 scene variations,
every second frame; ``bench/bench_start_in_view.py`` for the tracker's behaviour): an empty-room
start gives a median fraction of 0.00-0.20 per take and at most 0.30 over any five frames (clothes the colour of
the wall, changing lights, photographic backdrops are the highest); a start with the person in view
(the background learned from them) 0.37-0.44 medians once they move, above 0.27 in 78-100 % of the
frames. An earlier form that summed ``e`` over the outline separated them worse (empty room up to
0.39 under changing lights, person in view down to 0.29 medians).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

__all__ = ["GhostParams", "across_minus_along", "ghost_fraction"]


@dataclass(frozen=True)
class GhostParams:
    """Scales of :func:`ghost_fraction` and the pipeline's reaction to it.

    Attributes
    ----------
    image_sigma : float
        Gaussian smoothing (pixels) of both images before their gradients (the outline may sit a
        pixel off the edge).
    mask_sigma : float
        Gaussian smoothing (pixels) of the silhouette before its gradient gives the outline's normal.
    dominance, margin : float
        An outline pixel votes for the image whose ``e`` is more than ``dominance`` times the other's
        plus ``margin`` (Sobel units of brightness 0-255).
    window : int
        The pipeline judges the median fraction of the last ``window`` frames.
    threshold : float
        The median fraction above which the silhouette is taken for a ghost: its pose is withheld.
    threshold_start, start_poses : float, int
        The threshold until ``start_poses`` poses were published since the background was learned
        (a background with a person in it shows at the start).
    threshold_relearned : float
        The same once the background was learned again because of a ghost: a person who stayed
        where they stood is partly in the medians, and the pieces of them that moved leave fainter
        ghosts.
    clear : float
        A single frame above this is withheld whatever the median.
    frames, relearn_level : int, float
        After ``frames`` consecutive withheld frames whose median is above ``relearn_level`` the
        background is learned again.
    min_outline : int
        Outline pixels a silhouette needs before it is judged (smaller: fraction 0).
    motion_factor : float
        With the background model's brightness spread given (a model learned from an empty-looking
        room, :func:`ghost_fraction`), a pixel votes *ghost* only where that spread is above
        ``motion_factor`` times its median over the image: a person learned into the background
        moved while the room was learned, so their outline there spread; a room object whose edge
        a person's clothes happen to hide (a dark plant behind a wall-coloured shirt: the shirt shows
        only over the plant, an outline on the background's edges) did not. 0: every pixel votes.
    moved_threshold, moved_relearn_level : float
        ``threshold`` (and ``threshold_start``) and ``relearn_level`` for fractions counted that way:
        with an empty room learned they stay at 0.04 or below over any five frames (0.15 for a very
        noisy camera on a camouflaged shirt), with a person learned into it they reach 0.1-0.37 once
        the person moves.
    notch_margin, notch_run : float
        A ghost vote outside the hull of the person votes is the person's after all when it lies
        within ``notch_margin`` times the silhouette's height of that hull, on a stretch of the
        contour between two person votes shorter than ``notch_run`` times that height: a piece of a
        camouflaged shirt, bounded by a room object's edge, bulging out of a blurred camera's sparse
        person votes. 0: no such exception. Widening the hull to 6 % alone let the ghost of a person
        who stood still and stepped away pass (a pose published 1.2 m off).
    """

    image_sigma: float = 1.0
    mask_sigma: float = 1.5
    dominance: float = 2.0
    margin: float = 8.0
    window: int = 5
    threshold: float = 0.32
    threshold_start: float = 0.27
    threshold_relearned: float = 0.2
    clear: float = 0.45
    start_poses: int = 30
    frames: int = 6
    relearn_level: float = 0.3
    min_outline: int = 40
    motion_factor: float = 3.0
    moved_threshold: float = 0.06
    moved_relearn_level: float = 0.08
    notch_margin: float = 0.06
    notch_run: float = 0.4


_K3 = np.ones((3, 3), np.uint8)


def _gradient(image: NDArray[np.float32], sigma: float) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Sobel gradient ``(gx, gy)`` of ``image`` smoothed by a Gaussian of ``sigma`` pixels."""
    b = cv2.GaussianBlur(image, (0, 0), sigma) if sigma > 0 else image
    gx = np.asarray(cv2.Sobel(b, cv2.CV_32F, 1, 0, ksize=3), np.float32)
    return gx, np.asarray(cv2.Sobel(b, cv2.CV_32F, 0, 1, ksize=3), np.float32)


def across_minus_along(image: NDArray[np.float32], outline: NDArray[np.bool_], nx: NDArray[np.float32],
                       ny: NDArray[np.float32], sigma: float) -> NDArray[np.float32]:
    """``e`` of the module docstring at each outline pixel: the gradient across the outline minus the
    gradient along it.

    Parameters
    ----------
    image : (H, W) float32
        Brightness.
    outline : (H, W) bool
    nx, ny : (N,) float32
        The unit normal at each of the ``N`` outline pixels (row-major order).
    sigma : float

    Returns
    -------
    (N,) float32
    """
    gx, gy = _gradient(image, sigma)
    ax, ay = gx[outline], gy[outline]
    return np.asarray(np.abs(ax * nx + ay * ny) - np.abs(ax * ny - ay * nx), np.float32)


def ghost_fraction(background_bright: NDArray[np.floating], frame: NDArray[np.uint8], mask: NDArray[np.bool_],
                   params: GhostParams = GhostParams(), frame_sigma: float = 0.0,
                   background_std: NDArray[np.floating] | None = None) -> float:
    """The share of the silhouette's outline that votes *ghost* rather than *person*.

    Parameters
    ----------
    background_bright : (H, W) float
        The background model's brightness ``(R + G + B) / 3``
        (:attr:`~tracker_service.silhouette.background.BackgroundModel.bright_mean`).
    frame : (H, W, 3) uint8
        The current frame, as the camera gave it.
    mask : (H, W) bool
        Its silhouette.
    params : GhostParams
    frame_sigma : float
        The Gaussian smoothing the model's learning frames had
        (:attr:`~tracker_service.silhouette.background.BackgroundModel.smooth_sigma`): the frame's
        crop gets it too, folded into its gradient's smoothing (two Gaussians make one), so that
        the whole frame is not smoothed once more.
    background_std : (H, W) float, optional
        The model's brightness spread over the frames it was learned from
        (:attr:`~tracker_service.silhouette.background.BackgroundModel.bright_std`): a *ghost* vote
        then needs the spread of :attr:`GhostParams.motion_factor` (None: no such condition).

    Returns
    -------
    float
        In [0, 1]; 0 for a silhouette with fewer than ``params.min_outline`` outline pixels or no
        vote either way.
    """
    m = mask.astype(np.uint8)
    outline_full = m > cv2.erode(m, _K3, borderType=cv2.BORDER_REPLICATE)
    if int(np.count_nonzero(outline_full)) < params.min_outline:
        return 0.0
    bx, by, bw, bh = cv2.boundingRect(outline_full.view(np.uint8))  # the outline's box, without index arrays
    frame_blur = float(np.hypot(params.image_sigma, frame_sigma))
    pad = int(np.ceil(3 * max(frame_blur, params.mask_sigma))) + 2
    y0, x0 = max(by - pad, 0), max(bx - pad, 0)
    y1, x1 = by + bh + pad, bx + bw + pad
    outline = outline_full[y0:y1, x0:x1]
    mx, my = _gradient(m[y0:y1, x0:x1].astype(np.float32), params.mask_sigma)
    norm = np.hypot(mx[outline], my[outline]) + np.float32(1e-9)
    nx, ny = (mx[outline] / norm).astype(np.float32), (my[outline] / norm).astype(np.float32)
    crop = np.asarray(frame[y0:y1, x0:x1], np.float32)
    cur = (crop[..., 0] + crop[..., 1] + crop[..., 2]) / np.float32(3.0)  # mean(axis=2)'s sums, 3x faster
    then = np.ascontiguousarray(background_bright[y0:y1, x0:x1], np.float32)
    e_now = across_minus_along(cur, outline, nx, ny, frame_blur)
    e_then = across_minus_along(then, outline, nx, ny, params.image_sigma)
    k, c = params.dominance, params.margin
    ghosty = e_then > k * np.maximum(e_now, 0.0) + c
    persony = e_now > k * np.maximum(e_then, 0.0) + c
    person, ghost = int(np.count_nonzero(persony)), int(np.count_nonzero(ghosty))
    if ghost and background_std is not None and params.motion_factor > 0:
        # the camera's noise: the spread's median over the image (every 4th pixel: the same median)
        noise = float(np.median(background_std[::4, ::4]))
        spread = np.asarray(background_std[y0:y1, x0:x1])[outline]
        moved = int(np.count_nonzero(ghosty & (spread > params.motion_factor * noise)))
        # the hull only when it could count more votes than the spread did (every frame: the hot path)
        apart = 0
        if moved < ghost:
            hull = _hull(outline, persony)
            away = ghosty & ~_within(hull, outline, 2)
            if params.notch_margin > 0 and away.any():
                height = bh
                notch = _short_runs(m[y0:y1, x0:x1], outline, persony, params.notch_run * height)
                near = _within(hull, outline, max(2, round(params.notch_margin * height)))
                away &= ~(notch & near)
            apart = int(np.count_nonzero(away))
        ghost = max(moved, apart)
    return ghost / (ghost + person) if ghost + person else 0.0


def _hull(outline: NDArray[np.bool_], votes: NDArray[np.bool_]) -> NDArray[np.uint8] | None:
    """``(h, w) uint8``: the convex hull of the ``outline``'s pixels voting ``votes`` ((N,) bool),
    filled; None with fewer than three votes. :func:`_within` tells which outline pixels it holds.

    A wider margin (8 % of the outline's height) kept a very noisy camera's sparse person votes
    from leaving a piece of a camouflaged shirt outside, but hid the ghost of a person stepping
    away while it still touched them (poses published 1.3 m off)."""
    if int(np.count_nonzero(votes)) < 3:
        return None
    ys, xs = np.nonzero(outline)
    pts = np.stack([xs[votes], ys[votes]], axis=1).astype(np.int32)
    hull = np.zeros(outline.shape, np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(pts), 1)
    return hull


def _within(hull: NDArray[np.uint8] | None, outline: NDArray[np.bool_], margin: int) -> NDArray[np.bool_]:
    """(N,) bool: which of the ``outline``'s ``N`` pixels lie within ``margin`` pixels of ``hull``
    (:func:`_hull`; None holds none)."""
    ys, xs = np.nonzero(outline)
    if hull is None:
        return np.zeros(len(ys), bool)
    inside = np.asarray(cv2.dilate(hull, np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)))
    return np.asarray(inside[ys, xs] > 0, bool)


def _short_runs(mask: NDArray[np.uint8], outline: NDArray[np.bool_], person: NDArray[np.bool_],
                longest: float) -> NDArray[np.bool_]:
    """(N,) bool: which of the ``outline``'s ``N`` pixels lie on a stretch of the silhouette's contour
    between two *person* votes (``person``, (N,) bool) less than ``longest`` contour pixels apart."""
    h, w = outline.shape
    oy, ox = np.nonzero(outline)
    voted = np.zeros((h, w), bool)
    voted[oy[person], ox[person]] = True
    short = np.zeros((h, w), bool)
    contours, _ = cv2.findContours(mask, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    for c in contours:
        pts = c[:, 0, :]
        hit = voted[pts[:, 1], pts[:, 0]]
        if int(np.count_nonzero(hit)) < 2:
            continue
        # each point's previous and next person vote along the closed contour
        n, idx = len(pts), np.arange(len(pts))
        first, last = int(np.argmax(hit)), n - 1 - int(np.argmax(hit[::-1]))
        prev = np.maximum.accumulate(np.where(hit, idx, last - n))
        nxt = np.minimum.accumulate(np.where(hit, idx, first + n)[::-1])[::-1]
        inside = ~hit & (nxt - prev < longest)
        short[pts[inside, 1], pts[inside, 0]] = True
    return np.asarray(short[oy, ox], bool)
