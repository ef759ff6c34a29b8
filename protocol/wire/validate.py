"""Semantic checks of received messages: what the codec's schema cannot see.

:func:`protocol.wire.codec.decode` guarantees shapes, types and finiteness. A message can still be
nonsense by *meaning*: a 170 m (or 1.7 mm) body, a joint 10^30 m away, a rotation of 10^4 rad, a
frame stamped 30,000 years ahead, a sequence number of 2^63 - 1. One such message must not take a
client's state with it, so the clients check every message here first and drop what fails.

Every check is a pure function that returns a short *reason* string (a fixed identifier, usable as
a counter name) or ``None`` when the message is plausible; none raises, whatever it is given.

* :func:`check_body_info` - skeleton and body scale (stature, bone lengths, capsule radii, the
  ``height_m`` measurement);
* :func:`check_pose_frame` - finite, bounded root position, rotation vectors and joints, the
  joints around the root;
* :class:`StreamClock` - ``seq`` and ``capture_ts`` against the stream so far: accepts a
  monotonic stream within a window, rejects far-future stamps, seq jumps and stale (out-of-order)
  frames, and recognises a *new stream* (tracker restart: seq reset, time jump) once a few
  consistent frames of it arrive and the old stream has gone quiet;
* :class:`RateLimitedLog` - at most one log line per reason per interval, with a count of the
  suppressed ones;
* :func:`clamp_count` - a counter clamped into the codec's integer range.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from protocol.skeleton import JOINT_INDEX, JOINT_NAMES, N_CAPSULES, N_JOINTS, PARENTS, POSE_SIZE

__all__ = [
    "BONE_MAX_M",
    "CAPSULE_RADIUS_MAX_M",
    "COUNT_MAX",
    "JOINT_EXTENT_MAX_M",
    "MAX_POSITION_M",
    "MAX_ROTATION_RAD",
    "STATURE_RANGE_M",
    "ClockVerdict",
    "RateLimitedLog",
    "StreamClock",
    "check_body_info",
    "check_pose_frame",
    "clamp_count",
    "stature_of",
]

#: Largest |coordinate| of a root position or joint, metres (a capture volume is a room).
MAX_POSITION_M: Final[float] = 50.0
#: Largest rotation-vector norm, radians (a rotation needs at most pi; 2 pi leaves room for wrap).
MAX_ROTATION_RAD: Final[float] = 2.0 * math.pi + 1e-3
#: Plausible stature of a tracked body, metres (from the skeleton and from ``height_m``).
STATURE_RANGE_M: Final[tuple[float, float]] = (0.5, 2.5)
#: Longest single bone, metres (a 2.5 m person's shin is ~0.62 m).
BONE_MAX_M: Final[float] = 0.8
#: Largest capsule radius, metres.
CAPSULE_RADIUS_MAX_M: Final[float] = 0.5
#: Farthest a joint may be from the root joint, metres.
JOINT_EXTENT_MAX_M: Final[float] = 3.0
#: Largest integer the codec accepts (int64).
COUNT_MAX: Final[int] = 2**63 - 1

_LEGS: Final[tuple[tuple[int, ...], ...]] = tuple(
    tuple(JOINT_INDEX[f"{s}_{n}"] for n in ("knee", "ankle")) for s in ("l", "r"))
_TRUNK: Final[tuple[int, ...]] = tuple(JOINT_INDEX[n] for n in ("spine", "chest", "neck", "head", "head_top"))


def clamp_count(n: Any) -> int:
    """``n`` as an int in ``[0, COUNT_MAX]`` (what the codec accepts for counters); 0 if not a number."""
    try:
        v = int(n)
    except (TypeError, ValueError, OverflowError):
        return 0
    return min(max(v, 0), COUNT_MAX)


def _finite_float(x: Any) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError, OverflowError):
        return None
    return v if math.isfinite(v) else None


def _array(x: Any, shape: tuple[int, ...]) -> np.ndarray | None:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        return None
    return a if a.shape == shape else None


def stature_of(bone_lengths: Any) -> float | None:
    """Standing height estimated from bone lengths ``(J,)``: mean leg (hip to ankle) plus the trunk
    and head chain (pelvis to head top), metres; None if unusable. Direction-free, so it does not
    depend on the rest pose's orientation."""
    bl = _array(bone_lengths, (N_JOINTS,))
    if bl is None or not np.isfinite(bl).all():
        return None
    leg = 0.5 * sum(float(bl[list(chain)].sum()) for chain in _LEGS)
    return leg + float(bl[list(_TRUNK)].sum())


