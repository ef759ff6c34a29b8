"""Drawing game frames for people to look at (OpenCV), and writing them as PNG, GIF and MP4.

:class:`Renderer` draws one frame from a :class:`~game_client.game.GameSnapshot`: the arena seen from
above on the left (a lit floor with lane marks, the player's ninja at the bottom, the opponent's at
the top, both shaded with headbands; spinning shurikens, fireballs with trails, blades and fire
rings; the opponent's wind-up as a ring filling round it with a banner and a countdown telling the
player what to do; hit flashes; start and end banners) and a panel on the right (health bars,
round clock, the last recognised gesture and game events, and a stick figure of the player's pose
as the camera sees it, mirrored so the player's left is on the left). About 1-2 ms a frame. :class:`FrameWriter`
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

from protocol.formats.video import GifFrames, VideoWriter
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

    def _floor(self) -> NDArray[np.uint8]:
        """The arena's floor (drawn once per size): a lit gradient, lane stripes, a vignette."""
        cached: NDArray[np.uint8] | None = getattr(self, "_floor_img", None)
        if cached is not None:
            return cached
        w, h = self.size
        c = self.config
        x0, y0 = self._px(0, c.depth)
        x1, y1 = self._px(c.width, 0)
        img = np.full((h, w, 3), _BG, dtype=np.float32)
        t = np.linspace(0.0, 1.0, y1 - y0, dtype=np.float32)[:, None, None]
        img[y0:y1, x0:x1] = (1 - t) * np.array(_FLOOR, np.float32) * 0.8 + t * np.array(_FLOOR, np.float32) * 1.25
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        d = ((xx - cx) / max(x1 - x0, 1)) ** 2 + ((yy - cy) / max(y1 - y0, 1)) ** 2
        img[y0:y1, x0:x1] *= (1.0 - 0.5 * np.clip(d, 0, 1))[y0:y1, x0:x1, None]
        out = np.clip(img, 0, 255).astype(np.uint8)
        for x in c.lanes:  # dashed lane marks
            for yv in np.arange(0.3, c.depth - 0.3, 0.6):
                cv2.line(out, self._px(x, yv), self._px(x, min(yv + 0.3, c.depth - 0.2)), _LANE, 2, cv2.LINE_AA)
        cv2.rectangle(out, (x0, y0), (x1, y1), _LANE, 2)
        self._floor_img = out
        return out

    def _ninja(self, img: NDArray[np.uint8], centre: tuple[int, int], r: int, body: tuple[int, int, int],
               band: tuple[int, int, int], facing_up: bool, squash: float = 1.0) -> None:
        """A shaded ninja seen from above: shadow, body, head with a headband and eyes."""
        x, y = centre
        cv2.ellipse(img, (x + r // 4, y + r // 3), (r, max(2, int(r * 0.6))), 0, 0, 360, (18, 16, 15), -1, cv2.LINE_AA)
        ry = max(3, int(r * squash))
        for k in range(4):  # shading: darker rim to a lit centre, light from the upper left
            f = 0.65 + 0.12 * k
            col = tuple(int(min(255, v * f)) for v in body)
            rr = max(2, int(r * (1.0 - 0.18 * k)))
            cv2.ellipse(img, (x - k * r // 12, y - k * ry // 12), (rr, max(2, int(rr * ry / r))), 0, 0, 360, col, -1,
                        cv2.LINE_AA)
        hy = y - (ry // 2 if facing_up else -ry // 2)
        hr = max(3, r // 2)
        cv2.circle(img, (x, hy), hr, tuple(int(v * 0.55) for v in body), -1, cv2.LINE_AA)
        cv2.line(img, (x - hr, hy), (x + hr, hy), band, max(2, hr // 2), cv2.LINE_AA)
        tail = (x + hr + hr // 2, hy + (hr if facing_up else -hr))
        cv2.line(img, (x + hr, hy), tail, band, max(1, hr // 3), cv2.LINE_AA)
        ey = hy - (hr // 3 if facing_up else -hr // 3)
        for ex in (x - hr // 2, x + hr // 2):
            cv2.ellipse(img, (ex, ey), (max(1, hr // 4), 1), 0, 0, 360, (250, 250, 250), -1, cv2.LINE_AA)

    def _banner(self, img: NDArray[np.uint8], text: str, colour: tuple[int, int, int], y: int,
                scale: float = 0.7) -> None:
        """Centred text on a dark band across the arena."""
        (tw, th), _ = cv2.getTextSize(text, _FONT, scale, 2)
        cx = self.arena_w // 2
        band = img[max(0, y - th - 8): y + 8, 4: self.arena_w - 4]
        band[:] = (band.astype(np.float32) * 0.35).astype(np.uint8)
        cv2.putText(img, text, (cx - tw // 2, y), _FONT, scale, colour, 2, cv2.LINE_AA)

    def _arena(self, img: NDArray[np.uint8], s: GameSnapshot, flash: set[str]) -> None:
        c, k = self.config, self.scale
        img[:] = self._floor()
        ox, oy = self._px(s.opponent_x, c.opponent_y)
        ro = int(k * c.opponent_radius)
        if s.telegraph:  # the wind-up: a ring filling round the opponent, the lane it aims at lit up
            col = _HIGH if s.telegraph == "high" else _SIDE
            done = 1.0 - min(1.0, s.telegraph_left_s / max(c.windup_s, 1e-6))
            cv2.ellipse(img, (ox, oy), (ro + 10, ro + 10), -90, 0, int(360 * done), col, 4, cv2.LINE_AA)
            if s.telegraph == "side":
                lx, _ = self._px(s.player_x, 0)
                cv2.line(img, (lx, oy + ro), self._px(s.player_x, c.player_y), col, 1, cv2.LINE_AA)
        self._ninja(img, (ox, oy), ro, _OPP, (40, 40, 40), facing_up=False)
        if "opponent" in flash:
            cv2.circle(img, (ox, oy), ro + 6, (255, 255, 255), 3, cv2.LINE_AA)
            cv2.putText(img, "HIT!", (ox + ro + 6, oy), _FONT, 0.6, (255, 255, 255), 2, cv2.LINE_AA)
        px, py = self._px(s.player_x, c.player_y)
        r = int(k * c.player_radius)
        human = s.phase == Phase.WAITING
        self._ninja(img, (px, py), r, _HUMAN if human else _PLAYER, (60, 60, 60) if human else (40, 40, 220),
                    facing_up=True, squash=0.6 if s.crouching else 1.0)
        label = "you (ducking)" if s.crouching else "you (human)" if human else "you"
        cv2.putText(img, label, (px - 4 * len(label), py + r + 16), _FONT, 0.4, _TEXT, 1, cv2.LINE_AA)
        if "player" in flash:
            cv2.circle(img, (px, py), r + 6, (255, 255, 255), 3, cv2.LINE_AA)
        for p in s.projectiles:
            self._projectile(img, p.kind, p.x, p.y, p.radius, p.width, s.t)
        if s.telegraph:
            warn = "HIGH ATTACK - CROUCH!" if s.telegraph == "high" else "SIDE ATTACK - STEP ASIDE!"
            self._banner(img, f"{warn} {s.telegraph_left_s:.1f}s", (0, 210, 255), int(self.size[1] * 0.42), 0.55)
        elif s.phase == Phase.WAITING:
            self._banner(img, "TRANSFORM TO START", _TEXT, int(self.size[1] * 0.45), 0.6)
            self._banner(img, "arms out, then hands to the chest", _DIM, int(self.size[1] * 0.45) + 26, 0.42)
        elif s.phase == Phase.OVER:
            text = "DRAW" if s.winner == "draw" else "YOU WIN!" if s.winner == "player" else "YOU LOSE"
            self._banner(img, text, _GOOD if s.winner == "player" else _BAD, self.size[1] // 2, 1.1)

    def _projectile(self, img: NDArray[np.uint8], kind: str, x: float, y: float, radius: float, width: float,
                    t: float) -> None:
        k = self.scale
        cx, cy = self._px(x, y)
        if kind == "high":  # a spinning blade across the lanes, with a glow
            a, b = self._px(x - width / 2, y), self._px(x + width / 2, y)
            thick = max(3, int(2 * k * radius))
            cv2.line(img, a, b, tuple(int(v * 0.5) for v in _HIGH), thick + 6, cv2.LINE_AA)
            cv2.line(img, a, b, _HIGH, thick, cv2.LINE_AA)
        elif kind == "fire_ring":  # the player's fire ring: a glowing double ring
            rr = int(k * radius)
            cv2.circle(img, (cx, cy), rr + 3, (0, 120, 255), 5, cv2.LINE_AA)
            cv2.circle(img, (cx, cy), rr, _RING, 3, cv2.LINE_AA)
        elif kind == "side":  # a fireball with a trail
            rr = max(4, int(k * radius))
            for j in range(4, 0, -1):
                cv2.circle(img, (cx, cy - j * rr // 2), max(2, rr - j), tuple(int(v * (0.3 + 0.1 * (4 - j)))
                                                                            for v in _SIDE), -1, cv2.LINE_AA)
            cv2.circle(img, (cx, cy), rr, _SIDE, -1, cv2.LINE_AA)
            cv2.circle(img, (cx, cy), max(2, rr // 2), (120, 220, 255), -1, cv2.LINE_AA)
        else:  # the player's strike: a spinning shuriken
            rr = max(5, int(k * radius) + 3)
            ang = 12.0 * t
            pts = []
            for i in range(8):
                phi = ang + i * np.pi / 4
                dist = rr if i % 2 == 0 else rr * 0.35
                pts.append((int(cx + dist * np.cos(phi)), int(cy + dist * np.sin(phi))))
            cv2.fillPoly(img, [np.array(pts, np.int32)], _STRIKE, cv2.LINE_AA)
            cv2.circle(img, (cx, cy), max(1, rr // 5), _BG, -1, cv2.LINE_AA)

    def _panel(self, img: NDArray[np.uint8], s: GameSnapshot, joints: NDArray[np.floating] | None,
               lines: list[str]) -> None:
        w, h = self.size
        x0 = self.arena_w + 6
        c = self.config
        bars = (("YOU", s.player_health, _PLAYER), ("OPPONENT", s.opponent_health, _OPP))
        for row, (name, hp, col) in enumerate(bars):
            y = 18 + 34 * row
            cv2.putText(img, f"{name}", (x0, y), _FONT, 0.42, _TEXT, 1, cv2.LINE_AA)
            cv2.putText(img, f"{max(hp, 0):.0f}", (w - 36, y), _FONT, 0.42, _TEXT, 1, cv2.LINE_AA)
            bw = w - x0 - 8
            cv2.rectangle(img, (x0, y + 5), (x0 + bw, y + 17), (20, 18, 17), -1)
            fill = int(bw * max(hp, 0.0) / c.health)
            if fill > 0:
                cv2.rectangle(img, (x0, y + 5), (x0 + fill, y + 17), col, -1)
                cv2.rectangle(img, (x0, y + 5), (x0 + fill, y + 9), tuple(min(255, int(v * 1.3)) for v in col), -1)
            cv2.rectangle(img, (x0, y + 5), (x0 + bw, y + 17), _DIM, 1)
        status = {Phase.WAITING: "transform to start", Phase.FIGHTING: f"{s.round_left_s:4.1f} s left",
                  Phase.OVER: f"{s.winner.upper()} WINS ({s.end_reason})" if s.winner != "draw" else "DRAW"}[s.phase]
        cv2.putText(img, status, (x0, 96), _FONT, 0.5, _GOOD if s.phase == Phase.OVER else _TEXT, 1, cv2.LINE_AA)
        for i, text in enumerate(lines[-5:]):
            cv2.putText(img, text[:26], (x0, 116 + 15 * i), _FONT, 0.36, _DIM if i < len(lines[-5:]) - 1 else _TEXT,
                        1, cv2.LINE_AA)
        if joints is not None:
            self._stick(img, np.asarray(joints, dtype=np.float64), (x0, 196, w - 6, h - 6))

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

    The GIF's frames are thinned as they come (:class:`protocol.formats.video.GifFrames`), so a live
    session of any length holds fewer than ``gif_max_frames`` images.
    """

    out_dir: Path
    fps: float = 10.0
    png_every: int = 1
    gif_scale: float = 1.0
    gif_max_frames: int = 400
    mp4: bool = True
    _gif: GifFrames = field(init=False, repr=False)
    _next_t: float = 0.0
    _video: VideoWriter | None = None
    _count: int = 0

    def __post_init__(self) -> None:
        self.out_dir = Path(self.out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self._gif = GifFrames(self.gif_max_frames)

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
        self._gif.add(img)
        self._count += 1

    def close(self) -> list[Path]:
        """Finish the GIF and MP4; returns the files written besides the PNGs."""
        out: list[Path] = []
        if self._video is not None:
            self._video.close()
            self._video = None
            out.append(self.out_dir / "round.mp4")
        if self._gif.frames:
            frames = self._gif.frames
            if self.gif_scale != 1.0:
                frames = [np.asarray(cv2.resize(f, None, fx=self.gif_scale, fy=self.gif_scale,
                                                interpolation=cv2.INTER_AREA), dtype=np.uint8) for f in frames]
            rgb = [cv2.cvtColor(f, cv2.COLOR_BGR2RGB) for f in frames]
            path = self.out_dir / "round.gif"
            iio.imwrite(path, np.stack(rgb), duration=round(1000 * self._gif.duration_s(self.fps)), loop=0)
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
