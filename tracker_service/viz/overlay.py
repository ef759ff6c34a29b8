"""The tracker's overlay on a camera frame: the silhouette (tinted), the published joints projected
through the camera and joined along :data:`protocol.skeleton.PARENTS` (the subject's left in one
colour, the right in another), and a small HUD (phase, frames per second, confidence).

:func:`draw_overlay` draws one frame; :class:`OverlayVideo` writes the overlay of every frame the
daemon or the evaluation processes to a video (``mocap-tracker run/eval --video OUT.mp4``), through
their per-frame hooks.
"""

from __future__ import annotations

from collections import deque
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.skeleton import JOINT_NAMES, PARENTS

if TYPE_CHECKING:
    from protocol.formats.video import VideoWriter

__all__ = ["FrameOutcome", "Hud", "OverlayVideo", "Projector", "draw_overlay", "hud_lines"]

#: BGR colours: the silhouette tint, the subject's left side, right side and midline.
SILHOUETTE_BGR = (90, 210, 90)
LEFT_BGR = (60, 200, 255)
RIGHT_BGR = (255, 120, 60)
MID_BGR = (230, 230, 230)


class Projector(Protocol):
    """What the overlay needs of a camera (:class:`tracker_service.camera.Camera`)."""

    @property
    def width(self) -> int: ...

    @property
    def height(self) -> int: ...

    def project(self, points: ArrayLike) -> NDArray[np.float64]: ...


class FrameOutcome(Protocol):
    """What the overlay reads of a :class:`~tracker_service.pipeline.process.FrameResult`."""

    @property
    def phase(self) -> Any: ...

    @property
    def silhouette(self) -> NDArray[np.bool_] | None: ...

    @property
    def joints(self) -> NDArray[np.float64] | None: ...

    @property
    def confidence(self) -> float: ...

    @property
    def stage_ms(self) -> dict[str, float]: ...


class Hud(dict[str, str]):
    """The HUD's lines, label -> text, in order."""


def hud_lines(phase: str, fps: float | None, confidence: float | None) -> Hud:
    """The standard HUD: phase, frames per second (None: not known yet) and the match confidence
    (None: no pose)."""
    return Hud(phase=str(phase), fps="-" if fps is None or not np.isfinite(fps) else f"{fps:.1f}",
               conf="-" if confidence is None else f"{confidence:.2f}")


def _side_colour(j: int) -> tuple[int, int, int]:
    name = JOINT_NAMES[j]
    return LEFT_BGR if name.startswith("l_") else RIGHT_BGR if name.startswith("r_") else MID_BGR