def check_body_info(info: Any) -> str | None:
    """Reason a ``BodyInfo`` is implausible, or None.

    Reasons: ``body_skeleton`` (joint names / parents not this protocol's skeleton),
    ``body_nonfinite``, ``body_stature`` (skeleton stature outside :data:`STATURE_RANGE_M`),
    ``body_bone`` (a bone longer than :data:`BONE_MAX_M`), ``body_radius`` (a capsule radius not in
    ``(0, CAPSULE_RADIUS_MAX_M]``), ``body_height`` (``height_m`` outside the stature range or
    disagreeing with the skeleton by more than a factor 1.5).
    """
    try:
        if tuple(info.joint_names) != JOINT_NAMES or tuple(info.parents) != PARENTS:
            return "body_skeleton"
        off = _array(info.offsets, (N_JOINTS, 3))
        radii = _array(info.capsule_radii, (N_CAPSULES, 2))
        if off is None or radii is None or not (np.isfinite(off).all() and np.isfinite(radii).all()):
            return "body_nonfinite"
        bones = np.linalg.norm(off, axis=1)
        stature = stature_of(bones)
        lo, hi = STATURE_RANGE_M
        if stature is None or not lo <= stature <= hi:
            return "body_stature"
        if float(bones.max()) > BONE_MAX_M:
            return "body_bone"
        if not (float(radii.min()) > 0.0 and float(radii.max()) <= CAPSULE_RADIUS_MAX_M):
            return "body_radius"
        meas = info.measurements
        if "height_m" in meas:
            h = _finite_float(meas["height_m"])
            if h is None or not lo <= h <= hi or not stature / 1.5 <= h <= stature * 1.5:
                return "body_height"
        for v in meas.values():
            if _finite_float(v) is None:
                return "body_nonfinite"
    except Exception:  # never raise, whatever arrives
        return "body_malformed"
    return None


def check_pose_frame(frame: Any) -> str | None:
    """Reason a ``PoseFrame``'s content is implausible, or None (its clock is :class:`StreamClock`'s).

    Reasons: ``pose_nonfinite``, ``pose_position`` (root beyond :data:`MAX_POSITION_M`),
    ``pose_rotation`` (a rotation vector longer than :data:`MAX_ROTATION_RAD`), ``pose_joints``
    (a joint beyond :data:`MAX_POSITION_M` or farther than :data:`JOINT_EXTENT_MAX_M` from the root
    joint), ``pose_confidence`` (confidence or visibility outside [0, 1]), ``pose_clock`` (captured
    after it was published).
    """
    try:
        pose = _array(frame.pose, (POSE_SIZE,))
        joints = _array(frame.joints, (N_JOINTS, 3))
        if pose is None or joints is None or not (np.isfinite(pose).all() and np.isfinite(joints).all()):
            return "pose_nonfinite"
        if float(np.abs(pose[:3]).max()) > MAX_POSITION_M:
            return "pose_position"
        if float(np.linalg.norm(pose[3:].reshape(-1, 3), axis=1).max()) > MAX_ROTATION_RAD:
            return "pose_rotation"
        if float(np.abs(joints).max()) > MAX_POSITION_M:
            return "pose_joints"
        if float(np.linalg.norm(joints - joints[0], axis=1).max()) > JOINT_EXTENT_MAX_M:
            return "pose_joints"
        conf = _finite_float(frame.confidence)
        vis = np.asarray(frame.visibility, dtype=np.float64)
        if conf is None or not 0.0 <= conf <= 1.0 or not (np.isfinite(vis).all() and vis.min() >= 0.0
                                                            and vis.max() <= 1.0):
            return "pose_confidence"
        cap, pub = _finite_float(frame.capture_wall_ts), _finite_float(frame.publish_ts)
        if cap is None or pub is None or cap > pub:
            return "pose_clock"
    except Exception:  # never raise, whatever arrives
        return "pose_malformed"
    return None


@dataclass(frozen=True)
class ClockVerdict:
    """What :meth:`StreamClock.observe` decided about one frame.

    Attributes
    ----------
    reason : str or None
        Why the frame is dropped; None when accepted.
    new_stream : bool
        The frame was accepted as the first of a new stream (the first stream, or a restart):
        the client resets whatever clock it keeps for the stream.
    restart : bool
        ``new_stream`` and it replaced an earlier stream (a tracker restart).
    """

    reason: str | None
    new_stream: bool = False
    restart: bool = False

    @property
    def ok(self) -> bool:
        return self.reason is None


