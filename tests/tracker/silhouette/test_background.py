import cv2
import numpy as np
import pytest

from tracker_service.silhouette.background import (
    BackgroundParams,
    clean_mask,
    clean_mask_reference,
    exposure_gain,
    learn_background,
    measured_exposure,
    raw_foreground,
    raw_foreground_reference,
    subtract,
    update_background,
    update_background_reference,
)


def _room(rng: np.random.Generator, h: int = 120, w: int = 160) -> np.ndarray:
    img = np.zeros((h, w, 3), np.float32)
    img[:] = (150, 160, 170)
    img[: h // 2] = (120, 140, 180)  # wall / floor
    for _ in range(6):  # furniture
        x, y = rng.integers(0, w - 30), rng.integers(0, h - 30)
        img[y: y + 25, x: x + 28] = rng.uniform(40, 220, 3)
    img += rng.normal(0, 6, (h, w, 1))  # texture
    return np.clip(img, 0, 255)


def _frames(rng: np.random.Generator, base: np.ndarray, n: int, gain: float = 1.0) -> np.ndarray:
    return np.clip(base[None] * gain + rng.normal(0, 2.0, (n, *base.shape)), 0, 255).astype(np.uint8)


def _person_mask(h: int = 120, w: int = 160) -> np.ndarray:
    m = np.zeros((h, w), np.uint8)
    cv2.ellipse(m, (80, 55), (12, 25), 0, 0, 360, 1, -1)
    cv2.circle(m, (80, 24), 8, 1, -1)
    cv2.line(m, (75, 75), (72, 112), 1, 6)
    cv2.line(m, (85, 75), (88, 112), 1, 6)
    return m.astype(bool)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def test_silhouette_with_shadow_and_exposure_jitter(rng: np.random.Generator) -> None:
    base = _room(rng)
    model = learn_background(_frames(rng, base, 20))
    truth = _person_mask()
    frame = base.copy() * 1.08  # exposure jitter
    shadow = np.zeros(truth.shape, bool)
    shadow[108:118, 60:120] = True
    frame[shadow] *= 0.6  # soft cast shadow on the floor
    frame[truth] = (60, 60, 62)  # dark grey clothing
    frame = np.clip(frame + rng.normal(0, 2.0, frame.shape), 0, 255).astype(np.uint8)
    sil = subtract(model, frame)
    assert _iou(sil, truth) > 0.9
    assert not sil[shadow & ~cv2.dilate(truth.astype(np.uint8), np.ones((5, 5))).astype(bool)].any()


def test_empty_scene_gives_empty_mask(rng: np.random.Generator) -> None:
    base = _room(rng)
    model = learn_background(_frames(rng, base, 10))
    for gain in (0.9, 1.0, 1.12):
        assert not subtract(model, _frames(rng, base, 1, gain)[0]).any()


@pytest.mark.parametrize("gain", [0.5, 1.35])
def test_exposure_drift_beyond_the_highlight_ratio_keeps_the_room_background(rng: np.random.Generator,
                                                                             gain: float) -> None:
    # an automatic exposure that darkens the whole frame by half or brightens it by 35 %: past the brightness
    # test's ratios, so without following the exposure nearly the whole room turns foreground
    base = _room(rng) * 0.75  # room for the brighter frame below 240
    model = learn_background(_frames(rng, base, 12))
    truth = _person_mask()
    lit = base * gain
    lit[truth] = (60, 200, 60)
    frame = np.clip(lit + rng.normal(0, 2.0, lit.shape), 0, 255).astype(np.uint8)
    assert measured_exposure(model, frame) == pytest.approx(gain, rel=0.03)
    tol = BackgroundParams().exposure_tolerance  # the bounds absorb the first 5 %
    assert exposure_gain(model, frame) == pytest.approx(measured_exposure(model, frame) / (1 + np.sign(gain - 1) * tol))
    assert exposure_gain(model, frame, BackgroundParams(exposure=False)) == 1.0
    assert raw_foreground(model, frame, BackgroundParams(exposure=False))[~truth].mean() > 0.3
    sil = subtract(model, frame)
    assert _iou(sil, truth) > 0.9


def test_exposure_gain_ignores_the_person_and_clipped_pixels(rng: np.random.Generator) -> None:
    base = _room(rng)
    model = learn_background(_frames(rng, base, 12))
    frame = _frames(rng, base, 1, 1.1)[0]
    frame[20:100, 40:120] = (250, 250, 250)  # a third of the image: a white-clad person, clipped
    assert measured_exposure(model, frame) == pytest.approx(1.1, rel=0.02)
    assert exposure_gain(model, _frames(rng, base, 1, 1.03)[0]) == 1.0  # within the bounds' own tolerance
    frame[:] = 255  # nothing left that measures it
    assert measured_exposure(model, frame) == 1.0 and exposure_gain(model, frame) == 1.0


def test_clean_mask_keeps_largest_component_and_fills_holes() -> None:
    m = np.zeros((50, 50), bool)
    m[10:40, 10:30] = True
    m[20:25, 15:20] = False  # hole
    m[2:4, 45:48] = True  # speck
    out = clean_mask(m, BackgroundParams(open_px=1, close_px=1))
    assert out[22, 17] and not out[3, 46]
    assert out.sum() == 30 * 20


@pytest.mark.parametrize("open_px,close_px", [(3, 5), (1, 1), (5, 9), (3, 1)])
def test_clean_mask_in_the_box_equals_the_whole_image(open_px: int, close_px: int) -> None:
    """The box-cropped clean-up gives the whole-image result bit for bit: blobs with holes and
    notches, specks, several components, a person touching each image border and the corners,
    a hole that opens to the box's edge, and empty or all-speck masks."""
    rng = np.random.default_rng(23)
    params = BackgroundParams(open_px=open_px, close_px=close_px)
    cases = []
    for k in range(120):
        h, w = (60, 80) if k % 2 else (120, 160)
        m = np.zeros((h, w), bool)
        for _ in range(int(rng.integers(0, 4))):  # blobs
            y0, x0 = int(rng.integers(-10, h)), int(rng.integers(-10, w))
            m[max(y0, 0):y0 + int(rng.integers(5, h // 2)), max(x0, 0):x0 + int(rng.integers(3, w // 3))] = True
        m ^= rng.random((h, w)) < (0.02 if k % 3 else 0.15)  # specks and pinholes
        if k % 5 == 0:  # a person against one border or a corner
            side = int(rng.integers(0, 4))
            sl = [(slice(0, h // 2), slice(w // 3, w // 2)), (slice(h // 2, h), slice(w // 3, w // 2)),
                  (slice(h // 4, h // 2), slice(0, w // 4)), (slice(h // 2, h), slice(w - w // 4, w))][side]
            m[sl] = True
            m[sl[0].start + 2:sl[0].stop - 2, sl[1].start + 2:sl[1].start + 4] = False  # a hole or a notch
        cases.append(m)
    cases += [np.zeros((60, 80), bool), np.ones((60, 80), bool)]
    for m in cases:
        np.testing.assert_array_equal(clean_mask(m, params), clean_mask_reference(m, params))


def test_adaptive_update_absorbs_a_slow_change(rng: np.random.Generator) -> None:
    base = _room(rng)
    model = learn_background(_frames(rng, base, 10))
    moved = base.copy()
    moved[5:20, 5:40] = (30, 200, 30)  # an object placed in the room
    frame = _frames(rng, moved, 1)[0]
    assert subtract(model, frame).any()
    for _ in range(400):
        model = update_background(model, _frames(rng, moved, 1)[0], np.zeros(base.shape[:2], bool), rate=0.05)
    assert not subtract(model, frame).any()


@pytest.mark.parametrize("gain", [0.8, 1.1])
def test_update_kernel_matches_numpy_reference(rng: np.random.Generator, gain: float) -> None:
    base = _room(rng)
    model = learn_background(_frames(rng, base, 10))
    frame = _frames(rng, base, 1, gain)[0]
    frame[:8, :8] = 0  # black: chromaticity undefined
    fg = _person_mask()
    fast = update_background(model, frame, fg, rate=0.05)
    ref = update_background_reference(model, frame, fg, rate=0.05)
    for name in ("chroma_mean", "chroma_inv_var", "bright_mean", "bright_std"):
        a, b = getattr(fast, name), getattr(ref, name)
        assert a.dtype == b.dtype == np.float32 and a.shape == b.shape
        np.testing.assert_allclose(a, b, rtol=2e-5, atol=1e-6)
    odd = update_background(model, frame, fg, rate=0.05, rows=(1, 2))  # every other row
    np.testing.assert_allclose(odd.bright_mean, update_background_reference(model, frame, fg, 0.05, (1, 2)).bright_mean,
                               rtol=2e-5, atol=1e-6)
    np.testing.assert_array_equal(odd.bright_mean[0::2], model.bright_mean[0::2])
    np.testing.assert_array_equal(fast.bright_mean[fg], model.bright_mean[fg])  # the person left alone
    assert not np.array_equal(fast.bright_mean[~fg], model.bright_mean[~fg])
    assert model.bright_mean is not fast.bright_mean  # a new model; the old one unchanged


def test_bad_input_is_rejected(rng: np.random.Generator) -> None:
    with pytest.raises(ValueError):
        learn_background(np.zeros((1, 10, 10, 3), np.uint8))
    model = learn_background(_frames(rng, _room(rng), 3))
    with pytest.raises(ValueError, match="does not match"):
        subtract(model, np.zeros((10, 10, 3), np.uint8))


@pytest.mark.parametrize("gain", [0.7, 1.0, 1.15])
def test_foreground_kernel_matches_numpy_reference(rng: np.random.Generator, gain: float) -> None:
    base = _room(rng)
    model = learn_background(_frames(rng, base, 12))
    frame = _frames(rng, base, 1, gain)[0]
    frame[_person_mask()] = rng.integers(0, 256, (int(_person_mask().sum()), 3))
    frame[:10, :10] = 0  # black pixels: chromaticity undefined
    frame[-10:, -10:] = 255
    for params in (BackgroundParams(), BackgroundParams(chroma_threshold=1.5, shadow_ratio=0.5, dark_level=60.0),
                   BackgroundParams(exposure=False)):
        fast = raw_foreground(model, frame, params)
        ref = raw_foreground_reference(model, frame, params)
        assert fast.dtype == bool and fast.shape == ref.shape
        assert 0.01 < ref.mean() < 0.99  # both classes present: the comparison means something
        np.testing.assert_array_equal(fast, ref)
    for g in (0.8, 1.3):  # an explicit gain
        np.testing.assert_array_equal(raw_foreground(model, frame, gain=g),
                                      raw_foreground_reference(model, frame, gain=g))


def test_the_robust_model_learns_the_room_behind_a_moving_person(rng: np.random.Generator) -> None:
    """Frames that all show a person (a block moving across the room): the median-based model learns
    the room behind them, so the empty room reads empty and the person is seen wherever they stand;
    the mean-based model, its spread inflated where the person passed, misses them there."""
    from tracker_service.silhouette.background import learn_background, learn_background_robust, subtract

    room = rng.integers(40, 200, (60, 80, 3), dtype=np.uint8)

    def shot(x0: int | None) -> np.ndarray:
        f = room.copy()
        if x0 is not None:
            f[10:55, x0:x0 + 10] = (30, 140, 220)  # the person
        return np.clip(f.astype(np.int16) + rng.integers(-2, 3, f.shape), 0, 255).astype(np.uint8)

    frames = np.stack([shot(4 + 8 * k) for k in range(9)])  # somewhere else in every frame
    robust, plain = learn_background_robust(frames), learn_background(frames)
    assert subtract(robust, shot(None)).mean() < 0.005
    person = np.zeros((60, 80), bool)
    person[10:55, 36:46] = True
    seen_robust = subtract(robust, shot(36))[person].mean()
    seen_plain = subtract(plain, shot(36))[person].mean()
    assert seen_robust > 0.95 and seen_plain < 0.7  # (measured: 0.99 and 0.55)


def test_the_parts_of_a_person_split_by_a_wall_coloured_shirt_are_kept() -> None:
    """Legs under a missing waist and a head over a missing neck are parts of the person; a speck
    and a piece far to the side are not."""
    m = np.zeros((120, 160), bool)
    m[20:60, 70:90] = True  # torso and arms (the largest piece)
    m[70:110, 72:88] = True  # legs under a missing waist
    m[8:17, 76:84] = True  # the head over a missing neck
    m[50:53, 150:153] = True  # a speck
    m[30:60, 0:12] = True  # something large far to the side
    m[30:45, 64:67] = True  # a forearm piece beside the torso, within its rows
    m[0:6, 93:99] = True  # off the corner, above the head and beside it: a shadow on the wall, no head
    m[72:80, 91:95] = True  # a hand beside the legs (a piece below the largest), off the largest's corner
    out = clean_mask(m, BackgroundParams(open_px=1, close_px=1))
    assert out[90, 80] and out[12, 80] and out[40, 80] and out[35, 65] and out[76, 93]
    assert not out[51, 151] and not out[40, 5] and not out[3, 95]
    alone = clean_mask(m, BackgroundParams(open_px=1, close_px=1, part_frac=1.0))
    assert alone[40, 80] and not alone[90, 80] and not alone[12, 80]
    assert np.array_equal(out, clean_mask_reference(m, BackgroundParams(open_px=1, close_px=1)))


def test_a_thin_arm_the_opening_erases_comes_back_where_it_touches_the_person() -> None:
    """Opening by reconstruction: a 2-pixel arm raised from the shoulder (bare skin against a wall
    of nearly its colour) survives; a speck and a thin line apart from the person do not."""
    m = np.zeros((120, 160), bool)
    m[30:110, 70:90] = True  # the body
    for k in range(25):  # an arm raised up and out from the shoulder, 2 px wide
        m[30 - k, 89 + k:91 + k] = True
    m[60:62, 130:150] = True  # a thin line apart
    m[10:12, 20:22] = True  # a speck
    out = clean_mask(m, BackgroundParams())
    assert out[80, 80] and out[18, 101] and out[8, 111]
    assert not out[61, 140] and not out[11, 21]
    opened = clean_mask(m, BackgroundParams(reconstruct=False))
    assert opened[80, 80] and not opened[18, 101]
    assert np.array_equal(out, clean_mask_reference(m, BackgroundParams()))


def test_a_noisy_camera_is_smoothed_before_subtraction(rng: np.random.Generator) -> None:
    base = _room(rng)
    quiet = learn_background(_frames(rng, base, 10))
    assert quiet.smooth_sigma == 0.0
    noisy_frames = np.clip(base[None] + rng.normal(0, 12.0, (10, *base.shape)), 0, 255).astype(np.uint8)
    noisy = learn_background(noisy_frames)
    assert 0.7 <= noisy.smooth_sigma <= 1.5
    truth = _person_mask()
    frame = base.copy()
    frame[truth] = base[truth] * 0.55 + 40  # a person whose clothes are close to the room's colours
    frame = np.clip(frame + rng.normal(0, 12.0, frame.shape), 0, 255).astype(np.uint8)
    with_smoothing = subtract(noisy, frame)
    without = subtract(_unsmoothed(noisy_frames), frame)
    assert _iou(with_smoothing, truth) > _iou(without, truth) + 0.05
    assert np.array_equal(raw_foreground(noisy, frame), raw_foreground_reference(noisy, frame))


def _unsmoothed(frames: np.ndarray):  # type: ignore[no-untyped-def]
    """The model of ``frames`` as it was before noise-adaptive smoothing."""
    from tracker_service.silhouette.background import _chroma_bright, _model

    c, b = _chroma_bright(frames)
    return _model(c.mean(axis=0), c.std(axis=0), b.mean(axis=0), b.std(axis=0), len(frames), 0.004, 2.0)


def test_a_camera_whose_colour_is_subsampled_gets_the_wider_chroma_threshold(rng: np.random.Generator) -> None:
    """MJPEG and H.264 keep colour at half resolution (4:2:0): detected from the learning frames,
    and the chroma test is wider for them (their colour bleeds across the person's outline)."""
    from protocol.formats.video import VideoWriter  # noqa: F401  (PyAV is a dependency)
    from tracker_service.scene.variation import h264_roundtrip
    from tracker_service.silhouette.background import chroma_detail, chroma_subsampled, chroma_threshold_of

    base = np.clip(_room(rng) + rng.normal(0, 6, (120, 160, 3)), 0, 255)  # colour detail at every pixel
    frames = _frames(rng, base, 6)
    assert chroma_detail(frames[0]) > 0.44 and not chroma_subsampled(frames)
    jpeg = np.stack([cv2.imdecode(cv2.imencode(".jpg", f, [cv2.IMWRITE_JPEG_QUALITY, 70])[1], cv2.IMREAD_COLOR)
                     for f in frames])
    h264 = np.stack([h264_roundtrip(f, 28) for f in frames])
    assert chroma_subsampled(jpeg) and chroma_subsampled(h264)
    params = BackgroundParams()
    quiet, coded = learn_background(frames), learn_background(jpeg)
    assert not quiet.subsampled and chroma_threshold_of(quiet, params) == params.chroma_threshold
    assert coded.subsampled and chroma_threshold_of(coded, params) == params.chroma_threshold_subsampled
    frame = jpeg[0].copy()
    frame[_person_mask()] = (90, 140, 200)
    assert np.array_equal(raw_foreground(coded, frame), raw_foreground_reference(coded, frame))
