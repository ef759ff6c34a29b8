"""Choosing the subject's body model from the family by silhouette match (Okada & Stenger §3,
Fig. 6: "the model silhouette is then used to automatically select the best matching body model").

During the first frames every candidate body is tried: the templates are scaled to the size that
body would have at the subject's physical depth (from the silhouette's feet line, so body height
is *not* absorbed by the scale) and the best silhouette match (nwXOR) is found; the candidate with
the lowest mean distance wins, among the models whose height is close to the stature measured
from the silhouette (down from a raised hand's top to the head's, by the pose). When no database
was built for the winner, the tracker keeps the database's templates and scales them by
``height(winner) / height(database body)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import CAPSULE_INDEX, JOINT_INDEX, Body, standing_pose
from tracker_service.body.family import body_model, resized_model_body
from tracker_service.body.kinematics import fk
from tracker_service.body.raster import render_silhouette
from tracker_service.camera import Camera, default_camera
from tracker_service.estimators.base import Observation
from tracker_service.estimators.tree_filter.filter import FilterDB, FilterParams, initial_state, step
from tracker_service.silhouette.features import LevelFeatures
from tracker_service.silhouette.placement import scaled_placement

__all__ = ["STATURE_RANGE_M", "BodyChoice", "candidates_near", "measured_stature", "score_bodies",
           "shoulder_row", "shoulder_top"]

#: Statures a measured body may have (metres): a child of about five to a very tall adult.
STATURE_RANGE_M = (1.05, 2.05)
#: A body is resized at most this far beyond the heights of the models scored for it (metres): a
#: broken silhouette cannot make a giant, and a man of 2 m keeps his stature (the family's tallest
#: model is 1.80 m; at 0.10 a 2.02 m man was published 12 cm short and tracked 1.0 cm worse).
SIZE_MARGIN_M = 0.25

#: The shoulders: the first row of a silhouette (from its top) wider than this fraction of its
#: height (a head is 6-10 % wide there, shoulders about 30 %).
SHOULDER_WIDTH = 0.18
#: A head and neck above the shoulders are at least this fraction of the silhouette's height (13-20 %
#: standing; 10-16 % for a head that is there, on the family's models and the held-out takes'
#: first frames). Less: the head was lost to a background of its colour (skin before a pink wall).
HEAD_MIN = 0.10

_HEAD_TOP = JOINT_INDEX["head_top"]
_NECK = JOINT_INDEX["neck"]
_HAND_TIPS = np.array([JOINT_INDEX["l_hand_tip"], JOINT_INDEX["r_hand_tip"]])
_SKULL = CAPSULE_INDEX["skull"]
_HANDS = np.array([CAPSULE_INDEX["l_hand"], CAPSULE_INDEX["r_hand"]])


def score_bodies(scores: dict[str, list[float]], features: list[LevelFeatures], observed: NDArray[np.float64],
                 db: FilterDB, db_body: Body, camera: Camera, params: FilterParams,
                 candidates: Sequence[str]) -> dict[str, list[float]]:
    """Append each candidate's best silhouette distance for this frame.

    For every candidate of height ``h_c`` the database's templates are scaled by
    ``k = h_c / h_db`` -- the size that body has at the depth measured from the silhouette's feet
    line -- and the tree filter is run from scratch; its best full-resolution distance is the
    candidate's score. A body of the wrong size can only be fitted with a bent or stretched pose,
    so it scores worse. Candidates of one height share that search (the same templates at the same
    scale give the same distance): the family's 30 models have 13 heights.

    Parameters
    ----------
    scores : dict[str, list[float]]
        Distances so far (not modified).
    features : list of LevelFeatures
        The observation's pyramid.
    observed : (3,) float
        Placement measured from the silhouette (feet line), for the database's body size.
    db : FilterDB
    db_body : Body
    camera : Camera
        The templates' camera.
    params : FilterParams
    candidates : sequence of str
        Body model names.

    Returns
    -------
    dict[str, list[float]]
    """
    out = {k: list(v) for k, v in scores.items()}
    h_db = db_body.height
    by_size: dict[float, float] = {}  # models of one height get the same templates: one search (13 heights of 30)
    for name in candidates:
        k = body_model(name).body.height / h_db
        if k not in by_size:
            obs = scaled_placement(np.asarray(observed, np.float64), k, camera)
            _, est = step(initial_state(obs), db, Observation(features, obs), params)
            by_size[k] = float(est.distance)
        out.setdefault(name, []).append(by_size[k])
    return out


def shoulder_row(mask: NDArray[np.bool_]) -> int | None:
    """The silhouette's topmost row wider than :data:`SHOULDER_WIDTH` of its height, when less than
    :data:`HEAD_MIN` of its height lies above it (the head is missing: that row is the shoulders'
    top); None otherwise, and for an empty silhouette.

    Parameters
    ----------
    mask : (H, W) bool

    Returns
    -------
    int or None
    """
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0:
        return None
    h = int(rows[-1] - rows[0] + 1)
    wide = np.flatnonzero(mask[rows[0]: rows[-1] + 1].sum(axis=1) > SHOULDER_WIDTH * h)
    if len(wide) == 0 or wide[0] >= HEAD_MIN * h:
        return None
    return int(rows[0] + wide[0])


def shoulder_top(body: Body) -> float:
    """Where :func:`shoulder_row` finds the shoulders of ``body`` standing (its head and neck left
    out of the silhouette), as a fraction of its stature: 0.83-0.86 for the family's models.
    Measured on the body's own silhouette at the default camera, so the row and the fraction
    agree however round the shoulders are."""
    key = (body.name, float(body.height), np.asarray(body.capsule_radii, np.float64).tobytes())
    if key not in _SHOULDER_TOPS:
        _SHOULDER_TOPS[key] = _shoulder_top(body)
    return _SHOULDER_TOPS[key]


_SHOULDER_TOPS: dict[tuple[str, float, bytes], float] = {}  # per body (the database's: one entry)


def _shoulder_top(body: Body) -> float:
    cam = default_camera()
    joints = fk(standing_pose(body), body)
    radii = np.array(body.capsule_radii, np.float64)
    radii[[CAPSULE_INDEX["neck"], _SKULL]] = 0.0
    whole = render_silhouette(joints, body.capsule_radii, cam)
    headless = render_silhouette(joints, radii, cam)
    top, bottom = np.flatnonzero(whole.any(axis=1))[[0, -1]]
    row = shoulder_row(headless)
    if row is None:  # not a body the rule can read: its top as a whole
        return 1.0
    return float((bottom + 1 - row) / (bottom + 1 - top))


def measured_stature(mask: NDArray[np.bool_], observed: NDArray[np.float64], camera: Camera,
                     db_body: Body, joints: NDArray[np.floating[Any]] | None = None) -> float:
    """Standing height (metres) of the subject from the silhouette's vertical extent.

    The feet line gives the depth (``observed`` is the database body's placement at that depth:
    ``d = d_ref / s``; the tracker passes the scale that puts the current template's own lowest row
    on the silhouette's, :func:`~tracker_service.silhouette.placement.feet_scale`) and the row of
    the floor under the body (not the toe tips, which are nearer the camera and lower in the
    image); for a level camera the extent is the rows from that floor point to the top of the
    silhouette times ``d / f``. That extent is the stature while the
    head tops the silhouette. With the pose's ``joints`` it is measured whatever tops it: a hand
    (a wave, a greeting: the first frames of many takes) whose top (tip joint plus the hand's end
    radius) is ``a`` statures above the floor and ``z`` statures nearer the camera than the head
    reaches the silhouette's top row at the stature ``extent / (a + u z / f_y)`` (``u``: the top
    row's height above the principal point, pixels; perspective: a hand held toward the camera
    looks higher). The head (``a = 1``, ``z = 0``) gives the extent; the stature is the smallest
    of the three, the one whose top the silhouette's is. A silhouette topped by the shoulders
    (:func:`shoulder_row`: the head lost to a background of its colour, no hand read above the
    neck) is the extent to the shoulders' row over :func:`shoulder_top`.

    Parameters
    ----------
    mask : (H, W) bool
        The silhouette at the camera's resolution.
    observed : (3,) float
        :func:`~tracker_service.silhouette.placement.observed_placement` of ``mask``.
    camera : Camera
        The database's (level) camera.
    db_body : Body
        Its end radii over its height give the hands' and the head's tops.
    joints : (J, 3) float, optional
        The current pose's joints in units of the person's height in the camera's axes (``y`` up,
        ``z`` toward the camera), as the appearance network reads them (any origin). Without them
        the head is assumed on top.

    Returns
    -------
    float
        NaN for an empty silhouette or joints that are not finite.
    """
    ys = np.flatnonzero(mask.any(axis=1))
    if len(ys) == 0:
        return float("nan")
    ref = np.array([0.0, db_body.standing_root_height(), 0.0])
    s = max(float(observed[2]), 1e-6)
    d = float(camera.depth(ref)) / s
    floor_row = camera.cy + s * (float(camera.project(np.zeros(3))[1]) - camera.cy)
    top_row = ys[0] - 0.5
    extent = float((floor_row - top_row) * d / camera.fy)
    j = None if joints is None else np.asarray(joints, np.float64)
    if j is not None and not np.isfinite(j).all():
        return float("nan")
    r = db_body.capsule_radii[:, 1] / db_body.height
    shoulders = shoulder_row(mask)
    # a head lost to the background: the shoulders top the silhouette (unless the reading raises a
    # hand above them, whose arm can make a narrow top short)
    if shoulders is not None and (j is None or (j[_HAND_TIPS, 1] + r[_HANDS] < j[_NECK, 1]).all()):
        return float((floor_row - (shoulders - 0.5)) * d / camera.fy) / shoulder_top(db_body)
    if j is None:
        return extent
    head = j[_HEAD_TOP, 1] + r[_SKULL]
    a = 1.0 + j[_HAND_TIPS, 1] + r[_HANDS] - head
    z = j[_HAND_TIPS, 2] - j[_HEAD_TOP, 2]
    den = a + (camera.cy - top_row) * z / camera.fy
    # (a hand far below the head and far behind it cannot top the silhouette: its denominator is small)
    return float(min([extent, *(extent / den[den > 0.5])]))


def candidates_near(candidates: Sequence[str], height_m: float, tolerance_m: float = 0.08,
                    at_least: int = 3) -> tuple[str, ...]:
    """The candidates whose height is within ``tolerance_m`` of ``height_m`` (at least the
    ``at_least`` nearest), so selection scores a handful of models per frame, not all 30."""
    by_gap = sorted(candidates, key=lambda n: abs(body_model(n).body.height - height_m))
    near = [n for n in by_gap if abs(body_model(n).body.height - height_m) <= tolerance_m]
    return tuple(near if len(near) >= at_least else by_gap[:at_least])


@dataclass(frozen=True)
class BodyChoice:
    """The chosen body model and its size relative to the database's body."""

    body: Body
    scale: float
    mean_distance: float

    @staticmethod
    def from_scores(scores: dict[str, list[float]], db_body: Body, stature: float = float("nan"),
                    tolerance_m: float = 0.06, sized: bool = True) -> BodyChoice:
        """Lowest mean distance wins among the candidates whose height is within ``tolerance_m`` of
        the measured ``stature`` (those at the nearest height when none is; all candidates when the
        stature is unknown); no scores keeps the database's body.

        The winner gives the build (group, girths and proportions over height); with ``sized`` and
        a measured stature the body is that model at the measured stature
        (:func:`~tracker_service.body.family.resized_model_body`, within :data:`STATURE_RANGE_M` and
        :data:`SIZE_MARGIN_M` of the scored models' heights),
        so the published skeleton is as tall as the person measures, not as the nearest model of
        the family (whose steps are 4-5 cm)."""
        if not scores:
            return BodyChoice(db_body, 1.0, float("nan"))
        names = list(scores)
        if np.isfinite(stature):
            gap = {n: abs(body_model(n).body.height - stature) for n in names}
            # beyond the family's range (a man taller than its tallest) only the nearest height stays:
            # a shorter model's better silhouette score must not shrink him further
            names = [n for n in names if gap[n] <= max(tolerance_m, min(gap.values()) + 1e-6)]
        name = min(names, key=lambda n: float(np.mean(scores[n])))
        body = body_model(name).body
        if sized and np.isfinite(stature):
            # a broken silhouette (clothes the colour of the wall) can measure anything: the size
            # stays within SIZE_MARGIN_M of the scored models' heights
            hs = [body_model(n).body.height for n in scores]
            lo = max(STATURE_RANGE_M[0], min(hs) - SIZE_MARGIN_M)
            hi = min(STATURE_RANGE_M[1], max(hs) + SIZE_MARGIN_M)
            body = resized_model_body(name, float(np.clip(stature, lo, hi)))
        return BodyChoice(body, body.height / db_body.height, float(np.mean(scores[name])))
