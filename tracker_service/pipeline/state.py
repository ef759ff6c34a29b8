"""The tracker's state between frames and its result for one frame (:mod:`tracker_service.pipeline.process`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import Body
from tracker_service.cues.reading_filter import ReadingState
from tracker_service.cues.shoes import ShoeModel
from tracker_service.estimators.tree_filter.filter import initial_state
from tracker_service.pipeline.camera_estimate import CameraEstimate
from tracker_service.pipeline.smoothing import SmoothState
from tracker_service.silhouette.background import BackgroundModel

__all__ = ["FrameResult", "Phase", "TrackerState", "new_state"]

Phase = Literal["learning", "waiting", "initialising", "tracking"]


@dataclass(frozen=True)
class TrackerState:
    """Everything carried from one frame to the next."""

    phase: Phase
    background: BackgroundModel | None
    learning: tuple[NDArray[np.uint8], ...]
    filter: Any  # the estimator's state (FilterState for the tree filter)
    body: Body
    body_scale: float
    body_scores: dict[str, list[float]]
    statures: tuple[float, ...] = ()
    frames_in_phase: int = 0
    reinits: int = 0
    clock: float = 0.0
    smooth: SmoothState | None = None
    shoe_samples: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...] = ()
    shoes: ShoeModel | None = None
    bone_readings: tuple[NDArray[np.float64], ...] = ()
    proportions_set: bool = False
    base_body: Body | None = None  # the model before the proportions were read (proportions.py)
    reading: ReadingState | None = None  # the network's readings filtered over time (reading_filter.py)
    withheld: int = 0  # consecutive frames whose pose was withheld (TrackerConfig.min_confidence)
    relearning: bool = False  # learning the background again, robustly (a person was in it)
    relearns: int = 0
    supported: int = 0  # poses published since the background was learned
    ghost_run: int = 0  # consecutive frames whose silhouette was a ghost (silhouette/ghost.py)
    ghost_recent: tuple[float, ...] = ()  # the last frames' ghost fractions
    pending: int = 0  # consecutive good poses withheld before the first one (TrackerConfig.confirm_frames)
    camera_estimate: CameraEstimate | None = None  # the camera's placement measured from its frames
    init_rows: tuple[tuple[float, float], ...] = ()  # the silhouette's (feet, head) rows while initialising
    estimator: Any = None  # a particle filter (its state is ``filter``); None for the tree filter
    last_feet_scale: float | None = None  # the feet line's scale when the feet were last in view (observe.py)
    feet_cut: int = 0  # consecutive frames whose silhouette ran off the image's bottom border


@dataclass(frozen=True)
class FrameResult:
    """Output of :func:`process_frame` for one frame.

    Attributes
    ----------
    phase : str
    silhouette : (H, W) bool or None
    pose : (P,) float64 or None
        World pose (root placed in the scene), None until tracking.
    joints : (J, 3) float64 or None
    visibility : (N_PARTS,) float32
    confidence : float
        In [0, 1]: how close the pose probably is to the truth
        (:mod:`tracker_service.pipeline.confidence`; the silhouette match's without the reading).
    distance : float
    evaluations : tuple of int
    stage_ms : dict[str, float]
        ``background``, ``preprocess``, ``estimate`` (of which ``filter``: the cues and the filter
        step; ``appearance``: the appearance cue's network) and ``total`` milliseconds.
    reinitialised : bool
    body_changed : bool
        The body model was (re)chosen in this frame.
    rejected : str or None
        Why this frame's pose was withheld (``pose`` and ``joints`` are None): ``'depth'``,
        ``'height'`` or ``'non-finite'`` when the estimate put the person where no person can be seen
        from this camera (:func:`tracker_service.pipeline.process.implausible`), ``'low-confidence'``
        below ``TrackerConfig.min_confidence``, ``'ghost'`` when the silhouette is the ghost of a person
        learned into the background (:mod:`tracker_service.silhouette.ghost`), ``'confirming'`` for the
        first good poses after the background was learned (``TrackerConfig.confirm_frames``).
    ghost : float
        The silhouette's ghost fraction (0 when not judged).
    """

    phase: Phase
    silhouette: NDArray[np.bool_] | None
    pose: NDArray[np.float64] | None
    joints: NDArray[np.float64] | None
    visibility: NDArray[np.float32]
    confidence: float
    distance: float
    evaluations: tuple[int, ...]
    stage_ms: dict[str, float]
    reinitialised: bool = False
    body_changed: bool = False
    rejected: str | None = None
    ghost: float = 0.0


def new_state(body: Body, background: BackgroundModel | None = None) -> TrackerState:
    """Initial state; ``learning`` unless a background model is given."""
    return TrackerState(phase="waiting" if background is not None else "learning", background=background,
                        learning=(), filter=initial_state(), body=body, body_scale=1.0, body_scores={})
