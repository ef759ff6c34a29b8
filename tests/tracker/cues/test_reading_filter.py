"""The Kalman filter of the appearance network's readings (tracker_service/cues/reading_filter.py)."""

import numpy as np
import pytest

from tracker_service.cues.reading_filter import ReadingFilterParams, ReadingState, filter_reading

DT = 1.0 / 30.0


def run(mu: np.ndarray, var: np.ndarray, params: ReadingFilterParams, t0: float = 0.0
        ) -> tuple[ReadingState, np.ndarray, np.ndarray]:
    state = None
    out, outv = [], []
    for i in range(len(mu)):
        state, m, v = filter_reading(state, t0 + i * DT, mu[i], var[i], params)
        out.append(m)
        outv.append(v)
    assert state is not None
    return state, np.array(out), np.array(outv)


def test_noise_is_averaged_and_the_variance_shrinks() -> None:
    rng = np.random.default_rng(1)
    truth = np.tile(rng.normal(0.0, 0.3, (1, 22, 3)), (90, 1, 1))  # a still person
    var = np.full_like(truth, 0.02 ** 2)
    noisy = truth + rng.normal(0.0, 0.02, truth.shape)
    _, out, outv = run(noisy, var, ReadingFilterParams())
    raw_err = np.abs(noisy[30:] - truth[30:]).mean()
    assert np.abs(out[30:] - truth[30:]).mean() < 0.9 * raw_err

    def accel(x: np.ndarray) -> float:
        return float(np.abs(x[2:] - 2.0 * x[1:-1] + x[:-2])[30:].mean())

    # the default process noise is light (a hand may reverse its swing in a few frames), so the
    # tremble is cut by ~40 %, not removed
    assert accel(out) < 0.7 * accel(noisy)
    assert np.all(outv <= var + 1e-15)
    assert outv[-1].max() < 0.85 * var.max()
    _, hard, _ = run(noisy, var, ReadingFilterParams(accel=2.0))  # less process noise: smoother
    assert accel(hard) < 0.5 * accel(out)


def test_a_constant_velocity_is_followed_without_lag() -> None:
    t = np.arange(60) * DT
    truth = np.zeros((60, 22, 3))
    truth[..., 0] = 0.5 * t[:, None]  # every joint drifting at half a height per second
    var = np.full_like(truth, 0.01 ** 2)
    _, out, _ = run(truth, var, ReadingFilterParams())
    assert np.abs(out[20:] - truth[20:]).max() < 1e-3


def test_a_confident_reading_moves_the_estimate_more_than_an_unsure_one() -> None:
    mu = np.zeros((20, 1, 3))
    mu[-1] = 0.1  # a jump on the last frame
    sure = np.full_like(mu, 0.01 ** 2)
    unsure = sure.copy()
    unsure[-1] = 0.2 ** 2
    _, a, _ = run(mu, sure, ReadingFilterParams())
    _, b, _ = run(mu, unsure, ReadingFilterParams())
    assert a[-1, 0, 0] > 0.05 and b[-1, 0, 0] < 0.02


@pytest.mark.parametrize("gap", [0.0, -0.1, 1.0])
def test_restarts_at_the_reading_after_a_gap_or_when_time_does_not_advance(gap: float) -> None:
    prm = ReadingFilterParams()
    state, _, _ = run(np.zeros((10, 2, 3)), np.full((10, 2, 3), 1e-4), prm)
    mu = np.full((2, 3), 0.3)
    var = np.full((2, 3), 1e-2)
    new, m, v = filter_reading(state, state.t + gap, mu, var, prm)
    assert np.array_equal(m, mu) and np.array_equal(v, var) and new.t == state.t + gap
    # another skeleton's shape restarts too
    s3, m3, v3 = filter_reading(state, state.t + DT, np.full((3, 3), 0.2), np.ones((3, 3)), prm)
    assert m3.shape == (3, 3) and np.all(m3 == 0.2) and np.all(v3 == 1.0) and s3.x.shape == (3, 3)


def test_the_filter_returns_new_arrays_and_leaves_its_input_alone() -> None:
    mu = np.zeros((2, 1, 3))
    var = np.full((2, 1, 3), 1e-2)
    prm = ReadingFilterParams()
    state, m, _ = filter_reading(None, 0.0, mu[0], var[0], prm)
    m[:] = 5.0
    assert np.all(state.x == 0.0) and np.all(mu == 0.0)
    mu[1] = 0.1
    state2, m2, v2 = filter_reading(state, DT, mu[1], var[1], prm)  # the update path
    assert 0.0 < m2[0, 0] < 0.1
    m2[:] = 5.0
    v2[:] = 5.0
    assert np.all(state2.x < 0.1) and np.all(state2.pxx < 1e-2) and np.all(mu[1] == 0.1)
    assert np.all(state.x == 0.0)  # the old state is not changed by the step
