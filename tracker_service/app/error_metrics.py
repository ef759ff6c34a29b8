"""Error measures of a tracked sequence against its truth: jitter, jumps, re-acquisition after a
loss, and how well the published confidence ranks the frames' errors (:mod:`.evaluate` reports
them)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["acceleration_error", "confidence_error_spearman", "joint_jumps", "reacquisition_times"]


def acceleration_error(frame: NDArray[np.int64], est: NDArray[np.float64], true: NDArray[np.float64]) -> float:
    """Mean joint acceleration error (metres per frame squared): the jitter of the published pose.

    Over every three consecutive frames ``i - 1, i, i + 1`` that were all tracked steadily (the
    caller leaves out initialisation, forced losses until the track is back, re-initialisations and
    the frame a new skeleton is published, whose jumps are not jitter), the second
    difference of the estimated root-relative joints minus that of the true ones, its norm averaged
    over the joints and the triples (the "Accel" error of temporal human-pose papers). A pose that
    trembles from frame to frame scores high even when its mean error is low.

    Parameters
    ----------
    frame : (F,) int64
        Frame number of each tracked frame (increasing).
    est, true : (F, J, 3) float64
        Root-relative joints.

    Returns
    -------
    float
        NaN when no three consecutive frames were tracked.
    """
    frame = np.asarray(frame)
    if len(frame) < 3:
        return float("nan")
    ok = (frame[2:] - frame[:-2]) == 2
    if not ok.any():
        return float("nan")
    d = np.asarray(est, np.float64) - np.asarray(true, np.float64)
    acc = d[2:] - 2.0 * d[1:-1] + d[:-2]
    return float(np.linalg.norm(acc[ok], axis=-1).mean())


def reacquisition_times(t: NDArray[np.float64], err: NDArray[np.float64], losses: list[int], fps: float,
                        within_m: float = 0.10, relative: float = 1.25, run: int = 3,
                        min_left_s: float = 1.0) -> list[float]:
    """Time (s) from each forced loss until the track is back.

    Back means ``run`` frames in a row within ``within_m`` of the truth, or, where the track was
    worse than that in the second before the loss, within ``relative`` x its median error then
    (a take the tracker follows at 12 cm is back at 15 cm, not never). The time counts from the
    loss to the first frame of the run. A loss not yet back with less than ``min_left_s`` of the
    clip after it is not judged; one never back is ``inf``.

    Parameters
    ----------
    t : (F,) float64
        Timestamps of the evaluated frames.
    err : (F,) float64
        Root-relative mean joint error of each (metres).
    losses : list of int
        Index (into ``t``) of the frame at which each loss was forced.
    fps : float

    Returns
    -------
    list of float
    """
    out: list[float] = []
    n_before = max(round(fps), 1)
    for k in losses:
        before = err[max(k - n_before, 0): k]
        thr = max(within_m, relative * float(np.median(before))) if len(before) else within_m
        ok = err[k + 1:] < thr
        streak, found = 0, float("inf")
        for j, good in enumerate(ok):
            streak = streak + 1 if good else 0
            if streak >= run:
                found = float(t[k + 1 + j - run + 1] - t[k])
                break
        if np.isfinite(found) or t[-1] - t[k] >= min_left_s:  # not back, too little clip left: unjudged
            out.append(found)
    return out


def joint_jumps(frame: NDArray[np.int64], est: NDArray[np.float64], true: NDArray[np.float64],
                limit_m: float = 0.15) -> tuple[int, float]:
    """Jumps of the published joints that the truth does not make.

    Over every two consecutive frames that were both tracked steadily (as for
    :func:`acceleration_error`), a joint *jumps* when its move from one frame to the next differs
    from the true joint's move by more than ``limit_m``: ``|Δest - Δtrue| > limit_m``. A fast
    true motion is no jump; a skeleton flipping to another pose is.

    Parameters
    ----------
    frame : (F,) int64
        Frame number of each tracked frame (increasing).
    est, true : (F, J, 3) float64
        Joints in the world (metres), the root included.
    limit_m : float

    Returns
    -------
    pairs : int
        Consecutive frame pairs in which at least one joint jumps.
    worst_m : float
        The largest ``|Δest - Δtrue|`` over all joints and pairs (0 when there are none).
    """
    frame = np.asarray(frame)
    if len(frame) < 2:
        return 0, 0.0
    ok = (frame[1:] - frame[:-1]) == 1
    if not ok.any():
        return 0, 0.0
    d = np.asarray(est, np.float64) - np.asarray(true, np.float64)
    move = np.linalg.norm(d[1:] - d[:-1], axis=-1)[ok]  # (pairs, J)
    return int(np.sum(move.max(axis=1) > limit_m)), float(move.max())


def confidence_error_spearman(confidence: list[float], error: list[float]) -> float | None:
    """Spearman's rank correlation between the published confidence and the frame's error (a
    confidence that means something correlates negatively); None for fewer than 10 frames or a
    constant series."""
    c, e = np.asarray(confidence, np.float64), np.asarray(error, np.float64)
    if len(c) < 10 or np.ptp(c) == 0 or np.ptp(e) == 0:
        return None
    from scipy.stats import spearmanr

    return round(float(spearmanr(c, e).statistic), 3)
