"""The tracker's per-frame pipeline as a pure state machine: frame -> silhouette -> features ->
tree filter -> pose, joints, visibility and confidence.

Phases (``TrackerState.phase``):

``learning``      collecting empty-room frames for the background model (§2.2)
``waiting``       no person, or the silhouette is not yet near the image centre (§3: "pose
                  estimation is started when the center of the observed silhouette is close to the
                  image center")
``initialising``  the first frames: the filter starts facing the camera (front/back resolved so)
                  and the body model is chosen from the family by silhouette match
``tracking``      normal operation; after ``lost_frames`` bad matches the filter re-initialises
                  (counted in ``reinits``).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from protocol.kinematics import fk
from protocol.skeleton import JOINT_INDEX, N_PARTS, Body
from tracker_service.body.proportions import (
    ProportionParams,
    adapt_body,
    bone_lengths_read,
    describe,
    proportion_ratios,
)
from tracker_service.camera import Camera
from tracker_service.cues.appearance import (
    AppearanceNet,
    HeadingWindow,
    camera_joints,
    in_view,
    joints_cost,
    predict_joints,
    propose_leaves_in_window,
)
from tracker_service.cues.reading_filter import ReadingFilterParams, ReadingState, filter_reading
from tracker_service.cues.shoes import (
    ShoeModel,
    ShoeParams,
    band_pixels,
    feet_cost,
    foot_points,
    learn_shoes,
    reweight_legs,
    shoe_pixels,
)
from tracker_service.cues.skin import SkinModel, observe_skin
from tracker_service.estimators.tree_filter.filter import (
    FilterDB,
    FilterParams,
    FilterState,
    initial_state,
    step,
    support_heading,
)
from tracker_service.pipeline.body_selection import BodyChoice, candidates_near, measured_stature, score_bodies
from tracker_service.pipeline.refinement import RefineParams, refine_pose
from tracker_service.pipeline.smoothing import OneEuroParams, SmoothState, smooth_pose
from tracker_service.silhouette.background import (
    BackgroundModel,
    BackgroundParams,
    learn_background,
    subtract,
    update_background,
)
from tracker_service.silhouette.features import Distance, preprocess
from tracker_service.silhouette.placement import (
    feet_in_view,
    feet_scale,
    observed_placement,
    placement_to_root,
    scaled_placement,
    silhouette_rows,
)

__all__ = ["FrameResult", "TrackerConfig", "TrackerState", "new_state", "process_frame"]

log = logging.getLogger(__name__)

Phase = Literal["learning", "waiting", "initialising", "tracking"]


@dataclass(frozen=True)
class TrackerConfig:
    """Pipeline options (paper defaults: nwXOR, alpha = 5, beta = 1, m = 5).

    Attributes
    ----------
    distance : {'nwxor', 'cwxor', 'xor'}
    alpha, beta : float
        Weights of eq. 9 and eq. 10.
    occlusion : bool
        Occlusion-aware dynamics (eq. 14, "DM2"); False is "DM1".
    filter : FilterParams
    background : BackgroundParams
    background_frames : int
        Empty frames learned before tracking (0: the caller provides the model).
    background_rate : float
        Adaptive update rate of background pixels (0: off).
    start_radius : float
        Tracking starts when the silhouette's centre is within this fraction of the image width
        from the image centre.
    init_frames : int
        Frames of the initialising phase (body-model selection averages over them).
    body_candidates : tuple of str
        Body models considered by the selection (empty: keep the database's body).
    body : Body or None
        A given body (the user's measurements, :mod:`tracker_service.body.measured`) used from the
        end of the initialisation instead of a selection: templates scaled by its height over the
        database body's, its skeleton in the published joints. Not together with
        ``body_candidates``.
    use_mean_pose : bool
        Publish the posterior-mean pose (tempered, ``FilterParams.mean_temperature``) rather than
        the MAP leaf's pose: on an ambiguous silhouette the mean hedges between the modes.
    depth_from_feet : bool
        Take the subject's depth from the silhouette's feet line (scaled for the body model)
        rather than from the scale of the best template fit.
    skin : SkinModel or None
        Skin colour locus of the hand cue (:mod:`tracker_service.cues.skin`); None: silhouettes only
        (the paper's observation model).
    shoes : ShoeParams or None
        The shoe cue (:mod:`tracker_service.cues.shoes`): the shoes' colour learned while initialising;
        each frame's shoe pixels weigh the leaves in the filter (``FilterParams.shoe_weight``) and
        re-weight the published pose's legs (``ShoeParams.weight``); None: off.
    appearance : AppearanceNet or None
        The appearance cue's network (:mod:`tracker_service.cues.appearance`): the joints' depth read from
        the person's colour image weighs the leaves in the filter (``FilterParams.appearance_weight``);
        None: off.
    appearance_mirror : bool
        Read the person's crop flipped left-right too and pool both readings
        (:func:`tracker_service.cues.appearance.predict_joints`; one batch of two per network of the
        ensemble: it doubles the networks' cost, ~0.8 ms a frame per network).
    refine : RefineParams or None
        With the appearance cue: the published pose's joints are turned toward the network's
        reading, fused with the filter's pose by their variances (:mod:`tracker_service.pipeline.refinement`,
        ELMO's local refinement); None: the filter's pose as it is.
    proportions : ProportionParams or None
        With the appearance cue: after the first frames of tracking, the published skeleton's torso,
        arm and leg bones take the lengths the network reads (:mod:`tracker_service.body.proportions`;
        once per session, ``body_changed`` set; not with a given ``body`` (``--measurements``); only
        from frames where the person is not cut by the image border); None: the selected model's
        proportions. Refinement and proportions use the cue's reading whether or not the filter
        weighs leaves by it (``filter.appearance_weight``); without ``appearance`` both are off.
    reading_filter : ReadingFilterParams or None
        With the refinement: the network's readings are filtered over time by a constant-velocity
        Kalman filter (:mod:`tracker_service.cues.reading_filter`) before the published pose is refined
        toward them (restarted with every tracking session; kept through a re-initialisation);
        None: each frame's raw reading.
    smoothing : OneEuroParams or None
        One Euro filter of the published pose (:mod:`tracker_service.pipeline.smoothing`); None: the raw
        per-frame estimate.
    fps : float
        Frame rate assumed when :func:`process_frame` is given no time stamp.
    """

    distance: Distance = "nwxor"
    alpha: float = 5.0
    beta: float = 1.0
    occlusion: bool = True
    filter: FilterParams = field(default_factory=FilterParams)
    background: BackgroundParams = field(default_factory=BackgroundParams)
    background_frames: int = 10
    background_rate: float = 0.0
    start_radius: float = 0.25
    init_frames: int = 5
    body_candidates: tuple[str, ...] = ()
    body: Body | None = None
    use_mean_pose: bool = True
    depth_from_feet: bool = True
    skin: SkinModel | None = field(default_factory=SkinModel)
    shoes: ShoeParams | None = field(default_factory=ShoeParams)
    appearance: AppearanceNet | None = None
    appearance_mirror: bool = True
    refine: RefineParams | None = field(default_factory=RefineParams)
    proportions: ProportionParams | None = field(default_factory=ProportionParams)
    reading_filter: ReadingFilterParams | None = field(default_factory=ReadingFilterParams)
    smoothing: OneEuroParams | None = field(default_factory=OneEuroParams)
    fps: float = 30.0

    def __post_init__(self) -> None:
        if self.body is not None and self.body_candidates:
            raise ValueError("give either a body or body candidates to choose from, not both")


@dataclass(frozen=True)
class TrackerState:
    """Everything carried from one frame to the next."""

    phase: Phase
    background: BackgroundModel | None
    learning: tuple[NDArray[np.uint8], ...]
    filter: FilterState
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
    distance : float
    evaluations : tuple of int
    stage_ms : dict[str, float]
        ``background``, ``preprocess``, ``estimate`` (of which ``filter``: the cues and the filter
        step; ``appearance``: the appearance cue's network) and ``total`` milliseconds.
    reinitialised : bool
    body_changed : bool
        The body model was (re)chosen in this frame.
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


def new_state(body: Body, background: BackgroundModel | None = None) -> TrackerState:
    """Initial state; ``learning`` unless a background model is given."""
    return TrackerState(phase="waiting" if background is not None else "learning", background=background,
                        learning=(), filter=initial_state(), body=body, body_scale=1.0, body_scores={})


_FEET = np.array([JOINT_INDEX[n] for n in ("l_ankle", "l_toe", "r_ankle", "r_toe")])


def _feet_offset(pose: NDArray[np.float64], body: Body, db_body: Body, scale: float) -> float:
    """How far to raise the root so that ``body``'s lowest foot joint is where the templates' body
    scaled by ``scale`` puts it (metres). Zero for a body of the family's proportions; a body with
    longer or shorter legs (given measurements, a child) would otherwise hang its feet through the
    floor or float above it, since the root is placed from the template's."""
    if body is db_body and scale == 1.0:
        return 0.0
    rel = pose.copy()
    rel[:3] = 0.0
    return float(scale * fk(rel, db_body)[_FEET, 1].min() - fk(rel, body)[_FEET, 1].min())


def _heading_window(fstate: FilterState, db: FilterDB, params: FilterParams) -> HeadingWindow:
    """Where the appearance cue may propose: headings within ``params.max_turn`` of the filter's
    current one (its support's circular mean; facing the camera when it has none) and within
    ``params.max_heading``."""
    if len(fstate.leaves):
        centre, half = support_heading(fstate, db), params.max_turn
    else:
        centre, half = 0.0, np.pi / 2
    return HeadingWindow(centre, half, np.inf if params.max_heading is None else params.max_heading)


def _near_centre(mask: NDArray[np.bool_], radius: float) -> bool:
    xs = np.nonzero(mask)[1]
    return bool(len(xs)) and abs(float(xs.mean()) - mask.shape[1] / 2) <= radius * mask.shape[1]


def process_frame(state: TrackerState, frame: NDArray[np.uint8], db: FilterDB, db_body: Body, camera: Camera,
                  config: TrackerConfig, timestamp: float | None = None) -> tuple[TrackerState, FrameResult]:
    """Advance the tracker by one camera frame.

    Parameters
    ----------
    state : TrackerState
    frame : (H, W, 3) uint8
        BGR frame at the camera's resolution.
    db : FilterDB
    db_body : Body
        Body model the database was rendered with.
    camera : Camera
        The database's camera (frame size must match).
    config : TrackerConfig
    timestamp : float, optional
        Frame time (s) for the output smoothing; default: the previous one plus ``1 / config.fps``.

    Returns
    -------
    state : TrackerState
    result : FrameResult
    """
    t0 = time.perf_counter()
    if frame.ndim != 3 or frame.shape[:2] != (camera.height, camera.width) or frame.dtype != np.uint8:
        raise ValueError(f"frame must be ({camera.height}, {camera.width}, 3) uint8, got {frame.shape} {frame.dtype}")
    clock = float(timestamp) if timestamp is not None else state.clock + 1.0 / config.fps
    state = replace(state, clock=clock)
    empty_vis = np.zeros(N_PARTS, np.float32)
    if state.phase == "learning":
        frames = (*state.learning, frame)
        if len(frames) >= max(config.background_frames, 2):
            bg = learn_background(np.stack(frames))
            state = replace(state, phase="waiting", background=bg, learning=())
        else:
            state = replace(state, learning=frames)
        ms = {"background": (time.perf_counter() - t0) * 1e3}
        return state, FrameResult(state.phase, None, None, None, empty_vis, 0.0, float("nan"), (), ms)
    assert state.background is not None
    mask = subtract(state.background, frame, config.background)
    if config.background_rate > 0:
        fg = mask if mask.any() else np.zeros_like(mask)
        state = replace(state, background=update_background(state.background, frame, fg, config.background_rate))
    t1 = time.perf_counter()
    ms = {"background": (t1 - t0) * 1e3}
    if state.phase == "waiting":
        if not _near_centre(mask, config.start_radius):
            return state, FrameResult("waiting", mask, None, None, empty_vis, 0.0, float("nan"), (), ms)
        state = replace(state, phase="initialising", frames_in_phase=0, filter=initial_state(), body_scores={},
                        statures=(), shoe_samples=(), shoes=None, bone_readings=(), proportions_set=False,
                        reading=None)
    if not mask.any():  # the person left: wait for them to come back to the centre
        state = replace(state, phase="waiting", filter=initial_state(), reading=None)
        return state, FrameResult("waiting", mask, None, None, empty_vis, 0.0, float("nan"), (), ms)
    feats = preprocess(mask, config.distance, config.alpha, config.beta)
    t2 = time.perf_counter()
    raw = observed_placement(mask, camera)  # for the templates' own body size
    # a subject k times the templates' size looks k times larger at that depth, feet on the same row
    obs = None if raw is None else scaled_placement(raw, state.body_scale, camera)
    fstate = state.filter
    if not config.occlusion:
        fstate = replace(fstate, occluded=np.zeros(N_PARTS, bool))
    skin = observe_skin(frame, mask, config.skin) if config.skin is not None else None
    shoe_px = None
    leaf_shoe_cost = None
    feet_seen = feet_in_view(mask)  # shoes are learned, and looked for, only with the feet in the image
    if (state.phase == "tracking" and state.shoes is not None and config.shoes is not None and len(db.leaf_points)
            and feet_seen):
        shoe_px = shoe_pixels(frame, mask, state.shoes, config.shoes)
        shoe_params = config.shoes

        def leaf_shoe_cost(leaves: NDArray[np.int64], places: NDArray[np.float64]) -> NDArray[np.float64] | None:
            assert shoe_px is not None
            return feet_cost(shoe_px, foot_points(db.leaf_points[leaves], places, db.center), shoe_params, mask.shape)

    leaf_appearance_cost = None
    proposals = None
    seen = None
    ta = time.perf_counter()
    # (also when the person is cut by the image border, which no training view shows: skipping those
    # frames was measured worse on all three subjects, docs/TRACKER.md session 24)
    in_filter = config.filter.appearance_weight > 0 and len(db.leaf_joints3d) > 0
    if config.appearance is not None and (in_filter or config.refine is not None or config.proportions is not None):
        seen = predict_joints(config.appearance, frame, mask, config.appearance_mirror)
        if seen is not None and in_filter:
            mu, var = seen
            coords = config.filter.appearance_coords

            def leaf_appearance_cost(leaves: NDArray[np.int64]) -> NDArray[np.float64]:
                return joints_cost(mu, var, db.leaf_joints3d[leaves], coords)

            if config.filter.appearance_proposals > 0:
                scored = np.where(np.isin(np.arange(3), coords), var, np.inf)  # the coordinates the cost counts
                proposals = propose_leaves_in_window(mu, scored, db.leaf_joints3d, config.filter.appearance_proposals,
                                                     db.leaf_heading, _heading_window(fstate, db, config.filter))
    ms["appearance"] = (time.perf_counter() - ta) * 1e3
    fstate, est = step(fstate, db, feats, config.filter, obs, skin, silhouette_rows(mask), leaf_shoe_cost,
                       leaf_appearance_cost, proposals)
    t3 = time.perf_counter()
    pose = (est.pose_mean if config.use_mean_pose else est.pose_map).copy()
    body_changed = False
    restarted = False  # the filter restarted at a new body size: the smoother too
    base_body = state.base_body
    phase: Phase = state.phase
    frames_in_phase = state.frames_in_phase + 1
    scores = state.body_scores
    statures = state.statures
    shoe_samples, shoes = state.shoe_samples, state.shoes
    if phase == "initialising" and config.shoes is not None and feet_seen:
        shoe_samples = (*shoe_samples, band_pixels(frame, mask, config.shoes))
    body, scale = state.body, state.body_scale
    if phase == "initialising" and config.body_candidates and raw is not None:
        # measured whatever tops the silhouette, the head or a raised hand (as the network reads the
        # pose: it sees a raised hand better than the first frames' filter pose)
        tops = seen[0] if seen is not None else camera_joints(fk(pose, db_body), camera, db_body.height)
        st = measured_stature(mask, raw, camera, db_body, tops)
        if np.isfinite(st):
            statures = (*statures, st)
        ref = float(np.median(statures)) if statures else db_body.height
        cands = candidates_near(config.body_candidates, ref)
        sel_feats = preprocess(mask, "xor")  # symmetric: nwXOR's cheap contour misses favour small bodies
        sel_params = replace(config.filter, sigma=(0.02, 0.015, 0.012))
        scores = score_bodies(scores, sel_feats, raw, db, db_body, camera, sel_params, cands)
    if phase == "initialising" and frames_in_phase >= config.init_frames:
        if config.body_candidates:
            choice: BodyChoice = BodyChoice.from_scores(
                scores, db_body, float(np.median(statures)) if statures else float("nan"))
            body, scale = choice.body, choice.scale
        elif config.body is not None:
            body, scale = config.body, config.body.height / db_body.height
        if config.body_candidates or config.body is not None:
            resized = body.name != state.body.name or scale != state.body_scale
            # a changed skeleton is announced too (the proportions read in an earlier session are dropped)
            body_changed = resized or not np.array_equal(body.offsets, state.body.offsets)
            base_body = None
            if resized:  # restart the filter at the new size
                restarted = True
                fstate = initial_state(est.placement * np.array([1.0, 1.0, scale / state.body_scale]))
        phase = "tracking"
        frames_in_phase = 0
        if config.shoes is not None and shoe_samples:
            shoes = learn_shoes(np.concatenate([a for a, _ in shoe_samples]),
                                np.concatenate([b for _, b in shoe_samples]), config.shoes)
        shoe_samples = ()
    if shoe_px is None and phase == "tracking" and shoes is not None and config.shoes is not None and feet_seen:
        shoe_px = shoe_pixels(frame, mask, shoes, config.shoes)  # the frame that learned them
    if (shoe_px is not None and config.shoes is not None and config.use_mean_pose and len(est.support_leaves)
            and config.shoes.weight > 0 and len(db.leaf_points)):
        cost = feet_cost(shoe_px, foot_points(db.leaf_points[est.support_leaves], est.support_places, db.center),
                         config.shoes, mask.shape)
        if cost is not None:
            pose = reweight_legs(pose, db.leaf_poses[est.support_leaves].astype(np.float64), est.support_weights,
                                 cost, config.filter.mean_temperature, config.shoes)
    readings, proportions_set = state.bone_readings, state.proportions_set
    if (seen is not None and config.proportions is not None and config.body is None and phase == "tracking"
            and state.phase == "tracking" and not proportions_set and not body_changed  # a given body is kept
            and in_view(mask)):  # a person cut by the border is a view the network never saw
        readings = (*readings, bone_lengths_read(seen[0], body.height))
        if len(readings) >= config.proportions.frames:
            base = base_body if base_body is not None else body  # always relative to the model
            ratio = proportion_ratios(np.stack(readings), base, config.proportions)
            body, base_body, body_changed, proportions_set, readings = adapt_body(base, ratio), base, True, True, ()
            log.info("body %s: bone proportions from the appearance cue: %s", body.name, describe(ratio) or "unchanged")
    reading = state.reading
    if phase != "tracking":  # (a re-initialisation or a new body size keeps it: the network reads the image)
        reading = None  # a new person or session: the readings' history belongs to the old one
    elif seen is not None and config.reading_filter is not None and config.refine is not None:
        reading, *filtered = filter_reading(reading, clock, seen[0], seen[1], config.reading_filter)
        seen = (filtered[0], filtered[1])
    if seen is not None and config.refine is not None:  # ELMO's local refinement (pose_refinement.py)
        pose = refine_pose(pose, body, camera.pose[:3, :3], seen[0], seen[1], body.height, config.refine)
    place = est.placement.copy()
    if config.depth_from_feet:  # the feet line measures depth better than the template fit's scale
        s_feet = feet_scale(mask, db.level_runs[-1].runs(est.leaf), camera.cy)
        if s_feet is not None and abs(scale * s_feet / place[2] - 1.0) < 0.15:
            # s_feet is the floor-row ratio (the templates' size); the subject is `scale` times it
            place = scaled_placement(np.array([place[0], 0.0, s_feet]), scale, camera)
    pose[:3] = placement_to_root(place, pose[:3], camera, body_scale=scale)
    pose[1] += _feet_offset(pose, body, db_body, scale)
    smooth = state.smooth
    if config.smoothing is not None and phase == "tracking" and not est.reinitialised and not restarted:
        smooth, pose = smooth_pose(smooth, clock, pose, config.smoothing)
    else:
        smooth = None
    joints = fk(pose, body)
    reinits = state.reinits + int(est.reinitialised)
    state = replace(state, phase=phase, filter=fstate, body=body, body_scale=scale, body_scores=scores,
                    statures=statures, frames_in_phase=frames_in_phase, reinits=reinits, smooth=smooth,
                    shoe_samples=shoe_samples, shoes=shoes, bone_readings=readings, proportions_set=proportions_set,
                    base_body=base_body, reading=reading)
    t4 = time.perf_counter()
    ms |= {"preprocess": (t2 - t1) * 1e3, "estimate": (t4 - t2) * 1e3, "filter": (t3 - t2) * 1e3,
           "total": (t4 - t0) * 1e3}
    return state, FrameResult(phase, mask, pose, joints, est.visibility, est.confidence, est.distance,
                              est.evaluations, ms, est.reinitialised, body_changed)
