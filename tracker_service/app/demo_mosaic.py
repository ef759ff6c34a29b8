"""The pieces of ``mocap-tracker demo`` that do not talk to processes: the synthetic scene's ground
truth, the gesture score, the 3D skeleton view and the mosaic video.

The mosaic has one frame per tracker frame (the tracker's own overlay video, ``run --video``):

* top left, the camera frame with the silhouette and the projected skeleton (the tracker's overlay);
* top right, an orthographic front and side view of the published 3D skeleton (the ground truth
  in grey where known);
* bottom left, the game client's view and bottom right the cloth client's view, each the newest
  frame that client had written (its own ``--frames-out`` PNGs, by file time) when that tracker
  frame was published, so a client that lags shows its lag;
* a HUD strip: stream time, tracker / game / cloth frames per second, the latency of that frame
  and the gestures as they fire.

Frames are aligned by wall-clock time: each tracker frame ``i`` (capture time ``i / fps``) is
placed at the publication time of its ``PoseFrame`` (interpolated for frames without a pose),
and the client frames at the time their file was written.
"""

from __future__ import annotations

import bisect
import math
import os
import tomllib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import JOINT_NAMES, PARENTS

__all__ = ["EMPTY_PREFIX", "ClientFrames", "GestureSeen", "MosaicInputs", "PoseSeen", "ground_truth",
           "match_gestures", "mpjpe_cm", "percentile", "performed_gestures", "skeleton_view", "write_mosaic"]

#: Empty-room frames the synthetic source plays before the person appears (``open_source``'s default).
EMPTY_PREFIX = 15
TILE = (480, 360)  # (width, height) of one mosaic tile
HUD_H = 44
_GREY = (150, 150, 150)
_LEFT, _RIGHT, _MID = (60, 200, 255), (255, 120, 60), (230, 230, 230)


@dataclass(frozen=True)
class PoseSeen:
    """One pose the demo's subscriber received: seq, capture time (stream s), publication and
    receipt (Unix s), joints (24, 3), latency (capture to receipt, ms)."""

    seq: int
    capture_ts: float
    publish_ts: float
    recv_ts: float
    joints: NDArray[np.float32]
    latency_ms: float


@dataclass(frozen=True)
class GestureSeen:
    """A gesture event of the game client: gesture, direction, end (stream s), when it fired
    (stream s) and its confidence."""

    gesture: str
    direction: str
    end_s: float
    stream_ts: float
    confidence: float


# ------------------------------------------------------------------------------ ground truth


def ground_truth(script: Path, seed: int = 0, empty_prefix: int = EMPTY_PREFIX) -> tuple[float, NDArray[np.float64]]:
    """The synthetic scene's true joints without rendering anything: ``(fps, joints)`` with
    ``joints[k]`` (24, 3) the person's joints at capture time ``(k + empty_prefix) / fps``.

    Rebuilds what :class:`~tracker_service.scene.synthetic.SyntheticScene` does with ``seed`` (the
    same random person, motion retargeted, placed and grounded), without its EGL renderer."""
    from protocol.formats.load import load_motion
    from protocol.kinematics import fk_global
    from protocol.motion import ground
    from tracker_service.scene.subject import build_subject, random_subject_spec
    from tracker_service.scene.synthetic import SceneConfig, place_motion

    cfg = SceneConfig(empty_prefix=empty_prefix)
    body = build_subject(random_subject_spec(np.random.default_rng([int(seed), 0]))).body
    motion = load_motion(script, body=body)
    placed = place_motion(motion.poses, face_camera=cfg.face_camera, in_place=cfg.in_place)
    poses = ground(placed, body)
    joints, _ = fk_global(poses, body)
    return float(motion.fps), np.asarray(joints, dtype=np.float64)


