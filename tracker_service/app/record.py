"""Recording a tracker's session (``mocap-tracker record``): the poses published on
``mocap/tracker/<id>/pose`` and the body on ``.../body`` written as BVH, JSON lines and CSV.

Pure conversions (received frames -> arrays -> files) are kept apart from the Zenoh subscription
(:func:`record_session`), so they can be used and tested without a network:

* :func:`frames_to_arrays`: the :class:`~protocol.wire.messages.PoseFrame` list as arrays;
* :func:`write_recording_bvh`: the poses on the tracked body's skeleton (its bone lengths come from
  the ``BodyInfo``), with conventional joint names (``Hips``, ``Spine``, ``LeftArm``, ... in
  :data:`CONVENTIONAL_NAMES`) or the project's own; centimetres, ZXY Euler channels, Y up: what
  Blender's BVH importer expects (import with scale 0.01 for metres);
* :func:`write_jsonl`: one JSON object per frame (``seq``, ``capture_ts``, ``joints``, ``confidence``);
* :func:`write_csv`: ``seq, t`` (seconds since the first frame), then ``x, y, z`` of every joint;
* :func:`bvh_joint_positions`: the world joints of a BVH written here (end sites included), read
  back with :func:`protocol.formats.bvh.read_bvh` and its forward kinematics.

One BVH frame is written per received pose; the frame time is the median capture interval (frames
the network dropped are not filled in). The BVH has one hierarchy: the last ``BodyInfo`` received
(a warning says so when the tracker changed its body during the session).
"""

from __future__ import annotations

import csv
import json
import logging
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import zenoh
from numpy.typing import NDArray

from protocol.formats.bvh import BvhFile, bvh_fk, read_bvh, write_bvh
from protocol.skeleton import JOINT_INDEX, JOINT_NAMES, N_JOINTS, PARENTS, POSE_SIZE, Body, default_body
from protocol.wire.codec import ProtocolError, decode
from protocol.wire.keys import body_key, pose_key, validate_id
from protocol.wire.messages import BodyInfo, PoseFrame, body_from_body_info
from tracker_service.app.options import RecordOptions

__all__ = [
    "CONVENTIONAL_NAMES",
    "RecordSummary",
    "Recording",
    "RecordingArrays",
    "bvh_joint_positions",
    "frames_to_arrays",
    "read_recording_bvh",
    "record_session",
    "save_recording",
    "write_csv",
    "write_jsonl",
    "write_recording_bvh",
]

log = logging.getLogger(__name__)

#: Our joint names -> the conventional (Mixamo / MotionBuilder style) BVH names. The end joints
#: (head top, hand tips, toes) are ``End Site``\\ s of their parents and carry no name in a BVH.
CONVENTIONAL_NAMES: dict[str, str] = {
    "pelvis": "Hips", "spine": "Spine", "chest": "Spine1", "neck": "Neck", "head": "Head",
    "head_top": "HeadTop_End",
    "l_clavicle": "LeftShoulder", "l_shoulder": "LeftArm", "l_elbow": "LeftForeArm", "l_wrist": "LeftHand",
    "l_hand_tip": "LeftHand_End",
    "r_clavicle": "RightShoulder", "r_shoulder": "RightArm", "r_elbow": "RightForeArm", "r_wrist": "RightHand",
    "r_hand_tip": "RightHand_End",
    "l_hip": "LeftUpLeg", "l_knee": "LeftLeg", "l_ankle": "LeftFoot", "l_toe": "LeftToe_End",
    "r_hip": "RightUpLeg", "r_knee": "RightLeg", "r_ankle": "RightFoot", "r_toe": "RightToe_End",
}
BvhNames = Literal["conventional", "native"]


@dataclass
class Recording:
    """What a session received: the pose frames in arrival order and every ``BodyInfo``."""

    frames: list[PoseFrame] = field(default_factory=list)
    bodies: list[BodyInfo] = field(default_factory=list)
    decode_errors: int = 0

    def body(self) -> Body | None:
        """The skeleton of the recording: the last ``BodyInfo`` received (None: none)."""
        if not self.bodies:
            return None
        distinct = {(b.body_model, b.offsets.tobytes()) for b in self.bodies}
        if len(distinct) > 1:
            log.warning("the tracker changed its body %d times during the recording; the BVH uses the last "
                        "(%s)", len(distinct) - 1, self.bodies[-1].body_model)
        return body_from_body_info(self.bodies[-1])


@dataclass(frozen=True)
class RecordingArrays:
    """A recording as arrays (frames sorted by ``seq``, duplicates dropped).

    Attributes
    ----------
    seq : (F,) int64
    capture_ts : (F,) float64
    poses : (F, P) float64
    joints : (F, J, 3) float64
    confidence : (F,) float64
    """

    seq: NDArray[np.int64]
    capture_ts: NDArray[np.float64]
    poses: NDArray[np.float64]
    joints: NDArray[np.float64]
    confidence: NDArray[np.float64]

    @property
    def n_frames(self) -> int:
        return int(self.seq.shape[0])

    def fps(self, default: float = 30.0) -> float:
        """Frames per second from the median capture interval (``default`` with fewer than two frames)."""
        dt = np.diff(self.capture_ts)
        dt = dt[dt > 0]
        return float(1.0 / np.median(dt)) if len(dt) else default


