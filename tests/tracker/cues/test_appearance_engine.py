"""OpenCV's DNN engine runs the appearance network as its numpy reference does."""

from __future__ import annotations

import numpy as np
import pytest

from tracker_service.cues.appearance import forward, load_appearance, predict_joints, shipped_appearance_path
from tracker_service.cues.appearance_engine import AppearanceEngine


@pytest.fixture(scope="module")
def shipped():  # type: ignore[no-untyped-def]
    path = shipped_appearance_path()
    assert path is not None
    return load_appearance(path)


@pytest.mark.parametrize("batch", [1, 2])
def test_the_engine_equals_the_numpy_reference(shipped, batch: int, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    x = (rng.random((batch, shipped.size, shipped.size, 4)) - 0.5).astype(np.float32)
    outs = AppearanceEngine(shipped).forward(x)
    assert len(outs) == len(shipped.networks)
    for k, out in enumerate(outs):
        ref = forward(shipped, x, k)
        assert out.shape == ref.shape == (batch, shipped.n_outputs)
        np.testing.assert_allclose(out, ref, atol=1e-4, rtol=1e-4)


def test_predict_joints_uses_the_engine_kept_with_the_network(shipped) -> None:  # type: ignore[no-untyped-def]
    frame = np.full((240, 320, 3), 90, np.uint8)
    mask = np.zeros((240, 320), bool)
    mask[60:200, 140:180] = True
    frame[mask] = (40, 60, 200)
    got = predict_joints(shipped, frame, mask, mirror=True)
    assert got is not None and np.isfinite(got[0]).all() and (got[1] > 0).all()
    assert shipped.engine is shipped.engine  # made once
