import math

import numpy as np
import pytest

from tracker_service.app.evaluate import acceleration_error, confidence_error_spearman, reacquisition_times

FPS = 30.0


def _clip(err: list[float]) -> tuple[np.ndarray, np.ndarray]:
    return np.arange(len(err)) / FPS, np.asarray(err, float)


def test_back_within_10cm_counts_from_the_loss_to_the_first_good_frame() -> None:
    err = [0.05] * 30 + [0.40] * 10 + [0.06] * 40  # loss at frame 29; good again from frame 40
    t, e = _clip(err)
    (dt,) = reacquisition_times(t, e, [29], FPS)
    assert dt == pytest.approx(11 / FPS)


def test_a_track_worse_than_10cm_is_back_at_its_own_accuracy() -> None:
    err = [0.14] * 30 + [0.45] * 6 + [0.16] * 40  # 0.16 < 1.25 x 0.14
    t, e = _clip(err)
    assert reacquisition_times(t, e, [29], FPS) == [pytest.approx(7 / FPS)]
    assert reacquisition_times(t, e, [29], FPS, relative=1.0) == [math.inf]  # never within 14 cm


def test_isolated_good_frames_are_not_a_reacquisition() -> None:
    err = [0.05] * 30 + [0.3, 0.05, 0.05, 0.3] * 8 + [0.05] * 30
    t, e = _clip(err)
    (dt,) = reacquisition_times(t, e, [29], FPS)
    assert dt == pytest.approx(33 / FPS)


def test_a_loss_not_yet_back_in_the_last_second_is_not_judged() -> None:
    t, e = _clip([0.05] * 62 + [0.4] * 18)
    assert reacquisition_times(t, e, [61], FPS) == []  # 0.6 s left
    t, e = _clip([0.05] * 40 + [0.4] * 40)
    assert reacquisition_times(t, e, [39], FPS) == [math.inf]  # 1.33 s left and never back
    quick = [0.05] * 70 + [0.4, 0.05, 0.05, 0.05, 0.05]
    t, e = _clip(quick)
    assert reacquisition_times(t, e, [69], FPS) == [pytest.approx(2 / FPS)]  # back with 0.13 s left


def test_acceleration_error_is_zero_for_a_constant_offset_and_counts_only_consecutive_frames() -> None:
    rng = np.random.default_rng(0)
    true = np.cumsum(rng.normal(0.0, 0.01, (10, 4, 3)), axis=0)
    frames = np.arange(10)
    assert acceleration_error(frames, true + 0.05, true) == pytest.approx(0.0, abs=1e-12)  # a bias is no jitter
    est = true.copy()
    est[5, 2] += np.array([0.03, 0.0, 0.04])  # one joint pops by 5 cm on one frame
    # the pop's second difference is 5, -10, 5 cm at frames 4, 5, 6 on one of 4 joints, over 8 triples
    assert acceleration_error(frames, est, true) == pytest.approx((0.05 + 0.10 + 0.05) / 4 / 8)
    gap = np.array([0, 1, 2, 4, 5, 7])  # only (0, 1, 2) is three consecutive frames
    assert acceleration_error(gap, est[:6], true[:6]) == pytest.approx(0.0, abs=1e-12)
    assert math.isnan(acceleration_error(np.array([0, 2, 4]), est[:3], true[:3]))
    assert math.isnan(acceleration_error(np.arange(2), est[:2], true[:2]))


def test_jpeg_roundtrip_degrades_like_mjpeg() -> None:
    """``eval --jpeg-quality Q`` feeds the tracker each frame through JPEG: same shape and type,
    small errors that grow as the quality falls."""
    from tracker_service.app.evaluate import jpeg_roundtrip

    rng = np.random.default_rng(0)
    img = np.clip(rng.normal(120, 40, (240, 320, 3)), 0, 255).astype(np.uint8)
    hi, lo = jpeg_roundtrip(img, 95), jpeg_roundtrip(img, 30)
    assert hi.shape == img.shape and hi.dtype == np.uint8
    err = [np.abs(x.astype(int) - img).mean() for x in (hi, lo)]
    assert 0 < err[0] < err[1]


def test_confidence_error_correlation() -> None:
    rng = np.random.default_rng(0)
    err = rng.uniform(0.02, 0.2, 50)
    assert confidence_error_spearman(list(1 - err), list(err)) == pytest.approx(-1.0)
    assert abs(confidence_error_spearman(list(rng.random(50)), list(err)) or 0.0) < 0.4
    assert confidence_error_spearman([0.5] * 50, list(err)) is None  # a constant confidence says nothing
    assert confidence_error_spearman([0.1, 0.2], [0.3, 0.1]) is None  # too few frames


@pytest.mark.parametrize("size", [(640, 480), (1280, 720), (320, 240), (480, 640)])
def test_a_widened_camera_brought_to_the_working_size_is_the_working_camera(size: tuple[int, int]) -> None:
    from tracker_service.app.evaluate import widened
    from tracker_service.camera import default_camera

    cam = default_camera()
    wide = widened(cam, size)
    assert wide.size == size and np.allclose(wide.pose, cam.pose)
    back = wide.fitted(cam.size)
    assert back.size == cam.size
    assert back.fx == pytest.approx(cam.fx, rel=2e-3) and back.fy == pytest.approx(cam.fy, rel=2e-3)
    assert abs(back.cx - cam.cx) <= 0.5 and abs(back.cy - cam.cy) <= 0.5  # the crop's rounding


def test_joint_jumps_count_only_what_the_truth_does_not_do() -> None:
    from tracker_service.app.error_metrics import joint_jumps

    frames = np.arange(8)
    true = np.zeros((8, 3, 3))
    true[4:, 1, 0] = 0.5  # the truth itself moves a joint 50 cm in one frame: no jump
    assert joint_jumps(frames, true + 0.02, true) == (0, pytest.approx(0.0, abs=1e-12))
    est = true.copy()
    est[5, 2, 1] += 0.20  # a joint pops 20 cm for one frame: two pairs jump (out and back)
    pairs, worst = joint_jumps(frames, est, true)
    assert pairs == 2 and worst == pytest.approx(0.20)
    assert joint_jumps(frames, est, true, limit_m=0.25)[0] == 0
    assert joint_jumps(np.array([0, 2, 4, 5, 7, 9, 11, 13]), est, true)[0] == 0  # (4, 5) is the only pair: no pop
    assert joint_jumps(np.arange(1), est[:1], true[:1]) == (0, 0.0)