def _tint(out: NDArray[np.uint8], silhouette: NDArray[np.bool_], alpha: float) -> None:
    sil = np.asarray(silhouette, dtype=bool)
    h, w = out.shape[:2]
    if sil.shape != (h, w):
        sil = cv2.resize(sil.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)
    if not sil.any():
        return
    colour = np.asarray(SILHOUETTE_BGR, dtype=np.float32)
    px = out[sil].astype(np.float32)
    out[sil] = np.clip((1.0 - alpha) * px + alpha * colour, 0, 255).astype(np.uint8)
    contours, _ = cv2.findContours(sil.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(out, contours, -1, SILHOUETTE_BGR, 1, cv2.LINE_AA)


def _skeleton(out: NDArray[np.uint8], uv: NDArray[np.float64], thickness: int) -> None:
    ok = np.all(np.isfinite(uv), axis=1)
    pts = np.round(np.where(ok[:, None], uv, 0.0)).astype(np.int64)
    big = 4 * max(out.shape[:2])
    pts = np.clip(pts, -big, big)  # cv2 wants ints in range; lines to far points are clipped by it
    for j, par in enumerate(PARENTS):
        if par >= 0 and ok[j] and ok[par]:
            cv2.line(out, (int(pts[par, 0]), int(pts[par, 1])), (int(pts[j, 0]), int(pts[j, 1])),
                     _side_colour(j), thickness, cv2.LINE_AA)
    for j in range(len(PARENTS)):
        if ok[j]:
            cv2.circle(out, (int(pts[j, 0]), int(pts[j, 1])), thickness + 1, _side_colour(j), -1, cv2.LINE_AA)


def _hud(out: NDArray[np.uint8], hud: dict[str, str]) -> None:
    if not hud:
        return
    h = out.shape[0]
    scale = max(0.35, h / 600.0)
    lines = [f"{k}: {v}" for k, v in hud.items()]
    sizes = [cv2.getTextSize(t, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0] for t in lines]
    line_h = max(s[1] for s in sizes) + max(4, int(6 * scale))
    box_w = max(s[0] for s in sizes) + 10
    box_h = line_h * len(lines) + 6
    x0, y0 = 4, 4
    region = out[y0: y0 + box_h, x0: x0 + box_w]
    region[:] = (region.astype(np.float32) * 0.4).astype(np.uint8)  # darkened box behind the text
    for k, text in enumerate(lines):
        cv2.putText(out, text, (x0 + 5, y0 + 3 + line_h * (k + 1) - max(2, int(3 * scale))),
                    cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA)


def draw_overlay(image: NDArray[np.uint8], camera: Projector, *, joints: ArrayLike | None = None,
                 silhouette: NDArray[np.bool_] | None = None, hud: dict[str, str] | None = None,
                 alpha: float = 0.45) -> NDArray[np.uint8]:
    """The camera frame with the tracker's view drawn on it (a new array; ``image`` is not changed).

    Parameters
    ----------
    image : (H, W, 3) uint8 BGR
    camera : Projector
        The camera the joints are projected through; a frame of another size than the camera's
        gets the projection scaled to it.
    joints : (J, 3) float, optional
        World joint positions (metres), order :data:`protocol.skeleton.JOINT_NAMES`.
    silhouette : (h, w) bool, optional
        Foreground mask (resized to the frame when its size differs).
    hud : dict[str, str], optional
        HUD lines (:func:`hud_lines`).
    alpha : float
        Opacity of the silhouette tint.
    """
    out = np.array(image, dtype=np.uint8, copy=True)
    if out.ndim == 2:
        out = np.repeat(out[:, :, None], 3, axis=2)
    if silhouette is not None:
        _tint(out, silhouette, alpha)
    if joints is not None:
        j = np.asarray(joints, dtype=np.float64)
        uv = np.asarray(camera.project(j), dtype=np.float64).reshape(-1, 2)
        h, w = out.shape[:2]
        if (w, h) != (camera.width, camera.height):
            uv = uv * np.array([w / camera.width, h / camera.height])
        _skeleton(out, uv, thickness=max(1, round(min(h, w) / 240)))
    _hud(out, hud or {})
    return out


class OverlayVideo:
    """The overlay of every processed frame, written to a video (:class:`protocol.formats.video.VideoWriter`).

    Call it as the daemon's or the evaluation's per-frame hook: ``video(image, result)``. The HUD's
    frames per second are the pipeline's, from the mean ``stage_ms['total']`` of the last 30 frames.

    Parameters
    ----------
    path : str or Path
        ``*.mp4`` (H.264) or ``*.gif``.
    camera : Projector
    fps : float
        The video's frame rate (the source's).
    """

    def __init__(self, path: str | Path, camera: Projector, fps: float = 30.0) -> None:
        from protocol.formats.video import VideoWriter

        self.camera = camera
        self.writer: VideoWriter = VideoWriter(path, fps)
        self._ms: deque[float] = deque(maxlen=30)

    def __enter__(self) -> OverlayVideo:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    @property
    def frames(self) -> int:
        return self.writer.frames

    def __call__(self, image: NDArray[np.uint8], result: FrameOutcome | None) -> None:
        """Draw ``result`` (None: a frame the pipeline could not use: the bare frame) on ``image``
        and append it."""
        if result is None:
            self.writer.write(draw_overlay(image, self.camera, hud=hud_lines("skipped", None, None)))
            return
        total = result.stage_ms.get("total")
        if total is not None and total > 0:
            self._ms.append(float(total))
        fps = 1000.0 / float(np.mean(self._ms)) if self._ms else None
        has_pose = result.joints is not None
        frame = draw_overlay(image, self.camera, joints=result.joints, silhouette=result.silhouette,
                             hud=hud_lines(str(result.phase), fps, result.confidence if has_pose else None))
        self.writer.write(frame)

    def close(self) -> None:
        self.writer.close()