class StreamClock:
    """The stream's clock as a client sees it: accepts or rejects each frame's ``(seq, capture_ts)``.

    A frame *continues* the stream when ``0 < seq - last_seq <= max_seq_gap`` and its time is
    neither earlier than the last nor further ahead than the local time elapsed since the last
    accepted frame plus ``max_ahead_s``. Otherwise it is dropped with a reason:

    * ``ts_invalid`` - not a finite number >= 0 (never a new stream);
    * ``seq_repeat`` / ``out_of_order`` - an old or repeated frame (seq up to ``reorder_window``
      behind and time back by at most ``max_back_s``);
    * ``ts_future`` - too far ahead of the stream; ``ts_backwards`` - back by more than
      ``max_back_s``; ``seq_jump`` - seq ahead by more than ``max_seq_gap``; ``seq_reset`` - seq
      back by more than ``reorder_window``; ``ts_stalled`` - a new seq whose time went back.

    Every dropped frame but ``ts_invalid`` is a candidate for a **new stream** (a restarted tracker
    starts again at seq 0 and its own time 0): once ``confirm_frames`` of them in a row continue
    each other and the current stream has sent nothing accepted for ``quiet_s`` (local time), the
    candidate becomes the stream and the frame is accepted with ``new_stream``. One bad frame, or
    stale frames interleaved with a live stream, therefore never replace the stream, while a
    restart is followed within ``quiet_s`` plus a few frames.

    Parameters
    ----------
    max_ahead_s, max_back_s : float
    max_seq_gap, reorder_window : int
    confirm_frames : int
    quiet_s : float
    """

    def __init__(self, *, max_ahead_s: float = 2.0, max_back_s: float = 1.0, max_seq_gap: int = 3600,
                 reorder_window: int = 64, confirm_frames: int = 3, quiet_s: float = 0.3) -> None:
        self.max_ahead_s, self.max_back_s = max_ahead_s, max_back_s
        self.max_seq_gap, self.reorder_window = max_seq_gap, reorder_window
        self.confirm_frames, self.quiet_s = max(1, confirm_frames), quiet_s
        self.last_seq: int | None = None
        self.last_ts = 0.0
        self.last_now = 0.0
        self.streams = 0
        self._cand: tuple[int, float, float, int] | None = None  # seq, ts, now, count

    @property
    def started(self) -> bool:
        return self.last_seq is not None

    def _follows(self, seq: int, ts: float, now: float, seq0: int, ts0: float, now0: float) -> bool:
        return 0 < seq - seq0 <= self.max_seq_gap and 0.0 <= ts - ts0 <= max(now - now0, 0.0) + self.max_ahead_s

    def _adopt(self, seq: int, ts: float, now: float) -> ClockVerdict:
        restart = self.last_seq is not None
        self.last_seq, self.last_ts, self.last_now = seq, ts, now
        self.streams += 1
        self._cand = None
        return ClockVerdict(None, new_stream=True, restart=restart)

    def observe(self, seq: Any, capture_ts: Any, now: float | None = None) -> ClockVerdict:
        """Judge one frame (and update the clock if it is accepted); never raises.

        Parameters
        ----------
        seq : int
        capture_ts : float
            The frame's stream time, seconds.
        now : float, optional
            Local monotonic time, seconds (default :func:`time.monotonic`).
        """
        now = time.monotonic() if now is None else float(now)
        ts = _finite_float(capture_ts)
        if ts is None or ts < 0.0 or isinstance(seq, bool) or not isinstance(seq, int | np.integer) or seq < 0:
            return ClockVerdict("ts_invalid")
        seq = int(seq)
        if self.last_seq is None:
            return self._adopt(seq, ts, now)
        if self._follows(seq, ts, now, self.last_seq, self.last_ts, self.last_now):
            self.last_seq, self.last_ts, self.last_now = seq, ts, now
            self._cand = None
            return ClockVerdict(None)
        dseq, dts = seq - self.last_seq, ts - self.last_ts
        if -self.reorder_window <= dseq <= 0 and dts >= -self.max_back_s:
            reason = "seq_repeat" if dseq == 0 else "out_of_order"
        elif dseq > 0 and -self.max_back_s <= dts < 0.0 and dseq <= self.max_seq_gap:
            reason = "ts_stalled"
        elif dts < -self.max_back_s:
            reason = "ts_backwards"
        elif dseq > self.max_seq_gap:
            reason = "seq_jump"
        elif dseq <= 0:
            reason = "seq_reset"
        else:
            reason = "ts_future"
        # a candidate for a new stream
        c = self._cand
        count = c[3] + 1 if c is not None and self._follows(seq, ts, now, c[0], c[1], c[2]) else 1
        self._cand = (seq, ts, now, count)
        if count >= self.confirm_frames and now - self.last_now >= self.quiet_s:
            return self._adopt(seq, ts, now)
        return ClockVerdict(reason)


class RateLimitedLog:
    """Log a recurring warning at most once per ``interval_s`` per reason, with the suppressed count.

    ``log(reason, "text %s", arg)`` logs ``"text arg"`` the first time ``reason`` is seen and then
    at most once per interval, appending ``" (N more since last report)"`` when lines were
    suppressed. :attr:`counts` keeps the total per reason.
    """

    def __init__(self, logger: logging.Logger, interval_s: float = 5.0, level: int = logging.WARNING,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.logger, self.interval_s, self.level, self.clock = logger, interval_s, level, clock
        self.counts: dict[str, int] = {}
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def __call__(self, reason: str, msg: str, *args: object) -> bool:
        """Count ``reason`` and maybe log; True if a line was written."""
        self.counts[reason] = self.counts.get(reason, 0) + 1
        now = self.clock()
        last = self._last.get(reason)
        if last is not None and now - last < self.interval_s:
            self._suppressed[reason] = self._suppressed.get(reason, 0) + 1
            return False
        n = self._suppressed.pop(reason, 0)
        self._last[reason] = now
        try:
            if n:
                self.logger.log(self.level, msg + " (%d more since last report)", *args, n, stacklevel=2)
            else:
                self.logger.log(self.level, msg, *args, stacklevel=2)
        except Exception:  # a logging failure must not take the client down
            return False
        return True
