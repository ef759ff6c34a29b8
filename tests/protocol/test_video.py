"""protocol.formats.video: H.264 MP4 (yuv420p, even sizes) a browser plays, GIF for .gif paths."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from protocol.formats.video import VideoWriter, even_frame, read_frames, video_info


def _frames(n: int, h: int = 121, w: int = 161) -> list[np.ndarray]:
    out = []
    for i in range(n):
        f = np.zeros((h, w, 3), np.uint8)
        f[:, :, 0] = 40 + 15 * i  # blue ramps with the frame number
        f[:, :, 1] = np.linspace(0, 200, w, dtype=np.uint8)[None, :]
        f[:, :, 2] = 120
        cv2.rectangle(f, (10 + 5 * i, 20), (40 + 5 * i, 60), (255, 255, 255), -1)
        out.append(f)
    return out


def test_mp4_is_h264_yuv420p_with_even_size_and_reads_back(tmp_path: Path) -> None:
    frames = _frames(10)
    path = tmp_path / "sub" / "clip.mp4"
    with VideoWriter(path, fps=30) as video:
        for f in frames:
            video.write(f)
    assert video.frames == 10 and video.size == (161, 121)
    info = video_info(path)
    assert (info.codec, info.pix_fmt) == ("h264", "yuv420p")
    assert (info.width, info.height, info.frames) == (162, 122, 10)
    assert info.fps == pytest.approx(30.0)
    back = read_frames(path)
    assert len(back) == 10
    for a, b in zip(frames, back, strict=True):
        err = np.abs(b[:121, :161].astype(np.int16) - a.astype(np.int16))
        assert err.mean() < 4.0  # lossy, but the same picture
    cap = cv2.VideoCapture(str(path))  # and OpenCV's FFmpeg decodes it too
    n = 0
    while cap.read()[0]:
        n += 1
    cap.release()
    assert n == 10


def test_gif_only_for_a_gif_path(tmp_path: Path) -> None:
    path = tmp_path / "clip.gif"
    with VideoWriter(path, fps=10) as video:
        for f in _frames(4, 40, 60):
            video.write(f)
    info = video_info(path)
    assert info.codec == "gif" and info.frames == 4 and (info.width, info.height) == (60, 40)


def test_bad_frames_and_rates_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="fps"):
        VideoWriter(tmp_path / "a.mp4", fps=0)
    with VideoWriter(tmp_path / "b.mp4", fps=25) as video:
        video.write(np.zeros((20, 30, 3), np.uint8))
        with pytest.raises(ValueError, match="size"):
            video.write(np.zeros((22, 30, 3), np.uint8))
    with pytest.raises(ValueError, match="closed"):
        video.write(np.zeros((20, 30, 3), np.uint8))
    VideoWriter(tmp_path / "none.mp4", fps=30).close()
    assert not (tmp_path / "none.mp4").exists()


def test_even_frame_pads_with_the_edge() -> None:
    f = np.arange(3 * 5 * 3, dtype=np.uint8).reshape(3, 5, 3)
    e = even_frame(f)
    assert e.shape == (4, 6, 3)
    assert np.array_equal(e[:3, :5], f) and np.array_equal(e[3, :5], f[2]) and np.array_equal(e[:3, 5], f[:, 4])
    g = np.zeros((4, 6, 3), np.uint8)
    assert even_frame(g) is g


def test_gif_frames_stay_bounded_and_evenly_spaced() -> None:
    from protocol.formats.video import GifFrames

    g = GifFrames(max_frames=4)
    for k in range(21):
        g.add(np.full((2, 2, 3), k, np.uint8))
        assert len(g.frames) < 4
    assert [int(f[0, 0, 0]) for f in g.frames] == [0, 8, 16] and g.step == 8
    assert g.duration_s(10.0) == pytest.approx(0.8)  # each kept frame stands for 8 offered at 10 Hz