def mpjpe_cm(poses: Sequence[PoseSeen], fps: float, truth: NDArray[np.float64],
             empty_prefix: int = EMPTY_PREFIX) -> float | None:
    """Mean root-relative joint error (cm) of the received poses against the truth (as
    ``mocap-tracker eval`` scores it); None when no pose falls on a truth frame."""
    errs = []
    for p in poses:
        k = round(p.capture_ts * fps) - empty_prefix
        if 0 <= k < len(truth):
            je, jt = np.asarray(p.joints, np.float64), truth[k]
            errs.append(float(np.linalg.norm((je - je[0]) - (jt - jt[0]), axis=1).mean()))
    return round(100.0 * float(np.mean(errs)), 2) if errs else None


# ---------------------------------------------------------------------------------- gestures


def performed_gestures(script: Path, labels: Path | None = None) -> list[dict[str, Any]] | None:
    """The gestures a bundled script performs (``game_client/scripts/labels.toml``), or None if
    the script is not labelled."""
    labels = labels or Path(__file__).resolve().parents[2] / "game_client" / "scripts" / "labels.toml"
    try:
        table = tomllib.loads(labels.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError):
        return None
    entry = table.get(Path(script).stem)
    return None if entry is None else list(entry.get("gestures", []))


def match_gestures(performed: Sequence[dict[str, Any]], seen: Sequence[GestureSeen], offset_s: float,
                   tolerance_s: float = 1.0) -> list[bool]:
    """For each performed gesture (label ``end_s`` in motion time; ``offset_s`` added gives stream
    time), whether an unused recognised gesture of the same kind (and side-step direction) ended
    within ``tolerance_s`` of it."""
    used: set[int] = set()
    out = []
    for lab in performed:
        end = float(lab["end_s"]) + offset_s
        hit = next((i for i, g in enumerate(seen) if i not in used and g.gesture == lab["gesture"]
                    and (not lab.get("direction") or g.direction == lab["direction"])
                    and abs(g.end_s - end) <= tolerance_s), None)
        if hit is not None:
            used.add(hit)
        out.append(hit is not None)
    return out


# ------------------------------------------------------------------------------ 3D skeleton


def _colour(j: int) -> tuple[int, int, int]:
    name = JOINT_NAMES[j]
    return _LEFT if name.startswith("l_") else _RIGHT if name.startswith("r_") else _MID


def _draw_bones(img: NDArray[np.uint8], pts: NDArray[np.float64], grey: bool, thick: int) -> None:
    for j, p in enumerate(PARENTS):
        if p < 0 or not (np.all(np.isfinite(pts[j])) and np.all(np.isfinite(pts[p]))):
            continue
        a = (round(float(pts[p, 0])), round(float(pts[p, 1])))
        b = (round(float(pts[j, 0])), round(float(pts[j, 1])))
        cv2.line(img, a, b, _GREY if grey else _colour(j), thick, cv2.LINE_AA)


