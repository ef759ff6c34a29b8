"""The subject's bone proportions from the appearance cue's joint readings.

Body selection (:mod:`tracker_service.pipeline.body_selection`) picks one of the family's 30 models by
stature and silhouette fit; within a model the proportions are fixed, so a subject with a shorter
torso or longer legs than the chosen model is published with the model's. The tracker's error
shows it: for the benchmark's third subject (seed 11) the chosen model's torso is 5 % too long and
its legs 7 % too short, and the published neck and head sit 3 cm off in height on every frame
(docs/TRACKER.md, "Refining the published pose toward the network's joints").

The appearance network reads every joint relative to the pelvis (:mod:`tracker_service.cues.appearance`),
so each frame gives a reading of every bone's length. Over the first frames of tracking their
medians measure the subject's proportions: each bone of :data:`ADAPTED_BONES` is scaled by the
median reading over the model's length, the left and right bones by their mean ratio (bodies are
symmetric; the readings of a limb turned away are not), clipped to ``[1 - max_change,
1 + max_change]``. The hands', feet's, head top's and pelvis width's bones keep the model's: the
network's readings of the short distal bones shrink toward the training people's mean (forearm
-8 %, hand -10 % on validation takes), and the pelvis width is not depth-ambiguous.

Only the published skeleton changes; the templates, the filter and the body's stature stay the
selected model's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import JOINT_INDEX, JOINT_NAMES, MIRROR_JOINTS, N_JOINTS, PARENTS, Body

__all__ = ["ADAPTED_BONES", "ProportionParams", "adapt_body", "bone_lengths_read", "describe", "proportion_ratios"]

#: Bones (named by their child joint) whose length is taken from the readings: the spine, neck and
#: head, the clavicles, upper arms, thighs and shins.
ADAPTED_BONES: tuple[str, ...] = (
    "spine", "chest", "neck", "head",
    "l_clavicle", "l_shoulder", "l_elbow", "r_clavicle", "r_shoulder", "r_elbow",
    "l_knee", "l_ankle", "r_knee", "r_ankle",
)
_ADAPTED = np.array([JOINT_INDEX[n] for n in ADAPTED_BONES], np.int64)
_PARENT_IDX = np.array([max(p, 0) for p in PARENTS], np.int64)


@dataclass(frozen=True)
class ProportionParams:
    """When and how far the published skeleton follows the readings.

    Attributes
    ----------
    frames : int
        Frames of tracking with a reading before the proportions are set (once per session).
    max_change : float
        The largest relative change of a bone's length.
    """

    frames: int = 30
    max_change: float = 0.15

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise ValueError(f"frames must be >= 1, got {self.frames}")
        if not 0.0 <= self.max_change < 1.0:
            raise ValueError(f"max_change must be in [0, 1), got {self.max_change}")


def bone_lengths_read(mu: NDArray[np.float64], height: float) -> NDArray[np.float64]:
    """Every bone's length in one reading of the network.

    Parameters
    ----------
    mu : (J, 3) float64
        Joints relative to the pelvis over the height (:func:`tracker_service.cues.appearance.predict_joints`).
    height : float
        Metres.

    Returns
    -------
    (J,) float64
        Metres; 0 for the root.
    """
    m = np.asarray(mu, np.float64)
    out = np.linalg.norm(m - m[_PARENT_IDX], axis=1) * height
    out[0] = 0.0
    return out


def proportion_ratios(readings: NDArray[np.float64], body: Body, params: ProportionParams) -> NDArray[np.float64]:
    """Each bone's length ratio, subject over model.

    Parameters
    ----------
    readings : (n, J) float64
        :func:`bone_lengths_read` of ``n`` frames (non-finite rows are ignored).
    body : Body
        The model the readings are compared with.
    params : ProportionParams

    Returns
    -------
    (J,) float64
        1 for the bones outside :data:`ADAPTED_BONES` and when no reading is finite; left and right
        bones share their mean ratio.
    """
    r = np.asarray(readings, np.float64).reshape(-1, N_JOINTS)
    r = r[np.isfinite(r).all(axis=1)]
    ratio = np.ones(N_JOINTS)
    if not len(r):
        return ratio
    model = body.bone_lengths
    med = np.median(r, axis=0)
    raw = np.where(model > 1e-6, med / np.where(model > 1e-6, model, 1.0), 1.0)
    sym = 0.5 * (raw + raw[list(MIRROR_JOINTS)])
    ratio[_ADAPTED] = np.clip(sym[_ADAPTED], 1.0 - params.max_change, 1.0 + params.max_change)
    return ratio


def adapt_body(body: Body, ratio: NDArray[np.float64]) -> Body:
    """The body with every bone scaled by ``ratio``; its stature measurement and capsules kept.

    Parameters
    ----------
    body : Body
    ratio : (J,) float64
        :func:`proportion_ratios`.

    Returns
    -------
    Body
        Same name; ``measurements`` gain nothing (the stature the templates were scaled to is kept).
    """
    r = np.asarray(ratio, np.float64)
    if r.shape != (N_JOINTS,) or not (np.isfinite(r).all() and (r > 0).all()):
        raise ValueError(f"ratio must be ({N_JOINTS},) finite and positive")
    measurements = dict(body.measurements)
    measurements.setdefault("height_m", body.height)  # the stature stays the selected one
    return replace(body, offsets=body.offsets * r[:, None], measurements=measurements)


def describe(ratio: NDArray[np.float64]) -> str:
    """``spine 0.95, l_knee 1.02, ...`` for the bones that changed (for the log)."""
    return ", ".join(f"{JOINT_NAMES[j]} {ratio[j]:.3f}" for j in _ADAPTED if abs(ratio[j] - 1.0) > 1e-3)
