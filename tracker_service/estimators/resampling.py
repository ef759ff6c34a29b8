"""Resampling of weighted particle sets.

* :func:`multinomial_resample` -- Isard & Blake's factored sampling (Condensation): ``N`` independent
  draws by weight.
* :func:`stratified_resample` -- stratified resampling (Kitagawa; the cardbox paper's SRS,
  Algorithm 3 with eq. 9-10): one uniform draw in each stratum ``[i/N, (i+1)/N)`` of the
  cumulative weights; ``systematic=True`` uses a single offset for every stratum, which puts each
  particle's count within one of ``N w_i``. Independent offsets (the default) keep each count
  within two of ``N w_i`` and unbiased.
* :func:`deterministic_resample` -- the cardbox paper's DRS (Algorithm 4, eq. 11-13): rank by cost,
  keep the best unchanged, perturb the best ``rho N`` survivors, draw the rest around the best.

All take an explicit :class:`numpy.random.Generator`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["deterministic_resample", "multinomial_resample", "normalised_weights", "stratified_resample"]


def normalised_weights(neg_log: NDArray[np.float64]) -> NDArray[np.float64]:
    """``exp(-neg_log)`` normalised to sum 1, computed stably (relative to the best); non-finite
    costs get weight 0; all non-finite: uniform.

    Returns
    -------
    (N,) float64
    """
    c = np.asarray(neg_log, np.float64)
    ok = np.isfinite(c)
    if not ok.any():
        return np.full(len(c), 1.0 / len(c))
    w = np.zeros(len(c))
    w[ok] = np.exp(-(c[ok] - c[ok].min()))
    return w / w.sum()


def multinomial_resample(weights: NDArray[np.float64], n: int, rng: np.random.Generator) -> NDArray[np.int64]:
    """Indices of ``n`` independent draws by weight (factored sampling).

    Returns
    -------
    (n,) int64
    """
    w = np.asarray(weights, np.float64)
    cdf = np.cumsum(w)
    cdf /= cdf[-1]
    return np.minimum(np.searchsorted(cdf, rng.random(n), side="right"), len(w) - 1).astype(np.int64)


def stratified_resample(weights: NDArray[np.float64], n: int, rng: np.random.Generator,
                        systematic: bool = False) -> NDArray[np.int64]:
    """Indices of ``n`` stratified draws by weight (SRS, Algorithm 3): eq. 9 normalises the
    probabilities, eq. 10 accumulates them, and stratum ``i`` draws ``u_i = (i + U_i) / n``; the
    particle whose cumulative interval holds ``u_i`` is selected. Sorted ascending.

    Parameters
    ----------
    weights : (M,) float, >= 0, not all 0
    n : int
    rng : Generator
    systematic : bool
        One offset ``U`` for every stratum (systematic resampling) instead of one per stratum.

    Returns
    -------
    (n,) int64
    """
    w = np.asarray(weights, np.float64)
    cdf = np.cumsum(w / w.sum())  # eq. 9-10
    cdf[-1] = 1.0
    off = np.full(n, rng.random()) if systematic else rng.random(n)
    u = (np.arange(n) + off) / n
    return np.minimum(np.searchsorted(cdf, u, side="right"), len(w) - 1).astype(np.int64)


def deterministic_resample(particles: NDArray[np.float64], costs: NDArray[np.float64], survival: float,
                           noise_std: NDArray[np.float64] | float, rng: np.random.Generator,
                           n: int | None = None) -> NDArray[np.float64]:
    """The cardbox paper's deterministic resampling strategy (DRS, Algorithm 4).

    The particles are ranked by cost (ascending, no nonlinear transformation of the cost):

    * eq. 11: the first new particle is the best old one, unchanged;
    * eq. 12: the ``round(survival * n)`` best (the best included) survive, each but the best
      perturbed with Gaussian noise;
    * eq. 13: every other particle is drawn around the best (the best plus Gaussian noise).

    Parameters
    ----------
    particles : (M, D) float
    costs : (M,) float
        Lower is better (non-finite: worst).
    survival : float
        The survival rate ``rho`` in [0, 1] (Table I: 0.2 torso, 0.4 arms).
    noise_std : (D,) float or float
        Standard deviation of the Gaussian noise of eq. 12-13.
    rng : Generator
    n : int, optional
        Size of the new set (default: ``M``).

    Returns
    -------
    (n, D) float64
        Row 0 is the best particle; rows ``1 .. n_s - 1`` the next survivors in rank order
        (perturbed); the rest drawn around the best.
    """
    x = np.asarray(particles, np.float64)
    c = np.where(np.isfinite(costs), np.asarray(costs, np.float64), np.inf)
    n = len(x) if n is None else int(n)
    order = np.argsort(c, kind="stable")
    n_s = int(min(max(1, round(survival * n)), n, len(x)))
    best = x[order[0]]
    std = np.broadcast_to(np.asarray(noise_std, np.float64), (x.shape[1],))
    out = np.empty((n, x.shape[1]))
    out[0] = best  # eq. 11
    out[1:n_s] = x[order[1:n_s]] + rng.normal(size=(n_s - 1, x.shape[1])) * std  # eq. 12
    out[n_s:] = best + rng.normal(size=(n - n_s, x.shape[1])) * std  # eq. 13
    return out
