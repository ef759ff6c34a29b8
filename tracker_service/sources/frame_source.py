"""Frame sources behind one interface: iterate ``(timestamp, frame)`` pairs.

``synthetic[:FILE]``  the built-in synthetic scene (default motion: a shipped gesture script)
``camera[:INDEX]``    a camera through OpenCV, retried when it disappears
``video:PATH``        a video file
``frames:DIR``        a folder of images, in name order

A broken or missing frame is skipped and counted (``counters["bad_frames"]``); input problems
never raise out of the iterator, except a source that cannot be opened at all
(:class:`SourceError`, raised by :func:`open_source`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from tracker_service.camera import fit_box

__all__ = ["FrameSource", "SourceError", "SourceSpec", "fit_frame", "open_source", "parse_source"]

log = logging.getLogger(__name__)

_IMAGE_EXT = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm"}


class SourceError(RuntimeError):
    """A source that cannot be opened (the message names it)."""


@dataclass(frozen=True)
class SourceSpec:
    """A parsed ``--source`` value."""

    kind: str
    arg: str = ""


def parse_source(text: str) -> SourceSpec:
    """Parse ``synthetic[:FILE]``, ``camera[:INDEX]``, ``video:PATH`` or ``frames:DIR``.

    Raises
    ------
    ValueError
        Unknown kind or missing argument.
    """
    kind, _, arg = text.partition(":")
    kind = kind.strip().lower()
    if kind not in ("synthetic", "camera", "video", "frames"):
        raise ValueError(f"unknown source {text!r}: use synthetic[:FILE], camera[:INDEX], video:PATH or frames:DIR")
    if kind in ("video", "frames") and not arg:
        raise ValueError(f"source {kind} needs a path: {kind}:PATH")
    if kind == "camera" and arg and not arg.isdigit():
        raise ValueError(f"camera index must be a number, got {arg!r}")
    return SourceSpec(kind, arg)


class FrameSource(Protocol):
    """What the tracker reads frames from."""

    counters: dict[str, int]

    def __iter__(self) -> Iterator[tuple[float, NDArray[np.uint8]]]: ...

    def close(self) -> None: ...


def _as_bgr(img: Any, size: tuple[int, int] | None) -> NDArray[np.uint8] | None:
    if img is None or not isinstance(img, np.ndarray) or img.size == 0:
        return None
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    elif img.ndim != 3 or img.shape[2] != 3:
        return None
    if img.dtype != np.uint8:  # 16-bit or float images: stretch to 8 bits
        f = img.astype(np.float64)
        lo, hi = float(f.min()), float(f.max())
        img = ((f - lo) * (255.0 / max(hi - lo, 1e-12))).astype(np.uint8)
    if size is not None and (img.shape[1], img.shape[0]) != size:
        img = fit_frame(img, size)
    return np.ascontiguousarray(img)


def fit_frame(img: NDArray[np.uint8], size: tuple[int, int]) -> NDArray[np.uint8]:
    """Bring a frame to the working size without changing its aspect: crop the centre with the
    aspect of ``size`` (a 16:9 frame loses its sides for a 4:3 working size), halve it by area
    averaging while it stays at least ``size`` (:func:`~tracker_service.camera.fit_box`), then scale
    the rest of the way bilinearly (less than a factor of two down, or up). A stretched frame would
    make every person wider or narrower than any template.

    Halving, not one area average by the whole factor, is for speed: OpenCV halves in one fast
    pass, while its area average by any other factor takes a general path that cost 5-7 ms a frame
    at 1280x720 and 10-16 ms at 1920x1080 on one core, 0.6 and 1.0 ms this way (docs/BENCHMARKS.md,
    "Frame sizes"). The crop first leaves the sides that are thrown away unread.

    Parameters
    ----------
    img : (h, w, 3) uint8
    size : (int, int)
        ``(width, height)`` of the result.

    Returns
    -------
    (height, width, 3) uint8
        The principal point stays at the centre and the pixels stay square (to the crop's whole
        pixels); the vertical field of view is kept when the input is wider than ``size``, the
        horizontal one when it is taller. :meth:`~tracker_service.camera.Camera.fitted` is the
        camera of the result.
    """
    W, H = int(size[0]), int(size[1])
    h, w = img.shape[:2]
    if (w, h) == (W, H):
        return img
    x0, y0, cw, ch, k = fit_box((w, h), (W, H))
    out: Any = img[y0:y0 + ch, x0:x0 + cw]
    while k > 1:
        out = cv2.resize(out, (out.shape[1] // 2, out.shape[0] // 2), interpolation=cv2.INTER_AREA)
        k //= 2
    if out.shape[1] != W or out.shape[0] != H:
        out = cv2.resize(out, (W, H), interpolation=cv2.INTER_LINEAR)
    return np.asarray(out, np.uint8)


@dataclass
class FolderSource:
    """Images of a folder in name order; unreadable files are skipped and counted."""

    folder: Path
    size: tuple[int, int] | None = None
    fps: float = 30.0
    counters: dict[str, int] = field(default_factory=lambda: {"frames": 0, "bad_frames": 0})

    def __post_init__(self) -> None:
        if not self.folder.is_dir():
            raise SourceError(f"frames folder not found: {self.folder}")
        self.files = sorted(p for p in self.folder.iterdir() if p.suffix.lower() in _IMAGE_EXT)
        if not self.files:
            raise SourceError(f"no images ({', '.join(sorted(_IMAGE_EXT))}) in {self.folder}")

    def __iter__(self) -> Iterator[tuple[float, NDArray[np.uint8]]]:
        for k, f in enumerate(self.files):
            img = _as_bgr(cv2.imread(str(f), cv2.IMREAD_UNCHANGED), self.size)
            if img is None:
                self.counters["bad_frames"] += 1
                log.warning("skipping unreadable image %s", f)
                continue
            self.counters["frames"] += 1
            yield k / self.fps, img

    def close(self) -> None:
        return None


@dataclass
class CaptureSource:
    """A cv2.VideoCapture (camera index or video file). A camera that stops delivering is
    reopened every ``retry_s`` seconds (counted in ``reconnects``) until ``stop`` is set."""

    target: int | str
    size: tuple[int, int] | None = None
    retry_s: float = 1.0
    max_retries: int | None = None
    counters: dict[str, int] = field(default_factory=lambda: {"frames": 0, "bad_frames": 0, "reconnects": 0})
    stopped: bool = False

    def __post_init__(self) -> None:
        self.is_camera = isinstance(self.target, int)
        if not self.is_camera and not Path(str(self.target)).is_file():
            raise SourceError(f"video file not found: {self.target}")
        self.cap = self._open()
        if self.cap is None:
            raise SourceError(f"cannot open {'camera' if self.is_camera else 'video'} {self.target}")
        fps = float(self.cap.get(cv2.CAP_PROP_FPS) or 0.0)
        self.fps = fps if 1.0 <= fps <= 240.0 else 30.0

    def _open(self) -> Any:
        cap = cv2.VideoCapture(self.target)
        if not cap.isOpened():
            cap.release()
            return None
        return cap

    def __iter__(self) -> Iterator[tuple[float, NDArray[np.uint8]]]:
        t0 = time.monotonic()
        k = 0
        misses = 0
        retries = 0
        while not self.stopped:
            ok, img = self.cap.read() if self.cap is not None else (False, None)
            frame = _as_bgr(img, self.size) if ok else None
            if frame is not None:
                misses = 0
                self.counters["frames"] += 1
                ts = (time.monotonic() - t0) if self.is_camera else k / self.fps
                k += 1
                yield ts, frame
                continue
            if not self.is_camera:
                if ok:  # decoded but unusable
                    self.counters["bad_frames"] += 1
                    continue
                return  # end of the video
            misses += 1
            self.counters["bad_frames"] += 1
            if misses >= 5:  # the camera is gone: reopen it
                if self.max_retries is not None and retries >= self.max_retries:
                    log.error("camera %s did not come back after %d retries", self.target, retries)
                    return
                log.warning("camera %s stopped delivering frames; reopening", self.target)
                if self.cap is not None:
                    self.cap.release()
                time.sleep(self.retry_s)
                self.cap = self._open()
                retries += 1
                self.counters["reconnects"] += 1
                misses = 0

    def close(self) -> None:
        self.stopped = True
        if self.cap is not None:
            self.cap.release()
            self.cap = None


@dataclass
class SyntheticSource:
    """Frames of the synthetic scene (the ground truth stays available in :attr:`last_truth`).

    With ``prerender`` every frame is rendered when the source is made, before tracking starts, as
    a camera delivers frames that cost the tracker nothing (``0.23 MB`` a frame at 320x240: 97 MB
    for the 14 s demo round); otherwise each is rendered when it is read (10-25 ms a frame on the
    tracker's own core)."""

    scene: Any  # tracker_service.scene.synthetic.SyntheticScene (imported lazily: it needs an EGL context)
    counters: dict[str, int] = field(default_factory=lambda: {"frames": 0, "bad_frames": 0})
    last_truth: Any = None

    size: tuple[int, int] | None = None  # (width, height) the frames are brought to (None: as rendered)
    prerender: bool = False
    _frames: list[Any] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.prerender:
            log.info("rendering the synthetic scene's %d frames before tracking", self.scene.n_frames)
            self._frames = [self._render(i) for i in range(self.scene.n_frames)]

    def _render(self, i: int) -> tuple[float, NDArray[np.uint8], Any]:
        f = self.scene.frame(i)
        image = f.image
        if self.size is not None and image.shape[1::-1] != self.size:
            image = fit_frame(image, self.size)
        return f.timestamp, image, f.truth

    def __iter__(self) -> Iterator[tuple[float, NDArray[np.uint8]]]:
        for i in range(self.scene.n_frames):
            ts, image, self.last_truth = self._frames[i] if self._frames is not None else self._render(i)
            self.counters["frames"] += 1
            yield ts, image

    def close(self) -> None:
        self.scene.close()


def open_source(spec: SourceSpec, size: tuple[int, int], *, default_motion: Path | None = None,
                seed: int = 0, empty_prefix: int = 15, loop: bool = False, camera: Any = None,
                fps: float | None = None, prerender: bool = False) -> FrameSource:
    """Open a frame source.

    Parameters
    ----------
    spec : SourceSpec
    size : (int, int)
        ``(width, height)`` every frame is resized to.
    default_motion : Path, optional
        Motion of ``synthetic`` without a file.
    seed : int
        Synthetic scene seed.
    empty_prefix : int
        Empty-room frames before the person appears (synthetic only).
    loop : bool
        Unused for now (reserved for looping sources).
    camera : Camera, optional
        The camera filming the synthetic scene (the one the tracker is told about); its frames are
        brought to ``size``. None: the paper's camera at ``size``.
    fps : float, optional
        The synthetic scene's frame rate, the motion resampled to it (None: the motion's own).
    prerender : bool
        Render every synthetic frame now, before tracking (:class:`SyntheticSource`).

    Raises
    ------
    SourceError
    """
    if spec.kind == "frames":
        return FolderSource(Path(spec.arg), size)
    if spec.kind == "video":
        return CaptureSource(spec.arg, size)
    if spec.kind == "camera":
        return CaptureSource(int(spec.arg or 0), size)
    from tracker_service.scene.synthetic import SceneConfig, SyntheticScene

    motion = Path(spec.arg) if spec.arg else default_motion
    if motion is None or not motion.is_file():
        raise SourceError(f"synthetic source: motion file not found: {motion}")
    try:
        scene = SyntheticScene.from_file(str(motion), seed=seed,
                                         config=SceneConfig(width=size[0], height=size[1], empty_prefix=empty_prefix,
                                                            camera=camera, fps=fps))
    except (OSError, ValueError) as e:
        raise SourceError(f"synthetic source: {e}") from None
    return SyntheticSource(scene, size=size, prerender=prerender)
