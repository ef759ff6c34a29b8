"""ELMO's likelihood modes (§3.2, eq. 3) and their reweighting by a wide temporal prior (§3.3, eq. 4-6).

**Modes.** Refined hypotheses that converged to the same place are one mode: hypotheses are taken
best first, each joins the first mode whose centre lies within ``merge_m`` (mean world joint
distance) or starts a new one. A mode is its best member (centre ``mu_i``, its negative log
likelihood), with a diagonal covariance ``C_i``: the larger of the local search's inverse curvature
and the spread of its members. Its weight in the likelihood mixture (eq. 3) is ``w^_i ∝ p(y | mu_i)``
-- the number of hypotheses that reached a mode does not count (the paper's Fig. 1).

**Temporal integration** (eq. 6). With a prior that is a mixture over the previous frame's modes
diffused by a wide ``C_eta`` (eq. 4) and likelihood modes much narrower than it, each product of
Gaussians reduces to eq. 5, and the posterior is the likelihood's mixture reweighted::

    w_i^t = w^_i^t  sum_j w_j^{t-1} N(mu_i^t; mu_j^{t-1}, C_eta)                  (eq. 6)

``C_eta = sigma_eta^2 I`` is taken in the space of world joint positions (the paper's 3D key joints;
a pose-vector metric would weigh a root rotation like a wrist's), so ``N`` is
``exp(-0.5 (D_ij / sigma_eta)^2)`` with ``D_ij`` the mean joint distance; its normalising constant
is common to every term and cancels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Modes", "joint_distance", "merge_modes", "reweight"]


def joint_distance(ja: NDArray[np.float64], jb: NDArray[np.float64]) -> NDArray[np.float64]:
    """Mean joint distance ``(A, B)`` between every pose of ``ja`` ``(A, J, 3)`` and of ``jb`` ``(B, J, 3)``."""
    return np.linalg.norm(ja[:, None] - jb[None], axis=-1).mean(axis=-1)


@dataclass(frozen=True)
class Modes:
    """A Gaussian mixture over poses (eq. 3 or eq. 6).

    Attributes
    ----------
    poses : (K, P) float64
        Centres ``mu_i`` (world poses).
    joints : (K, J, 3) float64
        Their world joint positions.
    variance : (K, P) float64
        Diagonal ``C_i``.
    neg_log : (K,) float64
        ``-log p(y | mu_i)`` (eq. 6 of Okada & Stenger: the silhouette's Gaussian on distance).
    distance : (K,) float64
        Silhouette distance of each centre.
    weights : (K,) float64
        Normalised mixture weights.
    members : (K,) int64
        Hypotheses merged into each mode.
    """

    poses: NDArray[np.float64]
    joints: NDArray[np.float64]
    variance: NDArray[np.float64]
    neg_log: NDArray[np.float64]
    distance: NDArray[np.float64]
    weights: NDArray[np.float64]
    members: NDArray[np.int64]

    def __len__(self) -> int:
        return len(self.poses)

    def take(self, idx: NDArray[np.int64]) -> Modes:
        """The modes ``idx``, weights renormalised."""
        w = self.weights[idx]
        w = w / w.sum() if w.sum() > 0 else np.full(len(idx), 1.0 / max(len(idx), 1))
        return Modes(self.poses[idx], self.joints[idx], self.variance[idx], self.neg_log[idx],
                     self.distance[idx], w, self.members[idx])


def _likelihood_weights(neg_log: NDArray[np.float64]) -> NDArray[np.float64]:
    f = np.where(np.isfinite(neg_log), neg_log, np.inf)
    if not np.isfinite(f).any():
        return np.full(len(f), 1.0 / max(len(f), 1))
    w = np.exp(-(f - f.min()))
    return w / w.sum()


def merge_modes(poses: NDArray[np.float64], joints: NDArray[np.float64], variance: NDArray[np.float64],
                neg_log: NDArray[np.float64], distance: NDArray[np.float64], merge_m: float) -> Modes:
    """Refined hypotheses ``(H, ...)`` merged into modes, best first (weights: eq. 3's ``w^``)."""
    order = np.argsort(neg_log, kind="stable")
    centres: list[int] = []
    groups: list[list[int]] = []
    for i in order:
        if centres:
            dist = joint_distance(joints[i: i + 1], joints[centres])[0]
            k = int(np.argmin(dist))
            if dist[k] < merge_m:
                groups[k].append(int(i))
                continue
        centres.append(int(i))
        groups.append([int(i)])
    c = np.asarray(centres, np.int64)
    var = variance[c].copy()
    for k, g in enumerate(groups):
        if len(g) > 1:  # the members' spread about the centre
            spread = ((poses[g] - poses[c[k]]) ** 2).mean(axis=0)
            var[k] = np.maximum(var[k], spread)
    return Modes(poses[c], joints[c], var, neg_log[c], distance[c], _likelihood_weights(neg_log[c]),
                 np.asarray([len(g) for g in groups], np.int64))


def reweight(modes: Modes, previous: Modes | None, sigma_eta_m: float) -> Modes:
    """Eq. 6: each likelihood mode's weight times the wide temporal prior (the previous modes'
    mixture diffused by ``C_eta``) at its centre; the likelihood's weights alone without a
    previous frame."""
    if previous is None or len(previous) == 0 or len(modes) == 0:
        return modes
    d = joint_distance(modes.joints, previous.joints)  # (L, K)
    log_prior = np.log(np.maximum(np.exp(-0.5 * (d / sigma_eta_m) ** 2) @ previous.weights, 1e-300))
    log_w = np.log(np.maximum(modes.weights, 1e-300)) + log_prior
    w = np.exp(log_w - log_w.max())
    return Modes(modes.poses, modes.joints, modes.variance, modes.neg_log, modes.distance, w / w.sum(),
                 modes.members)
