"""Drawing game frames for people to look at (OpenCV), and writing them as PNG, GIF and MP4.

:class:`Renderer` draws one frame from a :class:`~game_client.game.GameSnapshot`: the arena seen from
above on the left (lanes, the player's ninja at the bottom, the opponent at the top, every
projectile, the opponent's wind-up warning, hit flashes) and a panel on the right (health bars,
round clock, the last recognised gesture and game events, and a stick figure of the player's
pose as the camera sees it, mirrored so the player's left is on the left). :class:`FrameWriter`
saves frames at a fixed rate of game time as numbered PNGs plus ``round.gif`` (imageio) and
``round.mp4`` (H.264, :class:`protocol.formats.video.VideoWriter`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import cv2
import imageio.v3 as iio
import numpy as np
from numpy.typing import NDArray

from protocol.formats.video import VideoWriter
from protocol.skeleton import JOINT_INDEX, PARENTS

from .game import GameConfig, GameRecord, GameSnapshot, Phase

__all__ = ["FrameWriter", "Renderer"]

log = logging.getLogger(__name__)

# BGR colours
_BG, _FLOOR, _LANE = (32, 28, 26), (58, 52, 48), (80, 74, 70)
_PLAYER, _HUMAN, _OPP = (230, 160, 60), (170, 170, 170), (60, 60, 220)
_HIGH, _SIDE, _STRIKE, _RING = (40, 150, 255), (30, 80, 240), (250, 250, 250), (240, 230, 40)
_TEXT, _DIM, _GOOD, _BAD = (235, 235, 235), (150, 150, 150), (90, 210, 90), (80, 80, 240)
_FONT: Final[int] = cv2.FONT_HERSHEY_SIMPLEX
_LEFT_JOINTS: Final[frozenset[int]] = frozenset(i for n, i in JOINT_INDEX.items() if n.startswith("l_"))


@dataclass
class Renderer:
    """Draws game frames of ``size = (width, height)`` pixels (BGR ``uint8``)."""

    config: GameConfig = field(default_factory=GameConfig)
    size: tuple[int, int] = (480, 360)

    def __post_init__(self) -> None:
        h = self.size[1]
        self.arena_w = round(h * 0.8)
        c = self.config
        self.scale = min((self.arena_w - 20) / c.width, (h - 20) / c.depth)
        self.origin = (int((self.arena_w - self.scale * c.width) / 2), int(h - (h - self.scale * c.depth) / 2))

    def _px(self, x: float, y: float) -> tuple[int, int]:
        return round(self.origin[0] + x * self.scale), round(self.origin[1] - y * self.scale)

    def draw(self, snap: GameSnapshot, joints: NDArray[np.floating] | None = None, lines: list[str] | None = None,
             flash: set[str] | None = None) -> NDArray[np.uint8]:
        """One frame.

        Parameters
        ----------
        snap : GameSnapshot
        joints : (24, 3) float, optional
            The player's latest pose, drawn as a stick figure in the panel.
        lines : list of str, optional
            Recent events to list in the panel (newest last).
        flash : set of str, optional
            ``"player"`` and/or ``"opponent"``: who was just hit (drawn with a white halo).

        Returns
        -------
        (H, W, 3) uint8
        """
        w, h = self.size
        img = np.full((h, w, 3), _BG, dtype=np.uint8)
        self._arena(img, snap, flash or set())
        self._panel(img, snap, joints, lines or [])
        return img

    def _arena(self, img: NDArray[np.uint8], s: GameSnapshot, flash: set[str]) -> None:
        c, k = self.config, self.scale
        cv2.rectangle(img, self._px(0, c.depth), self._px(c.width, 0), _FLOOR, -1)
        for x in c.lanes:
            cv2.line(img, self._px(x, 0.2), self._px(x, c.depth - 0.2), _LANE, 1, cv2.LINE_AA)
        ox, oy = self._px(s.opponent_x, c.opponent_y)
        if s.telegraph:
            cv2.circle(img, (ox, oy), int(k * (c.opponent_radius + 0.35)), _HIGH if s.telegraph == "high" else _SIDE, 2)
        cv2.circle(img, (ox, oy), int(k * c.opponent_radius), _OPP, -1, cv2.LINE_AA)
        cv2.putText(img, "opponent", (ox - 30, oy - int(k * c.opponent_radius) - 6), _FONT, 0.38, _DIM, 1,
                    cv2.LINE_AA)
        if "opponent" in flash:
            cv2.circle(img, (ox, oy), int(k * c.opponent_radius) + 4, (255, 255, 255), 3, cv2.LINE_AA)
        px, py = self._px(s.player_x, c.player_y)
        r = int(k * c.player_radius * (0.6 if s.crouching else 1.0))
        col = _PLAYER if s.phase != Phase.WAITING else _HUMAN
        cv2.circle(img, (px, py), r, col, -1, cv2.LINE_AA)
        if s.phase != Phase.WAITING:  # a ninja headband
            cv2.line(img, (px - r, py - r // 3), (px + r, py - r // 3), (40, 40, 40), max(2, r // 4))
        label = "you (ducking)" if s.crouching else "you" if s.phase != Phase.WAITING else "you (human)"
        cv2.putText(img, label, (px - 4 * len(label), py + int(k * c.player_radius) + 14), _FONT, 0.38, _TEXT, 1,
                    cv2.LINE_AA)
        if "player" in flash:
            cv2.circle(img, (px, py), r + 4, (255, 255, 255), 3, cv2.LINE_AA)
        for p in s.projectiles:
            cx, cy = self._px(p.x, p.y)
            if p.kind == "high":
                cv2.line(img, self._px(p.x - p.width / 2, p.y), self._px(p.x + p.width / 2, p.y), _HIGH,
                         max(3, int(2 * k * p.radius)), cv2.LINE_AA)
            elif p.kind == "fire_ring":
                cv2.circle(img, (cx, cy), int(k * p.radius), _RING, 3, cv2.LINE_AA)
            else:
                cv2.circle(img, (cx, cy), max(3, int(k * p.radius)), _SIDE if p.kind == "side" else _STRIKE, -1,
                           cv2.LINE_AA)

    def _panel(self, img: NDArray[np.uint8], s: GameSnapshot, joints: NDArray[np.floating] | None,
               lines: list[str]) -> None:
        w, h = self.size
        x0 = self.arena_w + 6
        c = self.config
        bars = (("you", s.player_health, _PLAYER), ("opponent", s.opponent_health, _OPP))
        for row, (name, hp, col) in enumerate(bars):
            y = 16 + 30 * row
            cv2.putText(img, f"{name} {hp:.0f}", (x0, y), _FONT, 0.42, _TEXT, 1, cv2.LINE_AA)
            bw = w - x0 - 8
            cv2.rectangle(img, (x0, y + 4), (x0 + bw, y + 12), _LANE, -1)
            cv2.rectangle(img, (x0, y + 4), (x0 + int(bw * max(hp, 0.0) / c.health), y + 12), col, -1)
        status = {Phase.WAITING: "transform to start", Phase.FIGHTING: f"time {s.round_left_s:4.1f} s",
                  Phase.OVER: f"{s.winner.upper()} WINS ({s.end_reason})" if s.winner != "draw" else "DRAW"}[s.phase]
        cv2.putText(img, status, (x0, 80), _FONT, 0.42, _GOOD if s.phase == Phase.OVER else _TEXT, 1, cv2.LINE_AA)
        if s.telegraph:
            warn = "HIGH ATTACK: CROUCH!" if s.telegraph == "high" else "SIDE ATTACK: STEP!"
            cv2.putText(img, warn, (x0, 179), _FONT, 0.42, (0, 200, 255), 1, cv2.LINE_AA)
        for i, text in enumerate(lines[-5:]):
            cv2.putText(img, text[:26], (x0, 100 + 15 * i), _FONT, 0.36, _DIM if i < len(lines[-5:]) - 1 else _TEXT,
                        1, cv2.LINE_AA)
        if joints is not None:
            self._stick(img, np.asarray(joints, dtype=np.float64), (x0, 188, w - 6, h - 6))

    def _stick(self, img: NDArray[np.uint8], j: NDArray[np.float64], box: tuple[int, int, int, int]) -> None:
        """The player's pose seen from the camera (mirrored), scaled into ``box`` (x0, y0, x1, y1)."""
        if not np.isfinite(j).all():
            return
        x0, y0, x1, y1 = box
        cv2.rectangle(img, (x0, y0), (x1, y1), _LANE, 1)
        hip = j[JOINT_INDEX["l_hip"]] - j[JOINT_INDEX["r_hip"]]
        left = np.array([hip[0], 0.0, hip[2]])
        left /= np.linalg.norm(left) + 1e-9
        u = (j - j[JOINT_INDEX["pelvis"]]) @ left  # player's left -> screen left (mirror view)
        v = j[:, 1] - min(j[:, 1].min(), j[JOINT_INDEX["pelvis"], 1] - 1.0)
        k = min((x1 - x0 - 8) / 1.8, (y1 - y0 - 8) / 2.2)
        cx, base = (x0 + x1) / 2, y1 - 4
        pts = [(int(cx - k * a), int(base - k * b)) for a, b in zip(u, v, strict=True)]
        for child, par in enumerate(PARENTS):
            if par >= 0:
                col = _PLAYER if child in _LEFT_JOINTS else _TEXT
                cv2.line(img, pts[par], pts[child], col, 2, cv2.LINE_AA)


