"""A Kalman filter of the appearance network's joint readings over time.

The network reads every joint from one frame (:func:`tracker_service.cues.appearance.predict_joints`),
so its reading trembles from frame to frame by a few centimetres even where its mean is right
(docs/TRACKER.md, "Two networks, their readings filtered over time": the raw readings'
acceleration error is 3.4 cm per frame², as large as an unsmoothed published pose's). Before the
published pose is refined toward them (:mod:`tracker_service.pipeline.refinement`), each
coordinate of each joint is filtered by a constant-velocity Kalman filter whose measurement
variance is the network's own: a confident reading moves the estimate at once, an unsure one is
averaged with its predecessors. A constant
velocity is followed without lag, unlike a low-pass filter; the process noise (white acceleration,
``ReadingFilterParams.accel``) sets how fast a joint may change speed.

The state is per coordinate and independent (a diagonal filter): 66 position/velocity pairs, a few
microseconds a frame. Pure functions: :func:`filter_reading` takes the state and returns the new one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["ReadingFilterParams", "ReadingState", "filter_reading"]


@dataclass(frozen=True)
class ReadingFilterParams:
    """Process noise and restarts of the reading filter.

    Attributes
    ----------
    accel : float
        Standard deviation of a joint's acceleration, in the reading's units (the person's height)
        per second squared. 20 heights/s² is 36 m/s² for a 1.8 m person: a hand may reverse a
        1 m/s swing in a few frames. This is a light filter: for a reading spread of 2-5 % of the
        height its settled gain is ~0.6-0.8 (a memory of one or two frames), which cuts the
        frame-to-frame tremble by ~40 % (measured in docs/TRACKER.md).
    max_gap_s : float
        A longer gap between readings restarts the filter at the new reading.
    """

    accel: float = 20.0
    max_gap_s: float = 0.5


@dataclass(frozen=True)
class ReadingState:
    """Filter memory: per coordinate, position and velocity and their covariance.

    Attributes
    ----------
    t : float
        Time of the last reading (s).
    x, v : (J, 3) float64
        Filtered reading and its velocity (units per second).
    pxx, pxv, pvv : (J, 3) float64
        Covariance of each coordinate's position and velocity.
    """

    t: float
    x: NDArray[np.float64]
    v: NDArray[np.float64]
    pxx: NDArray[np.float64]
    pxv: NDArray[np.float64]
    pvv: NDArray[np.float64]


def _start(t: float, mu: NDArray[np.float64], var: NDArray[np.float64], params: ReadingFilterParams
           ) -> ReadingState:
    # unknown velocity: the speed a joint reaches within the gap the filter bridges
    v0 = (params.accel * params.max_gap_s) ** 2
    return ReadingState(t, mu.copy(), np.zeros_like(mu), var.copy(), np.zeros_like(mu), np.full_like(mu, v0))


def filter_reading(state: ReadingState | None, t: float, mu: NDArray[np.floating[Any]],
                   var: NDArray[np.floating[Any]], params: ReadingFilterParams
                   ) -> tuple[ReadingState, NDArray[np.float64], NDArray[np.float64]]:
    """One predict/update step of the constant-velocity filter.

    Parameters
    ----------
    state : ReadingState or None
        None, a gap longer than ``params.max_gap_s``, time not moving forward, or a state of another
        shape restarts the filter at this reading.
    t : float
        Time of the reading (s).
    mu : (J, 3) float
        The network's reading.
    var : (J, 3) float
        Its variance (positive).
    params : ReadingFilterParams

    Returns
    -------
    state : ReadingState
    mu : (J, 3) float64
        The filtered reading.
    var : (J, 3) float64
        Its posterior variance (never larger than ``var``).
    """
    m: NDArray[np.float64] = np.asarray(mu, np.float64)
    v2: NDArray[np.float64] = np.maximum(np.asarray(var, np.float64), 1e-12)
    if (state is None or state.x.shape != m.shape or not (0.0 < t - state.t <= params.max_gap_s)
            or not np.all(np.isfinite(state.x))):
        new = _start(t, m, v2, params)
        return new, new.x.copy(), new.pxx.copy()
    dt = t - state.t
    q = params.accel ** 2
    # predict (white-noise acceleration)
    x = state.x + dt * state.v
    v = state.v
    pxx = state.pxx + 2.0 * dt * state.pxv + dt * dt * state.pvv + q * dt ** 4 / 4.0
    pxv = state.pxv + dt * state.pvv + q * dt ** 3 / 2.0
    pvv = state.pvv + q * dt * dt
    # update with the reading, its variance the measurement noise
    s = pxx + v2
    kx, kv = pxx / s, pxv / s
    r = m - x
    x = x + kx * r
    v = v + kv * r
    pvv = pvv - kv * pxv
    pxv = pxv - kx * pxv
    pxx = pxx - kx * pxx
    new = ReadingState(t, x, v, pxx, pxv, pvv)
    return new, x.copy(), pxx.copy()
