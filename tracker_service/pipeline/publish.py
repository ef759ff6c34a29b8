"""Publish: the pose the tracker sends, from the estimator's estimate.

After the estimator's step, the published pose goes through the stages beyond the paper: the shoe
cue re-weights the legs of the support's mean; the appearance network's reading sets the bone
proportions once per session (:mod:`tracker_service.body.proportions`), is filtered over time
(:mod:`tracker_service.cues.reading_filter`) and pulls the joints toward it (ELMO's local refinement,
:mod:`tracker_service.pipeline.refinement`); the placement becomes a root position (depth from the
feet line, :mod:`tracker_service.silhouette.placement`); a leg through the floor is bent back onto
it (:mod:`tracker_service.pipeline.floor_contact`); the One Euro filter smooths it
(:mod:`tracker_service.pipeline.smoothing`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import JOINT_INDEX, Body
from tracker_service.body.kinematics import fk
from tracker_service.body.proportions import adapt_body, bone_lengths_read, describe, proportion_ratios
from tracker_service.camera import Camera
from tracker_service.cues.appearance import in_view
from tracker_service.cues.reading_filter import filter_reading
from tracker_service.cues.shoes import feet_cost, foot_points, reweight_legs, shoe_pixels
from tracker_service.estimators.base import Estimate
from tracker_service.estimators.tree_filter.model import FilterDB
from tracker_service.pipeline.confidence import expected_error
from tracker_service.pipeline.config import TrackerConfig
from tracker_service.pipeline.floor_contact import floor_contact
from tracker_service.pipeline.observe import FrameEvidence
from tracker_service.pipeline.refinement import refine_pose
from tracker_service.pipeline.smoothing import smooth_pose
from tracker_service.pipeline.state import TrackerState
from tracker_service.silhouette.placement import feet_scale, height_scale, placement_to_root, scaled_placement

__all__ = ["Transition", "publish"]

log = logging.getLogger(__name__)

_FEET = np.array([JOINT_INDEX[n] for n in ("l_ankle", "l_toe", "r_ankle", "r_toe")])


@dataclass(frozen=True)
class Transition:
    """The tracker's next state with this frame's flags.

    Attributes
    ----------
    state : TrackerState
    body_changed : bool
        The published skeleton changed this frame (a body chosen, proportions read).
    restarted : bool
        The estimator restarted at a new body size (the smoother restarts too).
    error_m : float
        The published pose's expected joint error, metres
        (:func:`tracker_service.pipeline.confidence.expected_error`); NaN without the reading.
    """

    state: TrackerState
    body_changed: bool
    restarted: bool
    error_m: float = float("nan")


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


def _airborne(mask: NDArray[np.bool_], runs: NDArray[np.int16], db: FilterDB, leaf: int, feet: float,
              gate: float) -> bool:
    """Whether the body is off the floor: the feet line's scale ``feet`` reads farther than the
    silhouette's height (:func:`height_scale`) by more than twice the filter's airborne gate."""
    if not db.level_column:
        return False
    s_height = height_scale(mask, runs, float(db.level_column[-1][leaf]))
    return s_height is not None and feet < s_height * (1.0 - 2.0 * gate)


def publish(move: Transition, prev: TrackerState, frame: NDArray[np.uint8], mask: NDArray[np.bool_],
            ev: FrameEvidence, est: Estimate, pose: NDArray[np.float64], db: FilterDB, db_body: Body,
            camera: Camera, config: TrackerConfig) -> tuple[NDArray[np.float64], Transition]:
    """The published world pose of this frame.

    Parameters
    ----------
    move : Transition
        The next state after the phase bookkeeping.
    prev : TrackerState
        The state before this frame.
    frame : (H, W, 3) uint8
    mask : (H, W) bool
    ev : FrameEvidence
        The frame's evidence (the network's reading, the shoe pixels).
    est : Estimate
        The estimator's estimate.
    pose : (P,) float64
        The estimate's pose (posterior mean or MAP), at the reference placement.
    db : FilterDB
    db_body : Body
    camera : Camera
    config : TrackerConfig

    Returns
    -------
    pose : (P,) float64
        The published pose, root placed in the world.
    move : Transition
        With the smoother, the proportions and the readings' filter advanced.
    """
    st = move.state
    body, scale, phase = st.body, st.body_scale, st.phase
    body_changed, base_body = move.body_changed, st.base_body
    shoe_px, shoes, seen = ev.shoe_pixels, st.shoes, ev.reading
    if shoe_px is None and phase == "tracking" and shoes is not None and config.shoes is not None and ev.feet_seen:
        shoe_px = shoe_pixels(frame, mask, shoes, config.shoes)  # the frame that learned them
    if (shoe_px is not None and config.shoes is not None and config.use_mean_pose and len(est.support_leaves)
            and config.shoes.weight > 0 and len(db.leaf_points)):
        cost = feet_cost(shoe_px, foot_points(db.leaf_points[est.support_leaves], est.support_places, db.center),
                         config.shoes, mask.shape)
        if cost is not None:
            pose = reweight_legs(pose, db.leaf_poses[est.support_leaves].astype(np.float64), est.support_weights,
                                 cost, config.filter.mean_temperature, config.shoes)
    readings, proportions_set = st.bone_readings, st.proportions_set
    if (seen is not None and config.proportions is not None and config.body is None and phase == "tracking"
            and prev.phase == "tracking" and not proportions_set and not body_changed  # a given body is kept
            and in_view(mask)):  # a person cut by the border is a view the network never saw
        readings = (*readings, bone_lengths_read(seen[0], body.height))
        if len(readings) >= config.proportions.frames:
            base = base_body if base_body is not None else body  # always relative to the model
            ratio = proportion_ratios(np.stack(readings), base, config.proportions)
            body, base_body, body_changed, proportions_set, readings = adapt_body(base, ratio), base, True, True, ()
            log.info("body %s: bone proportions from the appearance cue: %s", body.name, describe(ratio) or "unchanged")
    reading = st.reading
    if phase != "tracking":  # (a re-initialisation or a new body size keeps it: the network reads the image)
        reading = None  # a new person or session: the readings' history belongs to the old one
    elif seen is not None and config.reading_filter is not None and config.refine is not None:
        reading, *filtered = filter_reading(reading, st.clock, seen[0], seen[1], config.reading_filter)
        seen = (filtered[0], filtered[1])
    error_m = float("nan")
    if seen is not None and config.refine is not None:  # ELMO's local refinement (refinement.py)
        before = pose
        pose = refine_pose(pose, body, camera.pose[:3, :3], seen[0], seen[1], body.height, config.refine)
        error_m = expected_error(fk(before, body), fk(pose, body), seen[1], body.height)  # the confidence's
    place = est.placement.copy()
    if config.depth_from_feet and est.leaf >= 0:  # the feet line measures depth better than the template's scale
        runs = db.level_runs[-1].runs(est.leaf)
        s_feet = feet_scale(mask, runs, camera.cy)
        if s_feet is not None and abs(scale * s_feet / place[2] - 1.0) < 0.15 and not _airborne(
                mask, runs, db, est.leaf, scale * s_feet, config.filter.airborne_gate):
            # s_feet is the floor-row ratio (the templates' size); the subject is `scale` times it
            place = scaled_placement(np.array([place[0], 0.0, s_feet]), scale, camera)
    pose[:3] = placement_to_root(place, pose[:3], camera, body_scale=scale)
    pose[1] += _feet_offset(pose, body, db_body, scale)
    if config.floor is not None:  # a leg the reading straightened through the floor bends back onto it
        pose = floor_contact(pose, body, config.floor)
    smooth = st.smooth
    if config.smoothing is not None and phase == "tracking" and not est.reinitialised and not move.restarted:
        smooth, pose = smooth_pose(smooth, st.clock, pose, config.smoothing)
    else:
        smooth = None
    st = replace(st, body=body, smooth=smooth, bone_readings=readings, proportions_set=proportions_set,
                 base_body=base_body, reading=reading)
    return pose, Transition(st, body_changed, move.restarted, error_m)
