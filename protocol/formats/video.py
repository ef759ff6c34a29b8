"""Video files a web browser plays: H.264 in MP4 (yuv420p, even frame sizes), or an animated GIF.

The MP4 is encoded in-process with PyAV (``av``), whose wheels carry their own FFmpeg with libx264,
so nothing has to be installed on the system. The ``moov`` atom is written at the front of the file
(``+faststart``), so a browser starts playing before the whole file arrived. A frame of odd width or
height is padded by one row / column (copies of the last), since 4:2:0 chroma needs even sizes.
A path ending in ``.gif`` writes an animated GIF instead (through imageio's Pillow plugin).

::

    with VideoWriter("out.mp4", fps=30) as video:
        for frame in frames:          # (H, W, 3) uint8 BGR, all of the same size
            video.write(frame)

:func:`video_info` reads back a file's codec, pixel format, size and frame count (for tests and tools).
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["GifFrames", "VideoInfo", "VideoWriter", "even_frame", "read_frames", "video_info"]


def even_frame(frame: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """``frame`` (H, W, 3) padded to even H and W by repeating its last row / column."""
    h, w = frame.shape[:2]
    ph, pw = h % 2, w % 2
    if not (ph or pw):
        return frame
    return np.pad(frame, ((0, ph), (0, pw), (0, 0)), mode="edge")


def _rate(fps: float) -> Fraction:
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be positive, got {fps}")
    return Fraction(fps).limit_denominator(1001)


class VideoWriter:
    """Write BGR frames to an H.264 MP4 (or, for a ``.gif`` path, an animated GIF).

    Parameters
    ----------
    path : str or Path
        Output file; its folder is created. ``*.gif``: a GIF; anything else: H.264 in the
        container the suffix names (``.mp4`` for browsers).
    fps : float
        Frame rate.
    crf : int
        x264 constant rate factor (lower: better and bigger; 18-23 is visually near lossless).
    preset : str
        x264 speed preset.

    The frame size is taken from the first frame; later frames must have the same size.
    """

    def __init__(self, path: str | Path, fps: float, *, crf: int = 20, preset: str = "veryfast") -> None:
        self.path = Path(path)
        self.fps = float(fps)
        self.rate = _rate(self.fps)
        self.crf = int(crf)
        self.preset = preset
        self.gif = self.path.suffix.lower() == ".gif"
        self.frames = 0
        self.size: tuple[int, int] | None = None  # (width, height) of the input frames
        self._container: Any = None
        self._stream: Any = None
        self._gif: Any = None
        self._closed = False
        self.path.parent.mkdir(parents=True, exist_ok=True)

    # ------------------------------------------------------------------ context manager

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    # ------------------------------------------------------------------------- writing

    def _open(self, width: int, height: int) -> None:
        if self.gif:
            import imageio.v3 as iio

            self._gif = iio.imopen(self.path, "w", plugin="pillow")
            return
        import av

        container = av.open(str(self.path), mode="w", options={"movflags": "+faststart"})
        try:
            stream = container.add_stream("libx264", rate=self.rate)
            stream.width, stream.height = width + width % 2, height + height % 2
            stream.pix_fmt = "yuv420p"
            stream.options = {"crf": str(self.crf), "preset": self.preset}
        except Exception:
            container.close()
            raise
        self._container, self._stream = container, stream

    def write(self, frame_bgr: NDArray[np.uint8]) -> None:
        """Append one (H, W, 3) uint8 BGR frame (a (H, W) grey frame is accepted too)."""
        if self._closed:
            raise ValueError(f"{self.path}: the video is closed")
        f = np.asarray(frame_bgr)
        if f.ndim == 2:
            f = np.repeat(f[:, :, None], 3, axis=2)
        if f.ndim != 3 or f.shape[2] != 3:
            raise ValueError(f"frames must be (H, W, 3) BGR, got shape {f.shape}")
        if f.dtype != np.uint8:
            f = np.clip(f, 0, 255).astype(np.uint8)
        h, w = f.shape[:2]
        if self.size is None:
            if h < 2 or w < 2:
                raise ValueError(f"frame too small: {w}x{h}")
            self._open(w, h)
            self.size = (w, h)
        elif self.size != (w, h):
            raise ValueError(f"frame size {w}x{h} differs from the video's {self.size[0]}x{self.size[1]}")
        f = even_frame(np.ascontiguousarray(f))
        if self.gif:
            self._gif.write(np.ascontiguousarray(f[:, :, ::-1]), is_batch=False,
                            duration=1000.0 / self.fps, loop=0)
        else:
            import av

            vf = av.VideoFrame.from_ndarray(f, format="bgr24")
            vf.pts = self.frames
            vf.time_base = 1 / self.rate
            for packet in self._stream.encode(vf):
                self._container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        """Flush the encoder and close the file (again: nothing). A video without frames leaves no file."""
        if self._closed:
            return
        self._closed = True
        if self._gif is not None:
            self._gif.close()
        if self._container is not None:
            try:
                for packet in self._stream.encode(None):
                    self._container.mux(packet)
            finally:
                self._container.close()


class GifFrames:
    """A GIF's frames gathered in bounded memory: when ``max_frames`` are held, every second one is
    dropped and from then on only every :attr:`step`-th frame offered is kept, so a session of any
    length holds fewer than ``max_frames`` images, evenly spaced (a GIF is encoded only at the end;
    keeping every frame of a 10-minute session at 10 frames a second held 3 GB).

    Parameters
    ----------
    max_frames : int
        At least 2.
    """

    def __init__(self, max_frames: int = 400) -> None:
        self.max_frames = max(int(max_frames), 2)
        self.frames: list[NDArray[np.uint8]] = []
        self.step = 1
        self._offered = 0

    def add(self, frame: NDArray[np.uint8]) -> None:
        """Offer the next frame (kept when it falls on the current step)."""
        if self._offered % self.step == 0:
            self.frames.append(frame)
            if len(self.frames) >= self.max_frames:
                self.frames = self.frames[::2]
                self.step *= 2
        self._offered += 1

    def duration_s(self, fps: float) -> float:
        """How long each kept frame shows for frames offered at ``fps``."""
        return self.step / float(fps)


@dataclass(frozen=True)
class VideoInfo:
    """What :func:`video_info` reads from a video file."""

    codec: str
    pix_fmt: str | None
    width: int
    height: int
    frames: int
    fps: float


def video_info(path: str | Path) -> VideoInfo:
    """Codec name (``h264``, ``gif``, ...), pixel format, size, decoded frame count and rate of the
    first video stream of ``path``."""
    import av

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        n = sum(1 for _ in container.decode(stream))
        rate = stream.average_rate or stream.guessed_rate
        return VideoInfo(codec=stream.codec_context.name, pix_fmt=stream.codec_context.pix_fmt,
                         width=int(stream.codec_context.width), height=int(stream.codec_context.height),
                         frames=n, fps=float(rate) if rate else float("nan"))


def read_frames(path: str | Path) -> list[NDArray[np.uint8]]:
    """Every frame of the first video stream of ``path`` as (H, W, 3) uint8 BGR."""
    import av

    with av.open(str(path)) as container:
        return [np.asarray(f.to_ndarray(format="bgr24"), dtype=np.uint8)
                for f in container.decode(container.streams.video[0])]
