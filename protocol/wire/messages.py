"""Messages exchanged over Zenoh. Frozen dataclasses; each carries a ``schema_version``.

Arrays are numpy ``float32`` inside the program and plain msgpack lists on the wire (see
``docs/PROTOCOL.md`` and :mod:`protocol.wire.codec`). Shapes and units are stated per field; the codec
enforces them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Final

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import CAPSULES, JOINT_NAMES, N_CAPSULES, N_JOINTS, N_PARTS, PARENTS, POSE_SIZE, Body

__all__ = [
    "SCHEMA_VERSION",
    "BodyInfo",
    "PoseFrame",
    "TrackerState",
    "TrackerStatus",
    "body_from_body_info",
    "body_info_from_body",
]

#: Version of every message type defined here. Bumped on any incompatible change.
SCHEMA_VERSION: Final[int] = 3


class TrackerState(StrEnum):
    """Life cycle of a tracker (or replay publisher)."""

    STARTING = "starting"
    WAITING = "waiting"  # learning the background / waiting for a person near the image centre
    INITIALISING = "initialising"  # choosing the body model, first pose
    TRACKING = "tracking"
    LOST = "lost"  # likelihood collapsed; re-initialising
    STOPPED = "stopped"


def _frozen_array(a: NDArray[np.float32] | list[float], shape: tuple[int, ...], name: str) -> NDArray[np.float32]:
    arr = np.array(a, dtype=np.float32, copy=True)
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class PoseFrame:
    """One tracked (or replayed) frame.

    Attributes
    ----------
    tracker_id : str
        Identifier of the publishing tracker (also in the key expression).
    seq : int
        Frame sequence number, starts at 0 and increases by 1 per published frame (gaps = drops).
    capture_ts : float
        Stream time of the camera frame, seconds (monotonic within a tracker run).
    publish_ts : float
        Wall-clock time of publication, seconds since the Unix epoch.
    capture_wall_ts : float
        Wall-clock time the tracker got the frame (a camera's read returned, a file's frame was
        decoded, the synthetic scene drew it), seconds since the Unix epoch, never after
        ``publish_ts``: ``publish_ts - capture_wall_ts`` is the tracker's own latency, a client's
        receipt time minus it the latency from capture to that client (same host or synchronised
        clocks). A replay of recorded poses sets it to ``publish_ts``.
    pose : (P,) float32
        Pose vector, layout in :mod:`protocol.skeleton` (P = 60).
    joints : (J, 3) float32
        World joint positions, metres, Y up (J = 24, order :data:`JOINT_NAMES`).
    visibility : (N_PARTS,) float32
        Visible fraction in [0, 1] of each body part's projected area (0 = fully occluded).
    confidence : float
        Match confidence in [0, 1] (1 = perfect silhouette match; replayed ground truth is 1).
    estimator : str
        Estimator that produced the pose (``"tree"``, ``"condensation"``, ``"replay"``, ...).
    body_model : str
        Name of the body model in use (the matching ``BodyInfo`` is on the ``body`` key).
    schema_version : int
        Always :data:`SCHEMA_VERSION` for messages built by this version.
    """

    tracker_id: str
    seq: int
    capture_ts: float
    publish_ts: float
    capture_wall_ts: float
    pose: NDArray[np.float32]
    joints: NDArray[np.float32]
    visibility: NDArray[np.float32]
    confidence: float
    estimator: str
    body_model: str
    schema_version: int = SCHEMA_VERSION

    def __post_init__(self) -> None:
        object.__setattr__(self, "pose", _frozen_array(self.pose, (POSE_SIZE,), "pose"))
        object.__setattr__(self, "joints", _frozen_array(self.joints, (N_JOINTS, 3), "joints"))
        object.__setattr__(self, "visibility", _frozen_array(self.visibility, (N_PARTS,), "visibility"))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, PoseFrame):
            return NotImplemented
        return _fields_equal(self, other)

    __hash__ = None  # type: ignore[assignment]

    @property
    def occluded(self) -> NDArray[np.bool_]:
        """(N_PARTS,) bool: parts with no visible pixel (eq. 14's occlusion test)."""
        return self.visibility <= 0.0


@dataclass(frozen=True)
class BodyInfo:
    """Everything a client needs to rebuild the avatar without tracker code.

    Attributes
    ----------
    tracker_id : str
    body_model : str
        Model name (e.g. ``"mMA"``).
    measurements : dict[str, float]
        ``height_m``, ``chest_m``, ``waist_m``, ``hip_m``, ``shoulder_width_m`` and optionally
        ``weight_kg``; metres / kilograms.
    joint_names : tuple[str, ...]
        The skeleton's joint names, (J,).
    parents : tuple[int, ...]
        Parent index of each joint, -1 for the root, (J,).
    offsets : (J, 3) float32
        Rest (T-pose) offset of each joint from its parent in the parent's frame, metres.
    bone_lengths : (J,) float32
        ``|offsets|`` per joint (0 for the root), metres.
    capsule_names : tuple[str, ...]
        Names of the body capsules, (C,).
    capsule_joints : (C, 2) int
        Joint indices at the two ends of each capsule.
    capsule_radii : (C, 2) float32
        Radius at each end of each capsule, metres.
    schema_version : int
    """

    tracker_id: str
    body_model: str
    measurements: dict[str, float]
    offsets: NDArray[np.float32]
    capsule_radii: NDArray[np.float32]
    joint_names: tuple[str, ...] = JOINT_NAMES
    parents: tuple[int, ...] = PARENTS
    capsule_names: tuple[str, ...] = tuple(c[0] for c in CAPSULES)
    capsule_joints: tuple[tuple[int, int], ...] = tuple(
        (JOINT_NAMES.index(c[2]), JOINT_NAMES.index(c[3])) for c in CAPSULES
    )
    schema_version: int = SCHEMA_VERSION
    bone_lengths: NDArray[np.float32] = field(init=False)

    def __post_init__(self) -> None:
        off = _frozen_array(self.offsets, (N_JOINTS, 3), "offsets")
        object.__setattr__(self, "offsets", off)
        object.__setattr__(self, "capsule_radii", _frozen_array(self.capsule_radii, (N_CAPSULES, 2), "capsule_radii"))
        bl = np.linalg.norm(off.astype(np.float64), axis=1).astype(np.float32)
        bl.setflags(write=False)
        object.__setattr__(self, "bone_lengths", bl)
        object.__setattr__(self, "measurements", dict(self.measurements))
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        object.__setattr__(self, "parents", tuple(int(p) for p in self.parents))
        object.__setattr__(self, "capsule_names", tuple(self.capsule_names))
        object.__setattr__(self, "capsule_joints", tuple((int(a), int(b)) for a, b in self.capsule_joints))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, BodyInfo):
            return NotImplemented
        return _fields_equal(self, other)

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class TrackerStatus:
    """Periodic health report of a tracker or replay publisher.

    Attributes
    ----------
    tracker_id : str
    state : TrackerState
    ts : float
        Wall-clock time, seconds since the Unix epoch.
    uptime_s : float
        Seconds since the process started.
    fps : float
        Frames processed per second over the last reporting interval.
    frames : int
        Frames published since start.
    counters : dict[str, int]
        Error and event counters (``bad_frames``, ``dropped_frames``, ``reinitialisations``,
        ``decode_errors``, ...), all >= 0.
    stage_ms : dict[str, float]
        Mean milliseconds per frame of each pipeline stage over the last interval.
    estimator : str
    body_model : str
    advice : str
        What the person in front of the camera should do now, in words for them (empty when
        nothing): e.g. step aside while the room behind them is learned again.
    camera : dict[str, float]
        The camera's placement as measured from its own frames (empty until measured):
        ``tilt_deg`` (down positive), ``roll_deg``, ``height_m`` (metres above the floor for a
        person of ``stature_m``).
    schema_version : int
    """

    tracker_id: str
    state: TrackerState
    ts: float
    uptime_s: float
    fps: float
    frames: int
    counters: dict[str, int] = field(default_factory=dict)
    stage_ms: dict[str, float] = field(default_factory=dict)
    estimator: str = ""
    body_model: str = ""
    advice: str = ""
    camera: dict[str, float] = field(default_factory=dict)
    schema_version: int = SCHEMA_VERSION

    def __post_init__(self) -> None:
        object.__setattr__(self, "state", TrackerState(self.state))
        object.__setattr__(self, "counters", dict(self.counters))
        object.__setattr__(self, "stage_ms", dict(self.stage_ms))
        object.__setattr__(self, "camera", dict(self.camera))


def _fields_equal(a: object, b: object) -> bool:
    for name in a.__dataclass_fields__:  # type: ignore[attr-defined]
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if not np.array_equal(np.asarray(x), np.asarray(y)):
                return False
        elif x != y:
            return False
    return True


def body_info_from_body(body: Body, tracker_id: str) -> BodyInfo:
    """The wire description of a :class:`~protocol.skeleton.Body`."""
    return BodyInfo(
        tracker_id=tracker_id,
        body_model=body.name,
        measurements={k: float(v) for k, v in body.measurements.items()},
        offsets=body.offsets.astype(np.float32),
        capsule_radii=body.capsule_radii.astype(np.float32),
    )


def body_from_body_info(info: BodyInfo) -> Body:
    """Rebuild a :class:`~protocol.skeleton.Body` (for :func:`protocol.fk`) from a ``BodyInfo``."""
    return Body(
        name=info.body_model,
        offsets=info.offsets.astype(np.float64),
        capsule_radii=info.capsule_radii.astype(np.float64),
        measurements=dict(info.measurements),
    )
