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

from protocol.skeleton import CAPSULE_INDEX, CAPSULES, JOINT_INDEX, Body, standing_pose
from tracker_service.body.family import body_model, resized_model_body
from tracker_service.body.kinematics import fk
from tracker_service.camera import Camera
from tracker_service.estimators.base import Observation
from tracker_service.estimators.tree_filter.filter import FilterDB, FilterParams, initial_state, step
from tracker_service.silhouette.features import LevelFeatures
from tracker_service.silhouette.placement import scaled_placement

__all__ = ["STATURE_RANGE_M", "BodyChoice", "candidates_near", "head_missing", "measured_stature", "score_bodies",
           "shoulder_top"]

#: Statures a measured body may have (metres): a child of about five to a very tall adult.
STATURE_RANGE_M = (1.05, 2.05)
#: A body is resized at most this far beyond the heights of the models scored for it (metres): a
#: broken silhouette cannot make a giant, and a man of 2 m keeps his stature (the family's tallest
#: model is 1.80 m; at 0.10 a 2.02 m man was published 12 cm short and tracked 1.0 cm worse).
SIZE_MARGIN_M = 0.25

#: A silhouette whose top rows (this fraction of its height) are wider than ``HEADLESS_WIDTH`` of its
#: height is topped by the shoulders, not a head: the head was lost to a background of its colour
#: (skin before a pink wall). A head is 6-9 % of the height wide there, shoulders about 30 %.
HEADLESS_BAND = 0.06
HEADLESS_WIDTH = 0.18

_HEAD_TOP = JOINT_INDEX["head_top"]
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


def head_missing(mask: NDArray[np.bool_]) -> bool:
    """Whether the silhouette's top is the shoulders: its top :data:`HEADLESS_BAND` of rows hold a
    row wider than :data:`HEADLESS_WIDTH` of its height (a head, or a raised hand, is narrower).

    Parameters
    ----------
    mask : (H, W) bool

    Returns
    -------
    bool
        False for an empty silhouette.
    """
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0:
        return False
    h = int(rows[-1] - rows[0] + 1)
    band = mask[rows[0]: rows[0] + max(round(HEADLESS_BAND * h), 1)]
    return bool(band.sum(axis=1).max() > HEADLESS_WIDTH * h)


def shoulder_top(body: Body) -> float:
    """The highest point of ``body`` standing, its head and neck apart (the top of the thorax and
    shoulders), over its height: 0.86-0.88 for the family's models."""
    j = fk(standing_pose(body), body)
    r = body.capsule_radii
    tops = [max(j[JOINT_INDEX[a], 1] + r[i, 0], j[JOINT_INDEX[b], 1] + r[i, 1])
            for i, (_, part, a, b) in enumerate(CAPSULES) if part != "head"]
    return float(max(tops) / body.height)


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
    (:func:`head_missing`: the head lost to a background of its colour) is the extent over
    :func:`shoulder_top`.

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
    if head_missing(mask):  # the top is the shoulders
        return extent / shoulder_top(db_body)
    if joints is None:
        return extent
    j = np.asarray(joints, np.float64)
    if not np.isfinite(j).all():
        return float("nan")
    r = db_body.capsule_radii[:, 1] / db_body.height
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
