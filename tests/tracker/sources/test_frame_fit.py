"""Frames of any size reach the tracker at its working size with their aspect kept."""

from __future__ import annotations

import numpy as np
import pytest

from tracker_service.camera import fit_box
from tracker_service.sources.frame_source import fit_frame


def _disc(w: int, h: int, r: float) -> np.ndarray:
    """A white disc of radius ``r`` (a fraction of the height) at the centre of a black frame."""
    yy, xx = np.mgrid[:h, :w]
    img = np.zeros((h, w, 3), np.uint8)
    img[(xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2 <= (r * h) ** 2] = 255
    return img


@pytest.mark.parametrize("w,h", [(320, 240), (640, 480), (1280, 720), (720, 1280), (160, 90)])
def test_a_circle_stays_a_circle(w: int, h: int) -> None:
    out = fit_frame(_disc(w, h, 0.2), (320, 240))
    assert out.shape == (240, 320, 3) and out.dtype == np.uint8
    ys, xs = np.nonzero(out[..., 0] > 127)
    width, height = np.ptp(xs) + 1, np.ptp(ys) + 1
    assert abs(width / height - 1.0) < 0.05  # never stretched
    assert abs(xs.mean() - 159.5) < 1.0 and abs(ys.mean() - 119.5) < 1.0  # the centre stays the centre


def test_a_wide_frame_keeps_its_vertical_field_of_view() -> None:
    img = np.zeros((720, 1280, 3), np.uint8)
    img[:, 640 - 3:640 + 3] = 255  # a vertical line over the full height
    out = fit_frame(img, (320, 240))
    col = out[:, 158:162, 0].max(axis=1)
    assert (col > 0).all()  # the whole height survives; the sides are cropped


def test_the_synthetic_source_films_with_the_camera_the_tracker_is_told_about() -> None:
    """``run --source synthetic --camera ...`` and ``eval --camera ...``: the scene is filmed by that
    camera and its frames are brought to the working size like a real camera's."""
    from pathlib import Path

    from tracker_service.app.evaluate import _scene_camera, widened
    from tracker_service.app.options import EvalOptions
    from tracker_service.camera import default_camera, placed_camera
    from tracker_service.sources.frame_source import open_source, parse_source

    script = Path(__file__).resolve().parents[3] / "protocol" / "scripts" / "crouch.toml"
    cam = placed_camera(height_m=1.8, tilt_deg=15.0, width=640, height=480)
    src = open_source(parse_source(f"synthetic:{script}"), (320, 240), camera=cam, empty_prefix=1)
    try:
        assert src.scene.camera is cam  # type: ignore[attr-defined]
        _, frame = next(iter(src))
        assert frame.shape == (240, 320, 3)
    finally:
        src.close()
    work = default_camera()
    assert _scene_camera(work, EvalOptions()) is None
    assert _scene_camera(work, EvalOptions(camera=cam)) is cam
    wide = _scene_camera(work, EvalOptions(camera=cam, input_size=(1280, 720)))
    expect = widened(cam.fitted((320, 240)), (1280, 720))
    assert wide is not None and wide.size == (1280, 720) and np.allclose(wide.K, expect.K)
    assert np.allclose(wide.pose, cam.pose)


@pytest.mark.parametrize("size,box", [
    ((640, 480), (0, 0, 640, 480, 2)),
    ((1280, 720), (160, 0, 960, 720, 2)),
    ((1920, 1080), (240, 0, 1440, 1080, 4)),
    ((160, 90), (20, 0, 120, 90, 1)),
])
def test_the_crop_is_the_centre_with_the_working_aspect(size: tuple[int, int],
                                                        box: tuple[int, int, int, int, int]) -> None:
    x0, y0, cw, ch, k = fit_box(size, (320, 240))
    assert (x0, y0, cw, ch, k) == box
    assert cw % k == 0 and ch % k == 0 and cw * 3 == ch * 4  # halved exactly, 4:3


def test_an_hd_frame_is_averaged_not_sampled() -> None:
    """A fine pattern (one-pixel stripes) becomes its mean grey, as a lens would blur it, not stripes
    of a sampling's beat: the halvings average every pixel of the crop."""
    img = np.zeros((1080, 1920, 3), np.uint8)
    img[:, ::2] = 200
    out = fit_frame(img, (320, 240)).astype(np.float64)
    assert abs(out.mean() - 100.0) < 1.0 and out.std() < 3.0
