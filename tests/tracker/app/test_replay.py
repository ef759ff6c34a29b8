"""Replay core (frame mapping, seq/time continuity, FK joints) and the ``mocap-tracker`` CLI surface."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from protocol.kinematics import fk
from protocol.motion import Motion
from protocol.net.session import free_tcp_endpoint
from protocol.skeleton import JOINT_INDEX, N_PARTS, POSE_SIZE, ROT_JOINTS, body_from_measurements, standing_pose
from protocol.wire.codec import decode, encode
from protocol.wire.messages import BodyInfo, PoseFrame, body_info_from_body
from tracker_service.app.cli import build_parser, main
from tracker_service.app.replay import (
    ESTIMATOR,
    ReplayStream,
    frames_per_pass,
    replay_body_info,
    source_indices,
    synthetic_wave_motion,
)


def _arm_motion(n: int = 10, fps: float = 30.0, name: str = "arm") -> Motion:
    """Standing pose with a sinusoid on the left shoulder; every frame is distinct."""
    body = body_from_measurements(1.82, name="tall")
    poses = np.tile(standing_pose(body), (n, 1))
    k = ROT_JOINTS.index("l_shoulder")
    poses[:, 3 + 3 * k + 2] = np.radians(-80.0) + 0.8 * np.sin(np.arange(n) / 3.0)
    poses[:, 0] = np.arange(n) * 0.01  # walk sideways so each frame's root differs too
    return Motion(poses=poses, fps=fps, name=name, body=body)


# ---------------------------------------------------------------------------------- frame mapping


@pytest.mark.parametrize(("n", "fps", "rate", "expected"), [
    (100, 30, 30, 100), (100, 30, 60, 200), (100, 30, 10, 34), (100, 30, 15, 50), (1, 30, 30, 1),
    (51, 30, 29.97, 51), (7, 120, 30, 2),
])
def test_frames_per_pass(n: int, fps: float, rate: float, expected: int) -> None:
    assert frames_per_pass(n, fps, rate) == expected


def test_frames_per_pass_rejects_bad_input() -> None:
    with pytest.raises(ValueError):
        frames_per_pass(0, 30, 30)
    with pytest.raises(ValueError, match="rate"):
        frames_per_pass(10, 30, 0)
    with pytest.raises(ValueError, match="rate"):
        frames_per_pass(10, 30, float("nan"))


def test_source_indices_identity_double_half() -> None:
    k = np.arange(12)
    np.testing.assert_array_equal(source_indices(k, 12, 30, 30), k)
    np.testing.assert_array_equal(source_indices(k, 12, 30, 60), k // 2)
    np.testing.assert_array_equal(source_indices(k[:6], 12, 30, 15), 2 * k[:6])
    # 29.97 Hz output of a 30 fps motion: never skips more than one frame, never goes backwards
    idx = source_indices(np.arange(300), 1000, 30, 29.97, loop=False)
    assert np.all(np.diff(idx) >= 0) and np.all(np.diff(idx) <= 2)


def test_source_indices_loop_and_clamp() -> None:
    k = np.arange(25)
    np.testing.assert_array_equal(source_indices(k, 10, 30, 30, loop=True), k % 10)
    np.testing.assert_array_equal(source_indices(k, 10, 30, 30, loop=False), np.minimum(k, 9))
    assert int(source_indices(3, 10, 30, 30)) == 3
    with pytest.raises(ValueError, match=">= 0"):
        source_indices(-1, 10, 30, 30)


# ---------------------------------------------------------------------------------- ReplayStream


def test_frames_carry_seq_time_pose_and_fk_joints() -> None:
    m = _arm_motion(10)
    s = ReplayStream(m, "rp1")
    frames = list(s.frames())
    assert [f.seq for f in frames] == list(range(10))
    np.testing.assert_allclose([f.capture_ts for f in frames], np.arange(10) / 30.0)
    expected_joints = fk(m.poses, m.body)
    for k, f in enumerate(frames):
        assert f.tracker_id == "rp1" and f.estimator == ESTIMATOR == "replay"
        assert f.body_model == "tall" and f.confidence == 1.0 and f.publish_ts == 0.0
        assert f.pose.dtype == np.float32 and f.pose.shape == (POSE_SIZE,)
        np.testing.assert_array_equal(f.pose, m.poses[k].astype(np.float32))
        assert f.joints.dtype == np.float32
        np.testing.assert_allclose(f.joints, expected_joints[k], atol=1e-6)
        np.testing.assert_array_equal(f.visibility, np.ones(N_PARTS, np.float32))


def test_loop_keeps_seq_and_time_continuous() -> None:
    m = _arm_motion(10)
    s = ReplayStream(m, "rp1", loop=True)
    assert s.n_frames is None
    frames = list(s.frames(max_frames=35))
    assert [f.seq for f in frames] == list(range(35))
    ts = np.array([f.capture_ts for f in frames])
    np.testing.assert_allclose(np.diff(ts), 1 / 30.0)  # no jump back at the wrap
    np.testing.assert_allclose(ts[10], m.duration)  # frame time + one motion duration per loop
    np.testing.assert_array_equal(frames[23].pose, frames[3].pose)
    assert (s.loop_count(9), s.loop_count(10), s.loop_count(34)) == (0, 1, 3)


def test_rate_mapping_repeats_or_skips_frames() -> None:
    m = _arm_motion(10)
    fast = ReplayStream(m, "x", rate=60.0)
    assert fast.n_frames == 20
    f = list(fast.frames())
    np.testing.assert_array_equal(f[7].pose, m.poses[3].astype(np.float32))
    np.testing.assert_allclose(f[7].capture_ts, 7 / 60.0)
    slow = ReplayStream(m, "x", rate=10.0)
    assert slow.n_frames == 4
    assert [slow.source_index(k) for k in range(4)] == [0, 3, 6, 9]


def test_frame_bounds_and_publish_ts() -> None:
    s = ReplayStream(_arm_motion(5), "x")
    assert s.frame(4, publish_ts=123.5).publish_ts == 123.5
    with pytest.raises(IndexError):
        s.frame(5)
    with pytest.raises(IndexError):
        s.frame(-1)
    assert len(list(s.frames(max_frames=3))) == 3


def test_body_info_and_codec_round_trip() -> None:
    m = _arm_motion(4)
    s = ReplayStream(m, "rp2")
    info = s.body_info()
    assert info == replay_body_info(m, "rp2") == body_info_from_body(m.body, "rp2")
    assert decode(encode(info), BodyInfo) == info
    f = s.frame(2, publish_ts=1.7e9)
    assert decode(encode(f), PoseFrame) == f


def test_synthetic_wave_raises_and_waves_the_right_hand() -> None:
    m = synthetic_wave_motion(seconds=2.0, fps=30.0)
    assert m.poses.shape == (60, POSE_SIZE) and m.name == "synthetic-wave"
    j = fk(m.poses, m.body)
    head, rhand, lhand = JOINT_INDEX["head_top"], JOINT_INDEX["r_hand_tip"], JOINT_INDEX["l_hand_tip"]
    assert j[0, rhand, 1] < 1.0  # starts with the arm down
    assert np.all(j[20:, rhand, 1] > j[20:, head, 1])  # then above the head
    assert np.ptp(j[20:, rhand, 0]) > 0.2  # swinging side to side
    np.testing.assert_allclose(j[:, lhand], np.broadcast_to(j[0, lhand], (60, 3)))  # left arm still
    with pytest.raises(ValueError):
        synthetic_wave_motion(seconds=0)


# ----------------------------------------------------------------------------------------- CLI


def test_help_mentions_every_option(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["replay", "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert "self-test" in text and "127.0.0.1:7447" in text
    for opt in ("--bvh", "--script", "--synthetic-wave", "--rate", "--loop", "--duration", "--frames",
                "--id", "--mode", "--connect", "--listen", "--config"):
        assert opt in text


def test_top_level_help_lists_commands() -> None:
    text = build_parser().format_help()
    assert "replay" in text and "demo" in text


@pytest.mark.parametrize("argv", [
    [],
    ["replay"],
    ["replay", "--bvh", "a.bvh", "--script", "b.toml"],
    ["replay", "--synthetic-wave", "--rate", "-5"],
    ["replay", "--synthetic-wave", "--rate", "fast"],
    ["replay", "--synthetic-wave", "--frames", "0"],
    ["replay", "--synthetic-wave", "--duration", "nan"],
    ["replay", "--synthetic-wave", "--id", "a/b"],
    ["replay", "--synthetic-wave", "--wait-for-subscriber", "-1"],
    ["nonsense"],
])
def test_bad_arguments_exit_2_with_one_line(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err and "error:" in err[-1] and "Traceback" not in "\n".join(err)


@pytest.mark.parametrize(("argv", "needle"), [
    (["replay", "--bvh", "/nonexistent/walk.bvh"], "motion file not found"),
    (["replay", "--script", "/nonexistent/wave.toml"], "motion file not found"),
    (["replay", "--synthetic-wave", "--config", "/nonexistent/z.json5"], "zenoh config file not found"),
    (["replay", "--synthetic-wave", "--listen", "nonsense"], "invalid zenoh setting listen/endpoints"),
])
def test_runtime_errors_exit_1_with_one_line(argv: list[str], needle: str,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0] and err[0].startswith("mocap-tracker replay:")


def test_unreadable_bvh_exits_1(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "broken.bvh"
    bad.write_text("this is not a BVH file\n")
    assert main(["replay", "--bvh", str(bad), "--listen", free_tcp_endpoint()]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("mocap-tracker replay:")


def test_replay_in_process_runs_and_returns_0() -> None:
    argv = ["replay", "--synthetic-wave", "--frames", "5", "--rate", "200", "--listen", free_tcp_endpoint(),
            "--id", "inproc", "-q"]
    assert main(argv) == 0
