"""What the live viewer knows: the latest message of every tracker, game and cloth client on the
network, built from raw Zenoh samples without I/O (``mocap-view``'s pure core,
:mod:`tracker_service.app.view` draws it).

Every payload is decoded and checked as the clients check it (:mod:`protocol.wire.validate`);
whatever fails is counted by reason and otherwise ignored, so a hostile or broken publisher can
only lose its own messages.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import JOINT_NAMES, PARENTS
from protocol.wire.codec import ProtocolError, decode
from protocol.wire.game_messages import GameEvent, GameState, decode_game
from protocol.wire.keys import split_key
from protocol.wire.media import ClothMesh, PreviewFrame, decode_cloth_mesh, decode_preview
from protocol.wire.messages import BodyInfo, PoseFrame, TrackerStatus
from protocol.wire.validate import check_body_info, check_pose_frame

__all__ = ["ClothView", "LiveState", "TrackerView", "skeleton_segments"]

#: A source that sent nothing for this long is shown as silent (seconds).
SILENT_AFTER_S = 3.0


@dataclass
class TrackerView:
    """The latest of each message of one tracker, and when it arrived (``time.monotonic``)."""

    pose: PoseFrame | None = None
    body: BodyInfo | None = None
    status: TrackerStatus | None = None
    preview: PreviewFrame | None = None
    latency_ms: deque[float] = field(default_factory=lambda: deque(maxlen=90))
    last_rx: float = -np.inf


@dataclass
class ClothView:
    """The latest cloth mesh (with the last triangles seen) of one cloth client."""

    mesh: ClothMesh | None = None
    triangles: NDArray[np.uint32] | None = None
    last_rx: float = -np.inf


@dataclass
class LiveState:
    """Everything the viewer shows, updated by :meth:`on_sample`."""

    trackers: dict[str, TrackerView] = field(default_factory=dict)
    games: dict[str, GameState] = field(default_factory=dict)
    events: deque[str] = field(default_factory=lambda: deque(maxlen=8))
    cloths: dict[str, ClothView] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    version: int = 0  # bumped by every accepted message

    def _drop(self, reason: str) -> None:
        self.dropped[reason] = self.dropped.get(reason, 0) + 1

    def on_sample(self, key: str, payload: bytes, now: float | None = None, wall: float | None = None) -> bool:
        """Take one sample; True if it changed what is shown. Never raises for bad input.

        Parameters
        ----------
        key : str
            The sample's key (``mocap/tracker/<id>/pose`` ...).
        payload : bytes
        now : float, optional
            ``time.monotonic()`` of arrival.
        wall : float, optional
            ``time.time()`` of arrival (for the latency from the frame's capture, ``capture_wall_ts``).
        """
        now = time.monotonic() if now is None else now
        try:
            parts = split_key(key)
        except ValueError:
            self._drop("key")
            return False
        try:
            return self._take(parts.domain, parts.id, parts.leaf, payload, now,
                              time.time() if wall is None else wall)
        except ProtocolError:
            self._drop(f"{parts.domain}_{parts.leaf}_malformed")
            return False

    def _take(self, domain: str, sid: str, leaf: str, payload: bytes, now: float, wall: float) -> bool:
        if domain == "tracker":
            view = self.trackers.setdefault(sid, TrackerView())
            if leaf == "pose":
                pose = decode(payload, PoseFrame)
                if (reason := check_pose_frame(pose)) is not None:
                    self._drop(reason)
                    return False
                view.pose = pose
                view.latency_ms.append(max(0.0, (wall - pose.capture_wall_ts) * 1e3))
            elif leaf == "body":
                body = decode(payload, BodyInfo)
                if (reason := check_body_info(body)) is not None:
                    self._drop(reason)
                    return False
                view.body = body
            elif leaf == "status":
                view.status = decode(payload, TrackerStatus)
            elif leaf == "preview":
                view.preview = decode_preview(payload)
            else:
                return False
            view.last_rx = now
        elif domain == "game":
            msg = decode_game(payload)
            if isinstance(msg, GameState):
                self.games[sid] = msg
            elif isinstance(msg, GameEvent):
                what = " ".join(x for x in (msg.kind.value, msg.gesture, msg.actor, msg.detail) if x)
                self.events.append(f"{sid}: {what}")
        elif domain == "cloth" and leaf == "mesh":
            mesh = decode_cloth_mesh(payload)
            cv = self.cloths.setdefault(sid, ClothView())
            if mesh.triangles is not None:
                cv.triangles = mesh.triangles
            if cv.triangles is not None and int(cv.triangles.max()) >= len(mesh.vertices):
                cv.triangles = None  # a new garment whose topology has not come yet
            cv.mesh, cv.last_rx = mesh, now
        else:
            return False
        self.version += 1
        return True

    def tracker_lines(self, sid: str, now: float | None = None) -> list[str]:
        """Status lines of one tracker: state, fps, latency, confidence, body, per-stage ms."""
        now = time.monotonic() if now is None else now
        v = self.trackers[sid]
        st = v.status
        lines = [f"**tracker `{sid}`** " + ("(silent)" if now - v.last_rx > SILENT_AFTER_S else
                                            (st.state.value if st else "running"))]
        if st is not None:
            if st.advice:
                lines.append(f"⚠ {st.advice}")
            lines.append(f"fps {st.fps:.1f} · frames {st.frames} · {st.estimator or ''} · body {st.body_model or '-'}")
            if st.stage_ms:
                lines.append("ms: " + ", ".join(f"{k} {x:.1f}" for k, x in sorted(st.stage_ms.items())))
        if v.pose is not None:
            lat = np.asarray(v.latency_ms) if v.latency_ms else np.array([np.nan])
            lines.append(f"confidence {v.pose.confidence:.2f} · latency p50 {np.nanmedian(lat):.0f} ms "
                         f"p99 {np.nanpercentile(lat, 99):.0f} ms")
        return lines

    def game_lines(self, gid: str) -> list[str]:
        """Status lines of one game: phase, health bars, time left, counters."""
        g = self.games[gid]

        def bar(x: float) -> str:
            n = round(10 * float(np.clip(x, 0.0, 1.0)))
            return "█" * n + "░" * (10 - n)

        lines = [f"**game `{gid}`** {g.phase.value} · {g.round_left_s:.0f} s left",
                 f"player {bar(g.player_health)} · opponent {bar(g.opponent_health)}"]
        if g.winner:
            lines.append(f"winner: {g.winner} ({g.end_reason})")
        return lines


#: The bones (parent, child) and their colours: the person's left side blue, right red, middle white.
_BONES = np.array([(p, c) for c, p in enumerate(PARENTS) if p >= 0], np.int64)
_BONE_RGB = np.repeat(np.array([(70, 130, 255) if JOINT_NAMES[c].startswith("l_") else (255, 60, 60)
                                if JOINT_NAMES[c].startswith("r_") else (235, 235, 235) for _, c in _BONES],
                               np.uint8)[:, None, :], 2, axis=1)


def skeleton_segments(joints: Any) -> tuple[NDArray[np.float32], NDArray[np.uint8]]:
    """Bone segments of a pose for a line renderer.

    Parameters
    ----------
    joints : (J, 3) float
        World joints, order :data:`protocol.skeleton.JOINT_NAMES`.

    Returns
    -------
    points : (B, 2, 3) float32
        Parent and child joint of every bone.
    colours : (B, 2, 3) uint8
        RGB: the person's left side blue, right side red, the middle white.
    """
    return np.asarray(joints, np.float32)[_BONES], _BONE_RGB
