"""The public Python API: a ready tracker in one line.

>>> from tracker_service import Tracker
>>> tracker = Tracker()                      # doctest: +SKIP
>>> pose = tracker.process(frame, t=0.0)     # doctest: +SKIP

:class:`Tracker` wraps the same pipeline as ``mocap-tracker run`` with the same defaults (the
template database, built on first use; the body chosen from the family of 30 on the first frames;
the skin and shoe cues; the appearance cue when its network is available; the database's camera).
Each call of :meth:`Tracker.process` advances the pure pipeline
(:func:`tracker_service.pipeline.process.process_frame`) by one frame and returns the
:class:`~protocol.wire.messages.PoseFrame` a tracker would publish, or None while it learns the
background, waits for a person or initialises.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from protocol.wire.messages import PoseFrame
from tracker_service.app.options import TrackerOptions
from tracker_service.app.resources import ensure_db, requested_camera
from tracker_service.app.tracker_config import tracker_config
from tracker_service.camera import Camera
from tracker_service.paths import REPO_ROOT
from tracker_service.pipeline.process import (
    FrameResult,
    TrackerConfig,
    TrackerState,
    advice,
    new_state,
    process_frame,
)

__all__ = ["Tracker"]

#: The motion of :meth:`Tracker.synthetic_clip` when none is given: a shipped gesture script.
DEFAULT_CLIP = REPO_ROOT / "protocol" / "scripts" / "crouch.toml"


class Tracker:
    """A single-camera tracker: frames in, poses out.

    Parameters
    ----------
    options : TrackerOptions, optional
        The same options as ``mocap-tracker run``'s flags (default: its defaults).
    config : TrackerConfig, optional
        A pipeline configuration to use as it is (overrides what ``options`` would build).
    tracker_id : str
        The id carried by the returned poses.

    Attributes
    ----------
    camera : Camera
        The camera the database was rendered for: frames must be ``(camera.height, camera.width, 3)``.
    state : TrackerState
        The pipeline's state (phase, body, filter).
    last : FrameResult or None
        The last frame's full result (silhouette, stage timings, ...).
    """

    def __init__(self, options: TrackerOptions | None = None, config: TrackerConfig | None = None,
                 tracker_id: str = "python") -> None:
        opts = options or TrackerOptions()
        self._loaded = ensure_db(opts.db, camera=requested_camera(opts))  # templates for the user's camera
        self.config: TrackerConfig = config if config is not None else tracker_config(opts)
        self.camera: Camera = self._loaded.camera
        self.tracker_id = tracker_id
        self.state: TrackerState = new_state(self._loaded.body)
        self.last: FrameResult | None = None
        self._seq = 0

    @property
    def advice(self) -> str:
        """What the person in front of the camera should do now (empty: nothing), e.g. "step aside for
        a moment …" while the room behind them is learned again."""
        return advice(self.state)

    def reset(self) -> None:
        """Forget everything (the background included): the next frames are learned as the empty room."""
        self.state = new_state(self._loaded.body)
        self.last = None

    def process(self, frame: NDArray[np.uint8], t: float | None = None) -> PoseFrame | None:
        """Track one frame.

        Parameters
        ----------
        frame : (H, W, 3) uint8
            BGR frame at the camera's resolution (:attr:`camera`).
        t : float, optional
            Capture time in seconds (default: the previous one plus one frame at 30 Hz).

        Returns
        -------
        PoseFrame or None
            The pose (``joints`` (24, 3) metres in the world, Y up; ``confidence``; ``capture_ts``),
            or None while there is no pose (learning the background, no person, initialising).

        Raises
        ------
        ValueError
            A frame of the wrong size or type.
        """
        wall = time.time()
        self.state, res = process_frame(self.state, frame, self._loaded.db, self._loaded.body, self.camera,
                                        self.config, t)
        self.last = res
        if res.pose is None or res.joints is None:
            return None
        seq, self._seq = self._seq, self._seq + 1
        return PoseFrame(tracker_id=self.tracker_id, seq=seq, capture_ts=float(self.state.clock),
                         publish_ts=time.time(), capture_wall_ts=wall, pose=res.pose.astype(np.float32),
                         joints=res.joints.astype(np.float32),
                         visibility=np.clip(res.visibility, 0, 1).astype(np.float32),
                         confidence=float(np.clip(res.confidence, 0, 1)), estimator=self.config.estimator,
                         body_model=self.state.body.name)

    def synthetic_clip(self, seconds: float = 3.0, seed: int = 1, motion: str | Path | None = None,
                       empty_frames: int = 12) -> NDArray[np.uint8]:
        """Frames of the built-in synthetic scene at this tracker's camera (for trying the API).

        Parameters
        ----------
        seconds : float
            Length of the motion part of the clip.
        seed : int
            The synthetic person and room.
        motion : str or Path, optional
            A BVH recording or gesture script (default: a shipped crouch script).
        empty_frames : int
            Frames of the empty room first (the tracker learns its background from them).

        Returns
        -------
        (T, H, W, 3) uint8
            BGR frames at 30 Hz.
        """
        from protocol.formats.load import load_motion
        from tracker_service.scene.synthetic import SceneConfig, SyntheticScene

        mot = load_motion(motion or DEFAULT_CLIP, fps=30.0)
        cfg = SceneConfig(width=self.camera.width, height=self.camera.height, fps=30.0, empty_prefix=empty_frames)
        scene = SyntheticScene(mot, seed=seed, config=cfg)
        try:
            n = min(scene.n_frames, empty_frames + round(seconds * 30.0))
            return np.stack([scene.frame(i).image for i in range(n)])
        finally:
            scene.close()
