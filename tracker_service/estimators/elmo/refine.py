"""ELMO §3.2: local optimisation of each hypothesis to the nearest likelihood mode.

The paper refines by ICP on a stereo point cloud (a 3D metric error with a cheap local optimum).
Our likelihood is the silhouette distance of a rendered capsule body
(:class:`~tracker_service.estimators.likelihood.PoseLikelihood`, eq. 6's Gaussian on distance), not
differentiable in closed form, so the local optimum is found by a derivative-free *pattern search*
(coordinate descent with a shrinking step), all hypotheses together:

1. for every searched coordinate ``c`` (root position, root rotation, the main limb joints' rotation
   vector components) evaluate ``x +- h_c e_c`` -- ``2 C`` poses per hypothesis, one likelihood call
   for the whole batch;
2. the combined move (every improving coordinate at its better sign) is evaluated too; the hypothesis
   moves to the best of the combined move and the best single move if it improves;
3. a hypothesis that did not improve halves its steps;

for ``iterations`` rounds (``iterations x (2 C + 1)`` evaluations per hypothesis). Poses stay
within the joint limits (:func:`protocol.skeleton.clamp_pose`).

The mode's covariance (eq. 3's ``C_i``) is diagonal, from the last round's curvature along each
searched coordinate, ``h^2 / (f(x+h) + f(x-h) - 2 f(x))`` (the inverse second difference of the
negative log likelihood), floored and capped; the unsearched dimensions get the floor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import POSE_SIZE, clamp_pose
from tracker_service.estimators.likelihood import PoseLikelihood
from tracker_service.estimators.particles import joint_slice
from tracker_service.silhouette.features import LevelFeatures

__all__ = ["DEFAULT_SEARCH", "Refined", "coordinates", "pattern_search"]

#: Searched joints and their initial step (radians, each rotation-vector component); ``pelvis`` is
#: the root orientation. The root position's step is :attr:`ElmoParams.root_step_m`.
DEFAULT_SEARCH: dict[str, float] = {
    "pelvis": 0.1,
    "l_shoulder": 0.25, "r_shoulder": 0.25, "l_elbow": 0.25, "r_elbow": 0.25,
    "l_hip": 0.1, "r_hip": 0.1,
}


def coordinates(root_step_m: float, joints: dict[str, float]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The searched pose-vector entries and their initial steps: the root position's three, then
    each named joint's rotation vector."""
    idx = [0, 1, 2]
    step = [root_step_m] * 3
    for name, h in joints.items():
        s = joint_slice(name)
        idx += list(range(s.start, s.stop))
        step += [h] * 3
    return np.asarray(idx, np.int64), np.asarray(step, np.float64)


@dataclass(frozen=True)
class Refined:
    """Hypotheses after the local search.

    Attributes
    ----------
    poses : (H, P) float64
        The local optima (world poses).
    neg_log, distance : (H,) float64
        Their negative log likelihood and silhouette distance.
    variance : (H, P) float64
        Diagonal covariance of each mode.
    evaluations : int
        Likelihood evaluations spent.
    """

    poses: NDArray[np.float64]
    neg_log: NDArray[np.float64]
    distance: NDArray[np.float64]
    variance: NDArray[np.float64]
    evaluations: int


def pattern_search(start: NDArray[np.float64], likelihood: PoseLikelihood, features: list[LevelFeatures],
                   coords: NDArray[np.int64], steps: NDArray[np.float64], iterations: int = 4,
                   var_floor: float = 1e-4, var_cap: float = 0.25) -> Refined:
    """Refine every row of ``start`` ``(H, P)`` to a local minimum of the negative log likelihood.

    Parameters
    ----------
    start : (H, P) float64
        Initial world poses.
    likelihood : PoseLikelihood
    features : list of LevelFeatures
        The observation.
    coords : (C,) int64
        Searched pose-vector entries.
    steps : (C,) float64
        Their initial steps.
    iterations : int
        Rounds of the search (each ``2 C + 1`` evaluations per hypothesis).
    var_floor, var_cap : float
        Bounds of the per-dimension variance of a mode.

    Returns
    -------
    Refined
    """
    x = clamp_pose(np.atleast_2d(np.asarray(start, np.float64)).copy())
    h_n, c_n = len(x), len(coords)
    lik = likelihood(x, features)
    f, d = lik.neg_log.copy(), lik.distance.copy()
    evals = lik.evaluations
    h = np.tile(steps, (h_n, 1))  # (H, C) per-hypothesis steps
    variance = np.full((h_n, POSE_SIZE), var_floor)
    rows = np.arange(h_n)
    for it in range(iterations):
        trial = np.repeat(x[:, None, :], 2 * c_n, axis=1)  # (H, 2C, P): +h then -h per coordinate
        ci = np.arange(c_n)
        trial[:, 2 * ci, coords] += h
        trial[:, 2 * ci + 1, coords] -= h
        trial = clamp_pose(trial.reshape(-1, POSE_SIZE)).reshape(h_n, 2 * c_n, POSE_SIZE)
        lt = likelihood(trial.reshape(-1, POSE_SIZE), features)
        evals += lt.evaluations
        ft = lt.neg_log.reshape(h_n, c_n, 2)
        dt = lt.distance.reshape(h_n, c_n, 2)
        if it == iterations - 1:  # eq. 3's C_i: the inverse curvature along each searched coordinate
            curv = (ft[:, :, 0] + ft[:, :, 1] - 2.0 * f[:, None]) / np.maximum(h ** 2, 1e-12)
            v = np.where(curv > 0, 1.0 / np.maximum(curv, 1e-12), var_cap)
            variance[:, coords] = np.clip(v, var_floor, var_cap)
        best_sign = np.argmin(ft, axis=2)  # (H, C)
        fbest = np.take_along_axis(ft, best_sign[:, :, None], axis=2)[:, :, 0]
        gain = f[:, None] - fbest
        improving = gain > 0
        # the combined move: every improving coordinate at its better sign
        comb = x.copy()
        delta = np.where(best_sign == 0, h, -h) * improving
        comb[:, coords] += delta
        comb = clamp_pose(comb)
        lc = likelihood(comb, features)
        evals += lc.evaluations
        single = np.argmax(gain, axis=1)
        f_single = fbest[rows, single]
        d_single = np.take_along_axis(dt, best_sign[:, :, None], axis=2)[:, :, 0][rows, single]
        x_single = trial[rows, 2 * single + best_sign[rows, single]]
        use_comb = lc.neg_log < np.minimum(f_single, f)
        use_single = ~use_comb & (f_single < f)
        x = np.where(use_comb[:, None], comb, np.where(use_single[:, None], x_single, x))
        d = np.where(use_comb, lc.distance, np.where(use_single, d_single, d))
        f = np.where(use_comb, lc.neg_log, np.where(use_single, f_single, f))
        stalled = ~(use_comb | use_single)
        h[stalled] *= 0.5
    return Refined(x, f, d, variance, evals)