@dataclass
class FrameWriter:
    """Saves rendered frames at ``fps`` of game time to ``out_dir``.

    Writes ``frame_00000.png``... (every ``png_every``-th saved frame), ``round.gif`` (at most
    ``gif_max_frames`` frames, evenly thinned, scaled by ``gif_scale``) and ``round.mp4``.
    """

    out_dir: Path
    fps: float = 10.0
    png_every: int = 1
    gif_scale: float = 1.0
    gif_max_frames: int = 400
    mp4: bool = True
    frames: list[NDArray[np.uint8]] = field(default_factory=list)
    _next_t: float = 0.0
    _video: VideoWriter | None = None
    _count: int = 0

    def __post_init__(self) -> None:
        self.out_dir = Path(self.out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)

    def due(self, t: float) -> bool:
        """True if a frame should be saved for game time ``t`` (a new round restarting the game clock
        restarts the schedule)."""
        if t < self._next_t - 2.0 / self.fps:
            self._next_t = t
        return t + 1e-9 >= self._next_t

    def add(self, t: float, img: NDArray[np.uint8]) -> None:
        """Save one frame (call when :meth:`due`)."""
        self._next_t = max(self._next_t + 1.0 / self.fps, t)
        if self._count % self.png_every == 0:
            cv2.imwrite(str(self.out_dir / f"frame_{self._count:05d}.png"), img)
        if self.mp4:
            if self._video is None:
                self._video = VideoWriter(self.out_dir / "round.mp4", self.fps)
            self._video.write(img)
        self.frames.append(img)
        self._count += 1

    def close(self) -> list[Path]:
        """Finish the GIF and MP4; returns the files written besides the PNGs."""
        out: list[Path] = []
        if self._video is not None:
            self._video.close()
            self._video = None
            out.append(self.out_dir / "round.mp4")
        if self.frames:
            step = max(1, int(np.ceil(len(self.frames) / self.gif_max_frames)))
            frames = self.frames[::step]
            if self.gif_scale != 1.0:
                frames = [np.asarray(cv2.resize(f, None, fx=self.gif_scale, fy=self.gif_scale,
                                                interpolation=cv2.INTER_AREA), dtype=np.uint8) for f in frames]
            rgb = [cv2.cvtColor(f, cv2.COLOR_BGR2RGB) for f in frames]
            path = self.out_dir / "round.gif"
            iio.imwrite(path, np.stack(rgb), duration=round(1000 * step / self.fps), loop=0)
            out.append(path)
            log.info("wrote %d frames to %s", len(frames), path)
        return out


def event_line(r: GameRecord) -> str:
    """Short text of a game event for the panel."""
    who = {"player": "you", "opponent": "opp"}.get(r.actor, r.actor)
    if r.kind == "hit":
        return f"{r.t:5.1f} {r.detail} hits {who}"
    if r.kind == "attack":
        return f"{r.t:5.1f} opp {r.detail} attack"
    if r.kind == "round_end":
        return f"{r.t:5.1f} {who} {'win' if who == 'you' else 'wins'} ({'KO' if r.detail == 'knockout' else r.detail})"
    return f"{r.t:5.1f} {r.kind} {r.detail}".rstrip()
