"""The tracker's per-frame pipeline as a pure state machine: frame -> silhouette -> observe (features,
cues) -> estimate (the configured estimator) -> publish (refinement, placement, smoothing) -> pose,
joints, visibility and confidence. A pose the silhouette does not support (an implausible pelvis, or a
confidence below ``TrackerConfig.min_confidence``) is withheld and leaves no trace in the publishing
stages; when no pose was supported since the background was learned, the background is learned again,
robustly (a person in view at start).

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
from dataclasses import replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import N_PARTS, Body
from tracker_service.body.kinematics import fk
from tracker_service.camera import Camera
from tracker_service.cues.appearance import camera_joints
from tracker_service.cues.shoes import band_pixels, learn_shoes
from tracker_service.estimators import make_estimator
from tracker_service.estimators.base import Estimate
from tracker_service.estimators.tree_filter.filter import FilterDB, FilterState, TreeFilter
from tracker_service.pipeline.body_selection import BodyChoice, candidates_near, measured_stature, score_bodies
from tracker_service.pipeline.camera_estimate import (
    ASSUMED_STATURE_M,
    CameraEstimate,
    differs,
    room_estimate,
    silhouette_rows,
    with_height,
)
from tracker_service.pipeline.confidence import pose_confidence
from tracker_service.pipeline.config import TrackerConfig
from tracker_service.pipeline.observe import FrameEvidence, observe
from tracker_service.pipeline.publish import Transition, publish
from tracker_service.pipeline.state import FrameResult, Phase, TrackerState, new_state
from tracker_service.silhouette.background import (
    learn_background,
    learn_background_robust,
    subtract,
    update_background,
)
from tracker_service.silhouette.features import preprocess
from tracker_service.silhouette.ghost import ghost_fraction
from tracker_service.silhouette.placement import feet_scale

__all__ = ["FEET_CUT_ADVICE_FRAMES", "FrameResult", "TrackerConfig", "TrackerState", "advice", "force_loss",
           "implausible", "new_state", "process_frame"]

log = logging.getLogger(__name__)

#: Where a tracked person can be: the pelvis's depth in front of the camera and its height over the floor
#: (metres). Outside, the silhouette is not a person standing in the room (a background learned with the
#: person in it, a camera that moved) and the pose is withheld. At 8 m a person is 40 pixels tall in the
#: working image (320x240, 62.7 degree lens): too small to track.
PLAUSIBLE_DEPTH_M = (0.5, 8.0)
PLAUSIBLE_PELVIS_HEIGHT_M = (-0.5, 2.5)
#: Frames in a row with the feet cut off by the bottom border before the person is advised to step
#: back (:func:`advice`): the depth is then only bounded (``pipeline/observe.py: nearest_scale``).
FEET_CUT_ADVICE_FRAMES = 30


def implausible(joints: NDArray[np.float64], camera: Camera) -> str | None:
    """Why a pose cannot be a person in front of ``camera`` (None when it can).

    Parameters
    ----------
    joints : (J, 3) float64
        World joints, the pelvis first.
    camera : Camera

    Returns
    -------
    str or None
        ``'non-finite'``, ``'depth'`` (the pelvis closer than 0.5 m or further than 8 m) or
        ``'height'`` (the pelvis below the floor or above 2.5 m).
    """
    if not np.isfinite(joints).all():
        return "non-finite"
    depth = float(camera.depth(joints[:1])[0])
    if not PLAUSIBLE_DEPTH_M[0] <= depth <= PLAUSIBLE_DEPTH_M[1]:
        return "depth"
    if not PLAUSIBLE_PELVIS_HEIGHT_M[0] <= float(joints[0, 1]) <= PLAUSIBLE_PELVIS_HEIGHT_M[1]:
        return "height"
    return None


def advice(state: TrackerState) -> str:
    """What the person in front of the camera should do now, in words for them (empty: nothing);
    published in :class:`protocol.wire.messages.TrackerStatus`.

    Parameters
    ----------
    state : TrackerState

    Returns
    -------
    str
    """
    if state.phase == "learning":
        if state.relearning:
            return ("step aside for a moment, or move around: the room behind you is being learned again "
                    "(you were in view when the tracker started)")
        return "keep out of the camera's view for a moment: the empty room is being learned"
    if state.ghost_run > 0:
        return "move a little: part of the room was learned with you in it"
    if state.phase == "waiting":
        return "step into the middle of the camera's view"
    if state.phase == "tracking" and state.feet_cut >= FEET_CUT_ADVICE_FRAMES:
        return ("step back a little, or tilt the camera down: your feet are out of the picture, and your "
                "distance is measured from them")
    return ""


def _near_centre(mask: NDArray[np.bool_], radius: float) -> bool:
    xs = np.nonzero(mask)[1]
    return bool(len(xs)) and abs(float(xs.mean()) - mask.shape[1] / 2) <= radius * mask.shape[1]


def _estimator(state: TrackerState, db: FilterDB, db_body: Body, camera: Camera, config: TrackerConfig
               ) -> tuple[Any, TrackerState]:
    """The configured estimator: the tree filter over ``db`` (stateless: its state is ``filter``), or a
    particle filter made on first use and kept in the state (it renders ``db_body`` for ``camera``)."""
    if config.estimator == "tree":
        return TreeFilter(db, config.filter), state
    if state.estimator is None or state.estimator.name != config.estimator:
        est = make_estimator(config.estimator, db, db_body, camera, config.filter, config.estimator_seed)
        state = replace(state, estimator=est, filter=est.init())
    return state.estimator, state


def force_loss(state: TrackerState, db: FilterDB, db_body: Body, camera: Camera, config: TrackerConfig
               ) -> TrackerState:
    """The estimator restarted with no pose information at its current placement (the evaluation's
    forced losses: re-acquisition is measured from here)."""
    estimator, state = _estimator(state, db, db_body, camera, config)
    return replace(state, filter=estimator.init(getattr(state.filter, "placement", None)))


def _learn(state: TrackerState, frame: NDArray[np.uint8], camera: Camera, config: TrackerConfig) -> TrackerState:
    """The learning phase: collect empty-room frames, then learn the background (§2.2). When
    re-learning (a person was learned into the background), every ``relearn_every``-th frame over a
    few seconds, learned robustly (per-pixel medians: the room behind a moving person)."""
    if state.relearning:
        n = state.frames_in_phase + 1
        frames = (*state.learning, frame) if (n - 1) % config.relearn_every == 0 else state.learning
        if len(frames) >= max(config.relearn_frames, 3):
            return replace(state, phase="waiting", background=learn_background_robust(np.stack(frames)), learning=(),
                           relearning=False, frames_in_phase=0, supported=0, pending=0)
        return replace(state, learning=frames, frames_in_phase=n)
    frames = (*state.learning, frame)
    if len(frames) >= max(config.background_frames, 2):
        background = learn_background(np.stack(frames))
        estimate = state.camera_estimate
        if config.estimate_camera and estimate is None:  # the room's verticals: the camera's tilt and roll
            estimate = room_estimate(background.bright_mean, camera)
        return replace(state, phase="waiting", background=background, learning=(), supported=0,
                       camera_estimate=estimate, pending=0)
    return replace(state, learning=frames)


def _relearn(state: TrackerState, message: str, *args: object) -> TrackerState:
    """Learn the background again, robustly (a person was in view when it was learned); ``message``
    (with ``args``) says why in the log."""
    log.warning(message + ": learning the background again; step aside or move a little so that the camera "
                "sees the room behind you", *args)
    return replace(state, phase="learning", background=None, learning=(), relearning=True, frames_in_phase=0,
                   withheld=0, ghost_run=0, ghost_recent=(), relearns=state.relearns + 1, filter=None, reading=None,
                   smooth=None, last_feet_scale=None, feet_cut=0)


def _withhold(state: TrackerState, config: TrackerConfig, why: str) -> TrackerState:
    """Count a withheld pose; after ``config.relearn_after`` in a row with no pose published since the
    background was learned (fewer than 10: a person in view when it was learned, the silhouette their ghost),
    learn the background again."""
    withheld = state.withheld + 1
    if config.relearn_after <= 0 or withheld < config.relearn_after or state.supported >= 10:
        return replace(state, withheld=withheld)
    return _relearn(state, "no pose the silhouette supports for %d frames (%s)", withheld, why)


def _ghost(state: TrackerState, frame: NDArray[np.uint8], mask: NDArray[np.bool_], config: TrackerConfig
           ) -> tuple[TrackerState, float]:
    """The silhouette's ghost fraction (:mod:`tracker_service.silhouette.ghost`) and the state with the
    recent fractions kept and its run of ghost frames (median of the last ``GhostParams.window`` over
    the threshold, or this one over ``GhostParams.clear``) counted; after ``GhostParams.frames`` in a
    row whose median is over ``GhostParams.relearn_level`` the background is learned again (the person
    was in view when it was learned and has moved)."""
    assert state.background is not None and config.ghost is not None
    if not mask.any():
        return replace(state, ghost_run=0, ghost_recent=()), 0.0
    bg = state.background
    params = config.ghost
    # only the outline where the first background's spread shows motion while it was learned votes ghost
    # (a background learned again is a robust median of a person moving about: its spread says nothing)
    moved = params.motion_factor > 0 and not state.relearns
    g = ghost_fraction(bg.bright_mean, frame, mask, params, bg.smooth_sigma, bg.bright_std if moved else None)
    recent = (*state.ghost_recent, g)[-params.window:]
    level = float(np.median(recent))
    if moved:
        threshold, relearn_level = params.moved_threshold, params.moved_relearn_level
    elif state.supported >= params.start_poses:
        threshold, relearn_level = params.threshold, params.relearn_level
    else:
        threshold = params.threshold_relearned if state.relearns else params.threshold_start
        relearn_level = params.relearn_level
    if level <= threshold and g <= params.clear:
        return replace(state, ghost_run=0, ghost_recent=recent), g
    run = state.ghost_run + 1
    if run >= params.frames and level > relearn_level:
        return _relearn(state, "the silhouette is the ghost of a person learned into the background "
                        "(%d frames, ghost fraction %.2f)", run, level), g
    return replace(state, ghost_run=run, ghost_recent=recent), g


def _report_camera(estimate: CameraEstimate, camera: Camera, stature_known: bool = False) -> None:
    """Log the camera's placement measured from its frames; a warning, with the options to pass, when
    it is clearly not the camera the tracker was given (the height only beyond what an assumed
    stature explains, :func:`~tracker_service.pipeline.camera_estimate.differs`)."""
    if not np.isfinite(estimate.tilt_deg):
        log.info("too few vertical edges in the room (%d) to measure the camera's tilt", estimate.segments)
        return
    log.info("camera measured from its frames: tilt %.1f deg, roll %.1f deg, height %.2f m for a person of "
             "%.2f m (%d vertical edges)", estimate.tilt_deg, estimate.roll_deg, estimate.height_m,
             estimate.stature_m, estimate.segments)
    if differs(estimate, camera, stature_known=stature_known):
        height = f"--camera-height {estimate.height_m:.2f} " if np.isfinite(estimate.height_m) else ""
        log.warning("the camera seems not to be where the tracker assumes it (%s): measured tilt %.1f deg, roll "
                    "%.1f deg, height %.2f m (for a person of %.2f m); for better tracking run with %s--camera-tilt "
                    "%.1f, or give a calibration file with --camera", camera.summary(), estimate.tilt_deg,
                    estimate.roll_deg, estimate.height_m, estimate.stature_m, height, estimate.tilt_deg)


def _initialise(state: TrackerState, frame: NDArray[np.uint8], mask: NDArray[np.bool_], ev: FrameEvidence,
                est: Estimate, pose: NDArray[np.float64], fstate: Any, db: FilterDB, db_body: Body,
                camera: Camera, config: TrackerConfig, estimator: Any) -> Transition:
    """The initialising phase's bookkeeping: statures and silhouette scores of the candidate bodies,
    shoe colour samples; at its end the body model is chosen (or the given one taken), the shoes
    learned and the phase becomes ``tracking``. Outside that phase only the frame count moves.

    Returns
    -------
    Transition
        The next state (``filter`` = ``fstate``, restarted at a new body size) and this frame's flags.
    """
    body_changed = restarted = False
    base_body = state.base_body
    phase: Phase = state.phase
    frames_in_phase = state.frames_in_phase + 1
    scores, statures = state.body_scores, state.statures
    shoe_samples, shoes = state.shoe_samples, state.shoes
    raw, seen = ev.raw_placement, ev.reading
    if phase == "initialising" and config.shoes is not None and ev.feet_seen:
        shoe_samples = (*shoe_samples, band_pixels(frame, mask, config.shoes))
    body, scale = state.body, state.body_scale
    if phase == "initialising" and config.body_candidates and raw is not None:
        # measured whatever tops the silhouette, the head or a raised hand (as the network reads the
        # pose: it sees a raised hand better than the first frames' filter pose)
        tops = seen[0] if seen is not None else camera_joints(fk(pose, db_body), camera, db_body.height)
        # the depth from the filter's template's own lowest row, not the standing toe tips: a stride
        # puts the front foot further ahead (the person read too near and too short), a standing
        # woman's toes less far (too far and too tall)
        at = raw
        if est.leaf >= 0 and (s_feet := feet_scale(mask, db.level_runs[-1].runs(est.leaf), camera.cy)) is not None:
            at = np.array([raw[0], 0.0, s_feet])
        st = measured_stature(mask, at, camera, db_body, tops)
        if np.isfinite(st):
            statures = (*statures, st)
        ref = float(np.median(statures)) if statures else db_body.height
        cands = candidates_near(config.body_candidates, ref)
        sel_feats = preprocess(mask, "xor")  # symmetric: nwXOR's cheap contour misses favour small bodies
        sel_params = replace(config.filter, sigma=(0.02, 0.015, 0.012))
        scores = score_bodies(scores, sel_feats, raw, db, db_body, camera, sel_params, cands)
    init_rows = state.init_rows
    if phase == "initialising" and (rows := silhouette_rows(mask)) is not None:
        init_rows = (*init_rows, rows)
    camera_estimate = state.camera_estimate
    if phase == "initialising" and frames_in_phase >= config.init_frames:
        if config.body_candidates:
            choice: BodyChoice = BodyChoice.from_scores(  # a model the user named is used as it is
                scores, db_body, float(np.median(statures)) if statures else float("nan"),
                sized=len(config.body_candidates) > 1)
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
                fstate = estimator.init(est.placement * np.array([1.0, 1.0, scale / state.body_scale]))
        phase = "tracking"
        frames_in_phase = 0
        if camera_estimate is not None and not np.isfinite(camera_estimate.height_m):
            stature = config.body.height if config.body is not None else ASSUMED_STATURE_M
            camera_estimate = with_height(camera_estimate, list(init_rows), camera, stature)
            _report_camera(camera_estimate, camera, stature_known=config.body is not None)
        if config.shoes is not None and shoe_samples:
            shoes = learn_shoes(np.concatenate([a for a, _ in shoe_samples]),
                                np.concatenate([b for _, b in shoe_samples]), config.shoes)
        shoe_samples = ()
    nxt = replace(state, phase=phase, filter=fstate, body=body, body_scale=scale, body_scores=scores,
                  statures=statures, frames_in_phase=frames_in_phase, shoe_samples=shoe_samples, shoes=shoes,
                  base_body=base_body, init_rows=init_rows, camera_estimate=camera_estimate)
    return Transition(nxt, body_changed, restarted)


def process_frame(state: TrackerState, frame: NDArray[np.uint8], db: FilterDB, db_body: Body, camera: Camera,
                  config: TrackerConfig, timestamp: float | None = None) -> tuple[TrackerState, FrameResult]:
    """Advance the tracker by one camera frame: observe -> estimate -> publish.

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
        state = _learn(state, frame, camera, config)
        ms = {"background": (time.perf_counter() - t0) * 1e3}
        return state, FrameResult(state.phase, None, None, None, empty_vis, 0.0, float("nan"), (), ms)
    assert state.background is not None
    mask = subtract(state.background, frame, config.background)
    # the room follows the light while a person is tracked (5 poses published since the background was
    # learned, the last one too), except where they are; before that nobody knows where a person is (one
    # standing in a background learned with them would be absorbed, their ghost never seen)
    if (config.background_rate > 0 and state.phase == "tracking" and state.supported >= 5 and state.withheld == 0
            and mask.any()):
        guard = config.background_guard_px
        fg = mask if guard <= 0 else cv2.dilate(
            mask.view(np.uint8), cv2.getStructuringElement(cv2.MORPH_RECT, (2 * guard + 1, 2 * guard + 1))).view(bool)
        # alternate rows at twice the rate: the same time constant at half the cost
        rate, rows = min(2.0 * config.background_rate, 0.5), (state.supported % 2, 2)
        state = replace(state, background=update_background(state.background, frame, fg, rate, rows))
    ghost = 0.0
    if config.ghost is not None:
        state, ghost = _ghost(state, frame, mask, config)
        if state.ghost_run > 0 or state.phase == "learning":  # never a pose fitted to a ghost
            ms = {"background": (time.perf_counter() - t0) * 1e3}
            return state, FrameResult(state.phase, mask, None, None, empty_vis, 0.0, float("nan"), (), ms,
                                      rejected="ghost", ghost=ghost)
    t1 = time.perf_counter()
    ms = {"background": (t1 - t0) * 1e3}
    estimator, state = _estimator(state, db, db_body, camera, config)
    if state.phase == "waiting":
        if not _near_centre(mask, config.start_radius):
            return state, FrameResult("waiting", mask, None, None, empty_vis, 0.0, float("nan"), (), ms)
        state = replace(state, phase="initialising", frames_in_phase=0, filter=estimator.init(), body_scores={},
                        statures=(), shoe_samples=(), shoes=None, bone_readings=(), proportions_set=False,
                        reading=None, init_rows=(), last_feet_scale=None, feet_cut=0)
    if not mask.any():  # the person left: wait for them to come back to the centre
        state = replace(state, phase="waiting", filter=estimator.init(), reading=None, withheld=0,
                        last_feet_scale=None, feet_cut=0)
        return state, FrameResult("waiting", mask, None, None, empty_vis, 0.0, float("nan"), (), ms)
    fstate = state.filter
    if not config.occlusion and isinstance(fstate, FilterState):  # eq. 14 off (DM1)
        fstate = replace(fstate, occluded=np.zeros(N_PARTS, bool))
    # observe
    ev = observe(frame, mask, fstate, db, camera, config, state.body_scale, state.shoes, state.phase == "tracking",
                 state.last_feet_scale)
    raw, cut = ev.raw_placement, not ev.feet_seen
    last_feet_scale = float(raw[2]) if raw is not None else state.last_feet_scale if cut else None
    feet_cut = state.feet_cut + 1 if cut else 0
    ms["appearance"] = ev.appearance_ms
    # estimate
    t2 = time.perf_counter()
    fstate, est = estimator.step(fstate, ev.observation)
    t3 = time.perf_counter()
    pose = (est.pose_mean if config.use_mean_pose else est.pose_map).copy()
    # phases: the body chosen while initialising
    chosen = _initialise(state, frame, mask, ev, est, pose, fstate, db, db_body, camera, config, estimator)
    # publish
    pose, move = publish(chosen, state, frame, mask, ev, est, pose, db, db_body, camera, config)
    nxt = replace(move.state, reinits=state.reinits + int(est.reinitialised), last_feet_scale=last_feet_scale,
                  feet_cut=feet_cut)
    joints = fk(pose, nxt.body)
    t4 = time.perf_counter()
    ms |= {"preprocess": ev.preprocess_ms, "estimate": (t4 - t1) * 1e3 - ev.preprocess_ms,
           "filter": (t3 - t2) * 1e3 + (t2 - t1) * 1e3 - ev.preprocess_ms, "total": (t4 - t0) * 1e3}
    why = implausible(joints, camera)  # never a pose without grounds
    if why is None and est.confidence < config.min_confidence:
        why = "low-confidence"
    pending = chosen.state.pending
    if why is None and chosen.state.supported == 0 and pending + 1 < config.confirm_frames:
        why = "confirming"  # the first poses after the background was learned wait for a few good frames
    if why is not None:  # the publishing stages' memory as before them: a withheld pose leaves no trace
        nxt = replace(chosen.state, reinits=nxt.reinits, pending=pending + 1 if why == "confirming" else 0,
                      last_feet_scale=last_feet_scale, feet_cut=feet_cut)
        nxt = _withhold(nxt, config, why)
        return nxt, FrameResult(nxt.phase, mask, None, None, est.visibility, 0.0, est.distance, est.evaluations, ms,
                                est.reinitialised, chosen.body_changed, why, ghost)
    nxt = replace(nxt, withheld=0, supported=nxt.supported + 1, pending=0)
    confidence = pose_confidence(move.error_m, est.confidence)  # how far the pose probably is from the truth
    return nxt, FrameResult(nxt.phase, mask, pose, joints, est.visibility, confidence, est.distance,
                            est.evaluations, ms, est.reinitialised, move.body_changed, ghost=ghost)
