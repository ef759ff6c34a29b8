"""The published pose's confidence: how far it probably is from the truth.

The silhouette match (eq. 10's distance, the estimator's ``Estimate.confidence``) says how well
the template fits the outline, not whether the pose is right: a standing person fits well and is
still ambiguous in depth, a raised arm fits worse and is read right. Over 24 held-out runs
(12 takes, 2 people) its rank correlation with the frame's joint error is only -0.15.

With the appearance cue two quantities track the error much better:

* ``moved``: how far the refinement (:mod:`tracker_service.pipeline.refinement`) moved the joints
  toward the network's reading, RMS over the joints. The silhouette filter and the network are
  two independent estimates; when they disagree, at least one of them is wrong.
* ``sigma``: the network's own predicted standard deviation of the joints (its filtered reading,
  RMS over joints and axes), which grows on views it finds hard.

The expected error is their quadrature sum, ``e = hypot(moved, sigma)``, and the confidence
``exp(-e^2 / 2 s^2)`` with ``s`` = 10 cm: 1 for a pose both agree on with certainty, 0.61 at 10 cm,
0.14 at 20 cm. Rank correlation of ``e`` with the error: +0.74 pooled, +0.52 within a run (positive
in 18 of 18 runs). Without the cue (or a frame the network did not read) the confidence stays the
silhouette match's.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["CONFIDENCE_SCALE_M", "expected_error", "pose_confidence"]

#: The expected error (metres) at which the confidence is ``exp(-1/2)`` = 0.61.
CONFIDENCE_SCALE_M = 0.10


def expected_error(before: NDArray[np.float64], after: NDArray[np.float64], var: NDArray[np.float64],
                   height: float) -> float:
    """The published pose's expected joint error (metres).

    Parameters
    ----------
    before, after : (J, 3) float64
        The joints before and after the refinement toward the reading, metres.
    var : (J, 3) float64
        The reading's variances, in units of ``height`` squared.
    height : float
        The person's height, metres.

    Returns
    -------
    float
        ``hypot(moved, sigma)``; NaN when either is not finite.
    """
    moved = float(np.sqrt(np.mean(np.sum((np.asarray(after) - np.asarray(before)) ** 2, axis=1))))
    sigma = float(np.sqrt(np.mean(np.maximum(np.asarray(var, np.float64), 0.0)))) * float(height)
    return math.hypot(moved, sigma) if math.isfinite(moved) and math.isfinite(sigma) else math.nan


def pose_confidence(error_m: float, silhouette: float, scale_m: float = CONFIDENCE_SCALE_M) -> float:
    """The published confidence in ``[0, 1]``: ``exp(-error^2 / 2 scale^2)``, or the silhouette
    match's ``silhouette`` when the expected error is unknown (NaN)."""
    if not math.isfinite(error_m):
        return float(np.clip(silhouette, 0.0, 1.0))
    return float(math.exp(-0.5 * (error_m / scale_m) ** 2))