def frames_to_arrays(frames: list[PoseFrame]) -> RecordingArrays:
    """The frames as arrays, sorted by ``seq`` (a repeated ``seq`` keeps its first frame)."""
    by_seq: dict[int, PoseFrame] = {}
    for f in frames:
        by_seq.setdefault(int(f.seq), f)
    ordered = [by_seq[s] for s in sorted(by_seq)]
    return RecordingArrays(
        seq=np.array([f.seq for f in ordered], dtype=np.int64),
        capture_ts=np.array([f.capture_ts for f in ordered], dtype=np.float64),
        poses=np.array([f.pose for f in ordered], dtype=np.float64).reshape(-1, POSE_SIZE),
        joints=np.array([f.joints for f in ordered], dtype=np.float64).reshape(-1, N_JOINTS, 3),
        confidence=np.array([f.confidence for f in ordered], dtype=np.float64),
    )


def write_jsonl(path: str | Path, frames: RecordingArrays) -> None:
    """One JSON object per frame: ``seq``, ``capture_ts``, ``joints`` ((J, 3) metres, order
    :data:`protocol.skeleton.JOINT_NAMES`) and ``confidence``."""
    with Path(path).open("w") as fh:
        for k in range(frames.n_frames):
            fh.write(json.dumps({"seq": int(frames.seq[k]), "capture_ts": float(frames.capture_ts[k]),
                                 "joints": np.round(frames.joints[k], 6).tolist(),
                                 "confidence": round(float(frames.confidence[k]), 6)}) + "\n")


def csv_header() -> list[str]:
    """``seq, t, pelvis_x, pelvis_y, pelvis_z, spine_x, ...``."""
    return ["seq", "t", *[f"{n}_{a}" for n in JOINT_NAMES for a in "xyz"]]


def write_csv(path: str | Path, frames: RecordingArrays) -> None:
    """A header, then per frame ``seq``, ``t`` (seconds since the first frame's capture) and the
    joints' ``x, y, z`` in metres."""
    t0 = float(frames.capture_ts[0]) if frames.n_frames else 0.0
    with Path(path).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(csv_header())
        for k in range(frames.n_frames):
            w.writerow([int(frames.seq[k]), f"{frames.capture_ts[k] - t0:.6f}",
                        *(f"{v:.6f}" for v in frames.joints[k].reshape(-1))])


_DEF = re.compile(r"^(\s*)(ROOT|JOINT) (\S+)\s*$")


def write_recording_bvh(path: str | Path, poses: NDArray[np.float64], body: Body, fps: float,
                        names: BvhNames = "conventional") -> None:
    """The poses on ``body``'s skeleton as a BVH (:func:`protocol.formats.bvh.write_bvh`), with the
    joints named :data:`CONVENTIONAL_NAMES` (``names="conventional"``) or as in the project."""
    write_bvh(path, poses, body, fps)
    if names == "native":
        return
    p = Path(path)
    lines = p.read_text().split("\n")
    for k, line in enumerate(lines):
        if line.startswith("MOTION"):
            break
        m = _DEF.match(line)
        if m:
            lines[k] = f"{m.group(1)}{m.group(2)} {CONVENTIONAL_NAMES[m.group(3)]}"
    p.write_text("\n".join(lines))


def bvh_joint_positions(bvh: BvhFile, scale: float = 0.01) -> NDArray[np.float64]:
    """(F, J, 3) world positions of our joints in a BVH written by :func:`write_recording_bvh`
    (either naming): the forward kinematics of :func:`protocol.formats.bvh.bvh_fk`, and the end
    joints from their parents' ``End Site``\\ s. ``scale``: file units -> metres (cm: 0.01)."""
    pos, rot = bvh_fk(bvh, scale)
    ours = {v: k for k, v in CONVENTIONAL_NAMES.items()}
    out = np.full((bvh.n_frames, N_JOINTS, 3), np.nan)
    for k, bj in enumerate(bvh.joints):
        j = JOINT_INDEX[ours.get(bj.name, bj.name)]
        out[:, j] = pos[:, k]
        if bj.end_site is not None:
            ends = [c for c, par in enumerate(PARENTS) if par == j]
            if len(ends) == 1:
                out[:, ends[0]] = pos[:, k] + np.einsum("fij,j->fi", rot[:, k], bj.end_site * scale)
    return out