def skeleton_view(joints: NDArray[Any] | None, truth: NDArray[Any] | None = None,
                  size: tuple[int, int] = TILE) -> NDArray[np.uint8]:
    """Orthographic front (X-Y) and side (Z-Y) views of a skeleton (24, 3), metres, Y up, on a
    floor grid; the truth (same frame) in grey behind it. Each is centred horizontally on its own
    pelvis (the errors are root-relative); the floor (y = 0) at a fixed height."""
    w, h = size
    img = np.full((h, w, 3), 28, np.uint8)
    half = w // 2
    scale = (h - 60) / 2.1  # pixels per metre: 2.1 m from the floor to the top
    floor = h - 30
    cv2.line(img, (half, 8), (half, h - 8), (70, 70, 70), 1)
    for col, (label, axis) in enumerate((("front (x-y)", 0), ("side (z-y)", 2))):
        cx = half * col + half // 2
        cv2.putText(img, label, (half * col + 8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (200, 200, 200), 1, cv2.LINE_AA)
        for gx in range(-3, 4):
            x = int(cx + gx * 0.5 * scale)
            cv2.line(img, (x, floor), (x, floor + 6), (90, 90, 90), 1)
        cv2.line(img, (half * col + 10, floor), (half * col + half - 10, floor), (90, 90, 90), 1)
        sign = 1.0 if axis == 0 else -1.0  # side view: the camera (+Z) on the left
        for pts3, grey in ((truth, True), (joints, False)):
            if pts3 is None:
                continue
            p = np.asarray(pts3, np.float64)  # each centred on its own pelvis (errors are root-relative)
            uv = np.stack([cx + sign * (p[:, axis] - p[0, axis]) * scale, floor - p[:, 1] * scale], axis=1)
            _draw_bones(img, uv, grey, 2 if grey else 3)
    if joints is None:
        cv2.putText(img, "no pose yet", (w // 2 - 60, h // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (200, 200, 200), 1,
                    cv2.LINE_AA)
    return img


# ------------------------------------------------------------------------------ client frames


@dataclass
class ClientFrames:
    """The PNG frames a client wrote into ``folder``, by the time they were written."""

    folder: Path | None
    times: list[float] = field(default_factory=list)
    paths: list[Path] = field(default_factory=list)
    _cache: tuple[Path | None, NDArray[np.uint8] | None] = (None, None)

    def __post_init__(self) -> None:
        if self.folder is None or not self.folder.is_dir():
            return
        files = sorted((os.stat(p).st_mtime, p) for p in self.folder.glob("frame_*.png"))
        self.times = [t for t, _ in files]
        self.paths = [p for _, p in files]

    def __len__(self) -> int:
        return len(self.paths)

    def at(self, wall: float) -> NDArray[np.uint8] | None:
        """The newest frame written by ``wall`` (Unix s), or None."""
        k = bisect.bisect_right(self.times, wall) - 1
        if k < 0:
            return None
        path = self.paths[k]
        if self._cache[0] != path:
            img = cv2.imread(str(path), cv2.IMREAD_COLOR)
            self._cache = (path, None if img is None else np.asarray(img, np.uint8))
        return self._cache[1]


def _fit(img: NDArray[np.uint8] | None, size: tuple[int, int], label: str) -> NDArray[np.uint8]:
    """``img`` scaled into a tile of ``size`` (letterboxed), or a placeholder saying ``label``."""
    w, h = size
    tile = np.full((h, w, 3), 18, np.uint8)
    if img is None:
        cv2.putText(tile, label, (16, h // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (180, 180, 180), 1, cv2.LINE_AA)
        return tile
    ih, iw = img.shape[:2]
    s = min(w / iw, h / ih)
    nw, nh = max(1, int(iw * s)), max(1, int(ih * s))
    small = cv2.resize(img, (nw, nh), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
    x0, y0 = (w - nw) // 2, (h - nh) // 2
    tile[y0:y0 + nh, x0:x0 + nw] = small
    return tile


def _caption(tile: NDArray[np.uint8], text: str) -> None:
    (tw, _), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.42, 1)
    cv2.rectangle(tile, (0, tile.shape[0] - 20), (8 + tw, tile.shape[0]), (0, 0, 0), -1)
    cv2.putText(tile, text, (4, tile.shape[0] - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (235, 235, 235), 1, cv2.LINE_AA)


# ---------------------------------------------------------------------------------- mosaic


@dataclass
class MosaicInputs:
    """What :func:`write_mosaic` composes."""

    overlay: Path  # the tracker's overlay video (one frame per input frame, capture time i / fps)
    fps: float
    poses: list[PoseSeen]
    gestures: list[GestureSeen]
    game: ClientFrames
    cloth: ClientFrames
    truth: NDArray[np.float64] | None = None
    empty_prefix: int = EMPTY_PREFIX
    slack_s: float = 0.05  # a client frame written this long after the tracker frame still counts


def _frames(path: Path) -> Iterator[NDArray[np.uint8]]:
    import av

    with av.open(str(path)) as container:
        for f in container.decode(container.streams.video[0]):
            yield np.asarray(f.to_ndarray(format="bgr24"), dtype=np.uint8)


def _wall_clock(poses: Sequence[PoseSeen]) -> Any:
    """capture time -> publication time, interpolated between poses, slope 1 outside them."""
    if not poses:
        return lambda t: float("nan")
    ct = np.array([p.capture_ts for p in poses])
    pt = np.array([p.publish_ts for p in poses])

    def wall(t: float) -> float:
        if t < ct[0]:
            return float(pt[0] - (ct[0] - t))
        if t > ct[-1]:
            return float(pt[-1] + (t - ct[-1]))
        return float(np.interp(t, ct, pt))
    return wall


def _hud(width: int, t: float, fps: dict[str, float], latency: float | None,
         recent: list[GestureSeen], fired: list[str]) -> NDArray[np.uint8]:
    bar = np.full((HUD_H, width, 3), 12, np.uint8)
    lat = "-" if latency is None else f"{latency:.0f} ms"
    line = (f"t={t:6.2f} s   tracker {fps['tracker']:4.1f} fps   game view {fps['game']:4.1f} fps   "
            f"cloth view {fps['cloth']:4.1f} fps   latency {lat}")
    cv2.putText(bar, line, (8, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (230, 230, 230), 1, cv2.LINE_AA)
    cv2.putText(bar, "gestures: " + (", ".join(fired[-6:]) or "-"), (8, 37), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                (160, 220, 160), 1, cv2.LINE_AA)
    if recent:
        g = recent[-1]
        text = f"{g.gesture.upper().replace('_', ' ')}{' ' + g.direction if g.direction else ''}!"
        cv2.putText(bar, text, (width - 260, 32), cv2.FONT_HERSHEY_DUPLEX, 0.9, (60, 230, 255), 2, cv2.LINE_AA)
    return bar


def _rate(times: Sequence[float], now: float, window: float = 2.0) -> float:
    lo = bisect.bisect_left(times, now - window)
    hi = bisect.bisect_right(times, now)
    n = hi - lo
    if n < 2:
        return 0.0
    span = times[hi - 1] - times[lo]
    return (n - 1) / span if span > 0 else 0.0


def write_mosaic(inputs: MosaicInputs, out: Path) -> int:
    """Compose the mosaic of every tracker frame into ``out`` (H.264 MP4, ``inputs.fps``);
    returns the number of frames written."""
    from protocol.formats.video import VideoWriter

    by_t = {round(p.capture_ts * inputs.fps): p for p in inputs.poses}
    wall = _wall_clock(inputs.poses)
    pub_times = sorted(p.publish_ts for p in inputs.poses)
    game_times, cloth_times = inputs.game.times, inputs.cloth.times
    events = sorted(inputs.gestures, key=lambda g: g.stream_ts)
    last: PoseSeen | None = None
    n = 0
    with VideoWriter(out, inputs.fps) as video:
        for i, frame in enumerate(_frames(inputs.overlay)):
            t = i / inputs.fps
            w = wall(t) + inputs.slack_s
            pose = by_t.get(i)
            if pose is not None:
                last = pose
            k = i - inputs.empty_prefix
            truth = inputs.truth[k] if inputs.truth is not None and 0 <= k < len(inputs.truth) else None
            cam = _fit(frame, TILE, "")
            _caption(cam, "camera + silhouette + projected skeleton (tracker)")
            skel = skeleton_view(None if last is None else last.joints, truth)
            _caption(skel, "3D skeleton (colour: tracked, grey: truth)")
            game = _fit(inputs.game.at(w), TILE, "game: waiting for its first frame")
            _caption(game, "game client view")
            cloth = _fit(inputs.cloth.at(w), TILE, "cloth: waiting for its first frame")
            _caption(cloth, "cloth client view")
            fps = {"tracker": _rate(pub_times, w), "game": _rate(game_times, w), "cloth": _rate(cloth_times, w)}
            fired = [g for g in events if g.stream_ts <= t]
            recent = [g for g in fired if t - g.stream_ts < 1.5]
            names = [g.gesture + (f" {g.direction}" if g.direction else "") for g in fired]
            hud = _hud(2 * TILE[0], t, fps, None if last is None else last.latency_ms, recent, names)
            video.write(np.vstack([hud, np.hstack([cam, skel]), np.hstack([game, cloth])]))
            n += 1
    return n


def percentile(values: Sequence[float], q: float) -> float | None:
    """The ``q``-th percentile of ``values`` rounded to 0.1, or None if empty."""
    if not values:
        return None
    v = float(np.percentile(np.asarray(values, np.float64), q))
    return round(v, 1) if math.isfinite(v) else None
