"""The frozen options of the ``mocap-tracker`` commands and of the app cores they drive.

Each command's parse function (``options_from_args`` in :mod:`tracker_service.app.commands`) turns
its ``argparse.Namespace`` into one of these right after parsing; nothing below the parser sees the
namespace. They describe app wiring (files, ids, limits, which cues are on); the algorithms' own
tuning is the ``*Params`` of the pipeline. This module imports nothing heavy (no pipeline, cv2,
numba or zenoh), so building the parser stays cheap.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

from protocol.wire.keys import DEFAULT_TRACKER_ID

if TYPE_CHECKING:
    import zenoh

    from tracker_service.camera import Camera

__all__ = [
    "BuildDbOptions",
    "DemoOptions",
    "EvalCommandOptions",
    "EvalOptions",
    "Passes",
    "RecordOptions",
    "RenderOptions",
    "ReplayCommandOptions",
    "ReplayOptions",
    "RunCommandOptions",
    "RunOptions",
    "TrackerOptions",
    "TrainAppearanceOptions",
    "ZenohOptions",
]

#: One list of ``(seed, every)`` passes per network of the appearance ensemble.
Passes = tuple[tuple[tuple[int, int], ...], ...]

# ------------------------------------------------------------------------------------ shared


@dataclass(frozen=True)
class ZenohOptions:
    """The Zenoh session settings of ``--mode``, ``--connect``, ``--listen`` and ``--config``
    (None: the role's default, see :func:`protocol.net.session.build_config`)."""

    role: Literal["publisher", "subscriber"] = "subscriber"
    mode: str | None = None
    connect: tuple[str, ...] | None = None
    listen: tuple[str, ...] | None = None
    config_file: str | None = None

    def config(self) -> zenoh.Config:
        """The session configuration (raises FileNotFoundError / ValueError for bad settings)."""
        from protocol.net.session import build_config

        return build_config(self.role, mode=self.mode,
                            connect=None if self.connect is None else list(self.connect),
                            listen=None if self.listen is None else list(self.listen),
                            config_file=self.config_file)


@dataclass(frozen=True)
class TrackerOptions:
    """The tracker options of ``run`` and ``eval`` (turned into a
    :class:`~tracker_service.pipeline.process.TrackerConfig` by
    :func:`tracker_service.app.tracker_config.tracker_config`).

    Attributes
    ----------
    db : str, optional
        Template database folder (None: ``out/db/mMA``, built on first use).
    body : str
        ``auto`` (chosen by silhouette match) or a body model's name.
    measurements : str, optional
        The user's measurements (``height=M,...``), or for ``eval`` ``subject[:KEY,...]``.
    subject_allowed : bool
        Whether ``measurements`` may name the synthetic person's own (``eval``).
    estimator, distance, pose : str
        Pose estimator, silhouette distance, ``mean`` or ``map`` pose.
    occlusion, skin, shoes, smoothing, refine, proportions, reading_filter, floor : bool
        Whether that stage or cue is on.
    max_heading_deg : float, optional
        The user faces the camera within this many degrees (None: any heading).
    smooth_cutoff, smooth_beta : float, optional
        The One Euro filter's minimum cut-off (Hz) and speed coefficient of the joints' and the
        root's rotations (``OneEuroParams.min_cutoff_rot/_root``, ``beta_rot/_root``); None: the
        pipeline's defaults.
    appearance : str, optional
        The appearance network's file, ``off``, or None for the default file when it exists.
    min_confidence : float
        Poses whose confidence is below this are withheld (``TrackerConfig.min_confidence``).
    camera_file : str, optional
        A camera file (JSON in OpenCV's terms, :func:`tracker_service.camera.load_camera_file`):
        the templates are rendered for that camera (None: the default camera, or the shorthands).
    camera_height_m, camera_tilt_deg, fov_deg : float, optional
        Shorthands for the usual set-up (:func:`tracker_service.camera.placed_camera`): camera
        height, tilt (positive: looking down) and horizontal field of view; None: the default
        camera's. All None and no ``camera_file``: the default camera and database, unchanged.
    """

    db: str | None = None
    body: str = "auto"
    measurements: str | None = None
    subject_allowed: bool = False
    estimator: Literal["tree", "condensation", "drs", "srs", "elmo", "drs-cardbox", "srs-cardbox"] = "tree"
    distance: Literal["nwxor", "cwxor", "xor"] = "xor"
    occlusion: bool = True
    max_heading_deg: float | None = None
    skin: bool = True
    shoes: bool = True
    smoothing: bool = True
    appearance: str | None = None
    refine: bool = True
    proportions: bool = True
    reading_filter: bool = True
    floor: bool = True
    pose: Literal["mean", "map"] = "mean"
    smooth_cutoff: float | None = None
    smooth_beta: float | None = None
    min_confidence: float = 0.01
    camera_file: str | None = None
    camera_height_m: float | None = None
    camera_tilt_deg: float | None = None
    fov_deg: float | None = None


# ------------------------------------------------------------------------------ app cores


@dataclass(frozen=True)
class RunOptions:
    """Daemon options (:func:`tracker_service.app.daemon.run_tracker`): id, frame limit, duration,
    status period, real-time pacing, and whether to warm the pipeline up
    (:mod:`tracker_service.pipeline.warmup`) before the first real frame."""

    tracker_id: str = "default"
    max_frames: int | None = None
    duration: float | None = None
    status_interval: float = 1.0
    realtime: bool = True
    fps_hint: float = 30.0
    wait_for_subscriber: float = 0.0
    warm_up: bool = True


@dataclass(frozen=True)
class EvalOptions:
    """Options of :func:`tracker_service.app.evaluate.evaluate_motion`.

    Attributes
    ----------
    frames : int, optional
        Evaluate at most this many motion frames.
    seed : int
        Scene seed (subject, room, lighting, noise).
    empty_prefix : int
        Empty-room frames for background learning.
    force_loss_every_s : float
        Force a tracking loss (the filter is reset to a wrong pose) every this many seconds of
        tracking (0: never); re-acquisition time is measured after each: the time until three
        frames in a row are back within 10 cm (or within 1.25 x the median error of the second
        before the loss, where the track was worse than 10 cm). A loss not yet back in the clip's
        last second is not judged.
    fps : float
        Frame rate of the rendered video.
    in_place_travel_m : float
        Motions whose root travels farther than this are played on the spot (a treadmill), so
        the person stays in view.
    subject_measurements : tuple of str
        Give the tracker these of the scene person's own measurements (keys of
        :func:`tracker_service.app.evaluate.subject_measurements`: ``height``, ``group``, girths,
        ``shoulder``, ``arm``, ``leg``) instead of letting it choose a body model: what a user who
        enters them gets. Empty: the tracker's own choice.
    jpeg_quality : int, optional
        Every rendered frame passes through JPEG at this quality before the tracker sees it (a
        webcam's MJPEG); None: lossless.
    h264_crf : int, optional
        Every rendered frame passes through H.264 (an intra frame at this CRF) first; None: not.
    variation : tuple of str
        Domain-randomisation axes of the scene (:mod:`tracker_service.scene.variation`).
    input_size : (int, int), optional
        Film the scene at this ``(width, height)`` with :func:`~tracker_service.app.evaluate.widened`
        camera and bring every frame to the working size as ``run`` does; None: the working size.
    camera : Camera, optional
        The camera filming the scene (the one given to the tracker: ``--camera`` or the shorthands);
        None: the working camera.
    """

    frames: int | None = None
    seed: int = 0
    empty_prefix: int = 12
    force_loss_every_s: float = 0.0
    fps: float = 30.0
    in_place_travel_m: float = 2.0
    subject_measurements: tuple[str, ...] = ()
    jpeg_quality: int | None = None
    h264_crf: int | None = None
    variation: tuple[str, ...] = ()
    input_size: tuple[int, int] | None = None
    camera: Camera | None = None


@dataclass(frozen=True)
class ReplayOptions:
    """How to publish a replay (:func:`tracker_service.app.replay_daemon.publish_motion`).

    Attributes
    ----------
    tracker_id : str
        Id in the key expressions and messages.
    rate : float, optional
        Output frames per second (default: the motion's own rate).
    loop : bool
        Start again at the end (seq and capture time continue).
    duration : float, optional
        Stop after this many seconds of stream time.
    max_frames : int, optional
        Stop after this many frames.
    wait_for_subscriber : float
        Seconds to wait for a subscriber on the pose key before the first frame (0 = start at
        once). Lets a test or demo receive every frame from ``seq`` 0.
    status_interval : float
        Seconds between ``TrackerStatus`` messages.
    max_burst : int
        Frames the publisher may send back to back when it has fallen behind.
    """

    tracker_id: str = DEFAULT_TRACKER_ID
    rate: float | None = None
    loop: bool = False
    duration: float | None = None
    max_frames: int | None = None
    wait_for_subscriber: float = 0.0
    status_interval: float = 1.0
    max_burst: int = 3


# ----------------------------------------------------------------------------- the commands


@dataclass(frozen=True)
class BuildDbOptions:
    """``mocap-tracker build-db``: which body models, from which recordings and gesture scripts,
    written where (``out`` None: ``out/db/<body>``; with several bodies a parent folder)."""

    bodies: tuple[str, ...] = ("mMA",)
    mocap: str | None = None
    scripts: tuple[str, ...] = ()
    out: str | None = None
    max_poses: int | None = None
    takes: int | None = None


@dataclass(frozen=True)
class TrainAppearanceOptions:
    """``mocap-tracker train-appearance`` (and the training of a missing default network).

    ``None`` is the default of each setting; ``posture_passes`` (``vary_passes``) ``()`` means no
    posture-varied (randomised-scene) passes; ``out`` None is ``out/appearance/net.npz``.
    """

    out: str | None = None
    mocap: str | None = None
    epochs: int | None = None
    width: int | None = None
    passes: Passes | None = None
    posture_passes: Passes | None = None
    vary_passes: Passes | None = None
    members: int | None = None
    takes: int | None = None
    scripts: tuple[str, ...] = ()
    jobs: int = 1
    masks: str | None = None


@dataclass(frozen=True)
class RunCommandOptions:
    """``mocap-tracker run``: the frame source, the tracker, the Zenoh session and the daemon;
    ``video``: write the overlay of every frame (silhouette, skeleton, HUD) to this file; ``fps``:
    the synthetic camera's frame rate (None: the motion's own); ``prerender``: render the synthetic
    scene before tracking."""

    source: str = "synthetic"
    seed: int = 0
    tracker: TrackerOptions = field(default_factory=TrackerOptions)
    zenoh: ZenohOptions = field(default_factory=lambda: ZenohOptions(role="publisher"))
    daemon: RunOptions = field(default_factory=RunOptions)
    video: str | None = None
    fps: float | None = None
    prerender: bool = False


@dataclass(frozen=True)
class EvalCommandOptions:
    """``mocap-tracker eval``: the motion file, the tracker, the evaluation and the output form
    (``json``: only the JSON object on stdout, else a readable summary; ``progress``: frame counts on
    stderr; ``video``: write the overlay of every frame to this file)."""

    motion: str
    tracker: TrackerOptions = field(default_factory=lambda: TrackerOptions(subject_allowed=True))
    evaluation: EvalOptions = field(default_factory=EvalOptions)
    json: bool = False
    progress: bool = True
    video: str | None = None


@dataclass(frozen=True)
class ReplayCommandOptions:
    """``mocap-tracker replay``: the motion (a BVH or script file, or the built-in wave), the Zenoh
    session and how to publish."""

    motion: str | None = None
    synthetic_wave: bool = False
    zenoh: ZenohOptions = field(default_factory=lambda: ZenohOptions(role="publisher"))
    publish: ReplayOptions = field(default_factory=ReplayOptions)


@dataclass(frozen=True)
class RenderOptions:
    """``mocap-tracker render``: the motion file, the output (a folder or a video file) and the
    scene settings (``fps`` None: the motion's own rate)."""

    motion: str
    out: str
    seed: int = 0
    frames: int | None = None
    empty_prefix: int = 0
    fps: float | None = None
    jitter_px: float = 0.0
    noise: bool = True
    in_place: bool = False
    masks: bool = False
    json: bool = False


@dataclass(frozen=True)
class RecordOptions:
    """``mocap-tracker record``: subscribe to a tracker's poses (and body) and write the session.

    Attributes
    ----------
    bvh, jsonl, csv : str, optional
        Output files (at least one is given).
    tracker_id : str
        The tracker whose keys to subscribe to.
    duration : float, optional
        Stop after this many seconds (None: until SIGINT / SIGTERM).
    bvh_names : {'conventional', 'native'}
        Joint names in the BVH: ``Hips``, ``LeftArm``, ... (what Blender and retargeting tools
        expect), or the project's own (``pelvis``, ``l_shoulder``, ...; read back exactly by
        :func:`protocol.formats.load.load_motion`).
    body_timeout : float
        Seconds to wait for the tracker's ``BodyInfo`` (asked with a query) when none arrived.
    zenoh : ZenohOptions
    """

    bvh: str | None = None
    jsonl: str | None = None
    csv: str | None = None
    tracker_id: str = DEFAULT_TRACKER_ID
    duration: float | None = None
    bvh_names: Literal["conventional", "native"] = "conventional"
    body_timeout: float = 2.0
    zenoh: ZenohOptions = field(default_factory=ZenohOptions)


@dataclass(frozen=True)
class DemoOptions:
    """``mocap-tracker demo``: seconds to run, JSON summary only, replay instead of tracking."""

    duration: float = 6.0
    json: bool = False
    replay: bool = False