def _receive(session: zenoh.Session, tid: str, rec: Recording, stop: threading.Event, deadline: float | None,
             first_pose: threading.Event | None, body_timeout: float) -> None:
    pose_sub = session.declare_subscriber(pose_key(tid))
    body_sub = session.declare_subscriber(body_key(tid))
    try:
        if body_timeout > 0:  # the body is put only when it changes: ask the tracker's queryable for it now
            info = _query_body(session, tid, min(body_timeout, 1.0))
            if info is not None:
                rec.bodies.append(info)
        while not stop.is_set() and (deadline is None or time.monotonic() < deadline):
            busy = False
            while (sample := body_sub.try_recv()) is not None:
                busy = True
                try:
                    rec.bodies.append(decode(sample.payload.to_bytes(), BodyInfo))
                except ProtocolError as exc:
                    rec.decode_errors += 1
                    log.warning("undecodable BodyInfo: %s", exc)
            while (sample := pose_sub.try_recv()) is not None:
                busy = True
                try:
                    rec.frames.append(decode(sample.payload.to_bytes(), PoseFrame))
                except ProtocolError as exc:
                    rec.decode_errors += 1
                    log.warning("undecodable PoseFrame: %s", exc)
                if first_pose is not None and not first_pose.is_set():
                    first_pose.set()
                    log.info("receiving poses of tracker %r", tid)
            if not busy:
                stop.wait(0.005)
    finally:
        pose_sub.undeclare()
        body_sub.undeclare()


def _query_body(session: zenoh.Session, tid: str, timeout: float) -> BodyInfo | None:
    try:
        for reply in session.get(body_key(tid), timeout=timeout):
            if reply.ok is not None:
                return decode(reply.ok.payload.to_bytes(), BodyInfo)
    except (zenoh.ZError, ProtocolError) as exc:
        log.warning("body query failed: %s", exc)
    return None


def record_session(conf: zenoh.Config, options: RecordOptions, stop: threading.Event) -> Recording:
    """Subscribe to the tracker's pose and body keys until ``stop`` or ``options.duration`` seconds;
    the tracker's body queryable is asked at the start, and again at the end when no ``BodyInfo``
    arrived. Channel subscribers, undeclared
    in ``finally``; the session is closed on return."""
    from protocol.net.session import open_session

    tid = validate_id(options.tracker_id)
    rec = Recording()
    with open_session(conf) as session:
        deadline = None if options.duration is None else time.monotonic() + options.duration
        log.info("recording %s%s", pose_key(tid), "" if options.duration is None else f" for {options.duration} s")
        _receive(session, tid, rec, stop, deadline, threading.Event(), options.body_timeout)
        if not rec.bodies and rec.frames and options.body_timeout > 0:
            info = _query_body(session, tid, options.body_timeout)
            if info is not None:
                rec.bodies.append(info)
    return rec


@dataclass(frozen=True)
class RecordSummary:
    """What :func:`save_recording` wrote: poses, poses missing between the first and the last
    ``seq``, the frame rate, the files, the BVH's body model (None: no BVH) and undecodable messages."""

    frames: int
    missing: int
    fps: float
    files: tuple[str, ...]
    body: str | None
    decode_errors: int


def save_recording(rec: Recording, options: RecordOptions) -> RecordSummary:
    """Write the files ``options`` names; returns what was written.

    Raises
    ------
    RuntimeError
        No pose was received.
    """
    if not rec.frames:
        raise RuntimeError(f"no pose received on {pose_key(options.tracker_id)} (is the tracker running, and "
                           "reachable with these --connect/--listen settings?)")
    arrays = frames_to_arrays(rec.frames)
    fps = arrays.fps()
    written: list[str] = []
    body_name = None
    if options.bvh:
        body = rec.body()
        if body is None:
            body = default_body()
            log.warning("no BodyInfo from tracker %r: the BVH uses the default skeleton, so its joints differ "
                        "from the published ones", options.tracker_id)
        body_name = body.name
        Path(options.bvh).parent.mkdir(parents=True, exist_ok=True)
        write_recording_bvh(options.bvh, arrays.poses, body, fps, options.bvh_names)
        written.append(options.bvh)
    if options.jsonl:
        Path(options.jsonl).parent.mkdir(parents=True, exist_ok=True)
        write_jsonl(options.jsonl, arrays)
        written.append(options.jsonl)
    if options.csv:
        Path(options.csv).parent.mkdir(parents=True, exist_ok=True)
        write_csv(options.csv, arrays)
        written.append(options.csv)
    gaps = int(arrays.seq[-1] - arrays.seq[0] + 1 - arrays.n_frames)
    return RecordSummary(frames=arrays.n_frames, missing=gaps, fps=round(fps, 3), files=tuple(written),
                         body=body_name, decode_errors=rec.decode_errors)


def read_recording_bvh(path: str | Path) -> NDArray[np.float64]:
    """The (F, J, 3) joints of a BVH written by ``mocap-tracker record`` (metres)."""
    return bvh_joint_positions(read_bvh(path, offset_mode="add"))
