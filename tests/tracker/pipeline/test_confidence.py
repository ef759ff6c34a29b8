"""The published confidence (``pipeline/confidence.py``): from the expected error, falling with it."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from tracker_service.pipeline.confidence import CONFIDENCE_SCALE_M, expected_error, pose_confidence


def test_expected_error_is_the_move_and_the_readings_sigma_in_quadrature(rng: np.random.Generator) -> None:
    before = rng.normal(size=(24, 3))
    after = before + np.array([0.03, 0.0, 0.04])  # every joint moved 5 cm
    var = np.full((24, 3), (0.12 / 1.7) ** 2)  # 12 cm at 1.7 m
    assert expected_error(before, after, var, 1.7) == pytest.approx(math.hypot(0.05, 0.12))
    assert expected_error(before, before, np.zeros((24, 3)), 1.7) == 0.0
    assert math.isnan(expected_error(before, after * np.nan, var, 1.7))


def test_confidence_falls_with_the_expected_error_and_falls_back_to_the_silhouette() -> None:
    errors = [0.0, 0.05, CONFIDENCE_SCALE_M, 0.2, 0.4]
    conf = [pose_confidence(e, silhouette=0.3) for e in errors]
    assert conf[0] == 1.0 and all(a > b for a, b in itertools.pairwise(conf))
    assert conf[2] == pytest.approx(math.exp(-0.5))
    assert all(0.0 <= c <= 1.0 for c in conf)
    assert pose_confidence(math.nan, silhouette=0.3) == 0.3  # no reading: the silhouette match
    assert pose_confidence(math.nan, silhouette=1.7) == 1.0
