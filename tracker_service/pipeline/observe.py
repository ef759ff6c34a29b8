"""Observe: one frame's evidence for the estimator (silhouette features, placement, cues).

:func:`observe` turns the camera frame and its silhouette into the
:class:`~tracker_service.estimators.base.Observation` every estimator takes: the silhouette's
features on the image pyramid (Okada & Stenger eq. 7-12), the placement from the feet line, the skin
evidence, the shoe and appearance cues as leaf costs, and the appearance cue's proposed leaves. It
also returns the appearance network's reading and the shoe pixels, which the publishing stage uses
again.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from tracker_service.camera import Camera
from tracker_service.cues.appearance import HeadingWindow, joints_cost, predict_joints, propose_leaves_in_window
from tracker_service.cues.shoes import ShoeModel, feet_cost, foot_points, shoe_pixels
from tracker_service.cues.skin import observe_skin
from tracker_service.estimators.base import LeafCost, Observation
from tracker_service.estimators.tree_filter.filter import FilterDB, FilterParams, FilterState, support_heading
from tracker_service.pipeline.config import TrackerConfig
from tracker_service.silhouette.features import preprocess
from tracker_service.silhouette.placement import feet_in_view, observed_placement, scaled_placement, silhouette_rows

__all__ = ["FEET_CUT_TOLERANCE", "FrameEvidence", "nearest_scale", "observe"]

#: With the feet cut off by the image's bottom border, the person is taken to be no more than this
#: fraction farther than when the feet were last in view: the feet line reads the nearest foot, up to
#: ~0.3 m ahead of the body at 3 m (4 % pulled walks with a foot forward too near; docs/TRACKER.md).
FEET_CUT_TOLERANCE = 0.10


@dataclass(frozen=True)
class FrameEvidence:
    """A frame's evidence: what the estimator sees and what publishing reuses.

    Attributes
    ----------
    observation : Observation
        The estimator's input.
    raw_placement : (3,) float64 or None
        The placement measured for the templates' own body size (body selection measures with it).
    feet_seen : bool
        The feet are in the image (the shoe cue looks for shoes only then).
    shoe_pixels : tuple of two (N,) int64 arrays, or None
        The frame's shoe pixels (:func:`tracker_service.cues.shoes.shoe_pixels`), when looked for.
    reading : tuple of (J, 3) float64 arrays or None
        The appearance network's reading ``(mu, var)`` of the joints, when taken.
    preprocess_ms, appearance_ms : float
        Time spent on the silhouette's features and in the appearance network.
    """

    observation: Observation
    raw_placement: NDArray[np.float64] | None
    feet_seen: bool
    shoe_pixels: tuple[NDArray[np.int64], NDArray[np.int64]] | None
    reading: tuple[NDArray[np.float64], NDArray[np.float64]] | None
    preprocess_ms: float
    appearance_ms: float


def nearest_scale(mask: NDArray[np.bool_], last_feet_scale: float | None, body_scale: float) -> float | None:
    """The least scale the person can be at while the image's bottom border cuts off their feet.

    The feet line then no longer measures depth, but it still bounds it on one side: had the person
    stepped back, their feet would be in view again, so they are at least about as near as when the
    feet were last seen. Without the bound the depth followed the motion model and the silhouette
    alone, and a person standing 2.9 m away with their feet on the border drifted to 3.6 m in a
    few frames (a held-out take).

    Parameters
    ----------
    mask : (H, W) bool
        The silhouette (non-empty).
    last_feet_scale : float or None
        The feet line's scale (templates' own size) when the feet were last in view.
    body_scale : float
        The subject's size over the templates'.

    Returns
    -------
    float or None
        ``body_scale * last_feet_scale * (1 - FEET_CUT_TOLERANCE)`` when the feet are cut off and were
        seen before; None otherwise.
    """
    if last_feet_scale is None or feet_in_view(mask):
        return None
    return float(body_scale) * float(last_feet_scale) * (1.0 - FEET_CUT_TOLERANCE)


def _heading_window(fstate: object, db: FilterDB, params: FilterParams) -> HeadingWindow:
    """Where the appearance cue may propose: headings within ``params.max_turn`` of the filter's
    current one (its support's circular mean; facing the camera when it has none) and within
    ``params.max_heading``."""
    if isinstance(fstate, FilterState) and len(fstate.leaves):
        centre, half = support_heading(fstate, db), params.max_turn
    else:
        centre, half = 0.0, np.pi / 2
    return HeadingWindow(centre, half, np.inf if params.max_heading is None else params.max_heading)


def observe(frame: NDArray[np.uint8], mask: NDArray[np.bool_], fstate: object, db: FilterDB, camera: Camera,
            config: TrackerConfig, body_scale: float, shoes: ShoeModel | None, tracking: bool,
            last_feet_scale: float | None = None) -> FrameEvidence:
    """Build the frame's observation.

    Parameters
    ----------
    frame : (H, W, 3) uint8
        BGR frame.
    mask : (H, W) bool
        Its silhouette (non-empty).
    fstate : object
        The estimator's state before this frame (the appearance cue proposes near the tree
        filter's heading).
    db : FilterDB
    camera : Camera
    config : TrackerConfig
    body_scale : float
        The subject's size over the templates' (the placement is scaled by it).
    shoes : ShoeModel or None
        The shoe colour learned while initialising.
    tracking : bool
        The tracker is in its tracking phase (shoes are looked for only then).
    last_feet_scale : float, optional
        The feet line's scale (templates' own size) when the feet were last in view
        (``TrackerState.last_feet_scale``): with the feet now cut off by the bottom border, the
        observation's ``min_scale`` is that scale less :data:`FEET_CUT_TOLERANCE`.

    Returns
    -------
    FrameEvidence
    """
    t0 = time.perf_counter()
    feats = preprocess(mask, config.distance, config.alpha, config.beta)
    preprocess_ms = (time.perf_counter() - t0) * 1e3
    raw = observed_placement(mask, camera)  # for the templates' own body size
    # a subject k times the templates' size looks k times larger at that depth, feet on the same row
    obs = None if raw is None else scaled_placement(raw, body_scale, camera)
    min_scale = None if raw is not None else nearest_scale(mask, last_feet_scale, body_scale)
    skin = observe_skin(frame, mask, config.skin) if config.skin is not None else None
    costs: list[LeafCost] = []
    shoe_px = None
    feet_seen = feet_in_view(mask)  # shoes are learned, and looked for, only with the feet in the image
    if tracking and shoes is not None and config.shoes is not None and len(db.leaf_points) and feet_seen:
        shoe_px = shoe_pixels(frame, mask, shoes, config.shoes)
        shoe_params, px = config.shoes, shoe_px

        def leaf_shoe_cost(leaves: NDArray[np.int64], places: NDArray[np.float64]) -> NDArray[np.float64] | None:
            return feet_cost(px, foot_points(db.leaf_points[leaves], places, db.center), shoe_params, mask.shape)

        costs.append(LeafCost("shoes", config.filter.shoe_weight, leaf_shoe_cost))
    proposals = None
    seen = None
    ta = time.perf_counter()
    # (also when the person is cut by the image border, which no training view shows: skipping those
    # frames measured worse on all three subjects, docs/TRACKER.md)
    in_filter = config.filter.appearance_weight > 0 and len(db.leaf_joints3d) > 0
    if config.appearance is not None and (in_filter or config.refine is not None or config.proportions is not None):
        seen = predict_joints(config.appearance, frame, mask, config.appearance_mirror, camera)
        if seen is not None and in_filter:
            mu, var = seen
            coords = config.filter.appearance_coords

            def leaf_appearance_cost(leaves: NDArray[np.int64], _places: NDArray[np.float64]) -> NDArray[np.float64]:
                return joints_cost(mu, var, db.leaf_joints3d[leaves], coords)

            costs.append(LeafCost("appearance", config.filter.appearance_weight, leaf_appearance_cost))
            if config.filter.appearance_proposals > 0:
                scored = np.where(np.isin(np.arange(3), coords), var, np.inf)  # the coordinates the cost counts
                proposals = propose_leaves_in_window(mu, scored, db.leaf_joints3d, config.filter.appearance_proposals,
                                                     db.leaf_heading, _heading_window(fstate, db, config.filter))
    appearance_ms = (time.perf_counter() - ta) * 1e3
    observation = Observation(feats, obs, silhouette_rows(mask), skin, tuple(costs), proposals, min_scale)
    return FrameEvidence(observation, raw, feet_seen, shoe_px, seen, preprocess_ms, appearance_ms)
