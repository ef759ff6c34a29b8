"""Semantic message checks (protocol.wire.validate): body scale, pose ranges, the stream clock,
rate-limited logging and counter clamping. All pure and in-process."""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
import pytest

from protocol.kinematics import fk
from protocol.skeleton import POSE_SIZE, default_body, standing_pose
from protocol.wire.messages import BodyInfo, PoseFrame, body_info_from_body
from protocol.wire.validate import (
    COUNT_MAX,
    RateLimitedLog,
    StreamClock,
    check_body_info,
    check_pose_frame,
    clamp_count,
    stature_of,
)

BODY = default_body()


def _info(scale: float = 1.0, **kw: object) -> BodyInfo:
    info = body_info_from_body(BODY, "t")
    return dataclasses.replace(info, offsets=info.offsets * scale, capsule_radii=info.capsule_radii * scale,
                               measurements={**info.measurements, "height_m": BODY.height * scale}, **kw)


def _frame(seq: int = 0, ts: float = 0.0, pose: np.ndarray | None = None, joints: np.ndarray | None = None,
           confidence: float = 1.0) -> PoseFrame:
    p = standing_pose(BODY) if pose is None else pose
    return PoseFrame("t", seq, ts, 0.0, 0.0, p, fk(p, BODY) if joints is None else joints, np.ones(15), confidence,
                     "replay", BODY.name)


def test_body_info_plausible_and_scaled() -> None:
    assert check_body_info(_info()) is None
    assert 1.3 < (stature_of(_info().bone_lengths) or 0) < 1.9
    assert check_body_info(_info(1e-3)) == "body_stature"
    assert check_body_info(_info(100.0)) == "body_stature"
    assert check_body_info(_info(1.4)) is None  # 2.4 m: tall, still plausible


def test_body_info_single_bad_bone_radius_and_height() -> None:
    info = _info()
    off = info.offsets.copy()
    off[8] = (2.0, 0.0, 0.0)  # a 2 m upper arm
    assert check_body_info(dataclasses.replace(info, offsets=off)) == "body_bone"
    rad = info.capsule_radii.copy()
    rad[0, 0] = 3.0
    assert check_body_info(dataclasses.replace(info, capsule_radii=rad)) == "body_radius"
    assert check_body_info(dataclasses.replace(info, measurements={"height_m": 170.0})) == "body_height"
    assert check_body_info(dataclasses.replace(info, measurements={"height_m": 0.9})) == "body_height"
    assert check_body_info(dataclasses.replace(info, measurements={"height_m": math.nan})) == "body_height"


def test_checks_never_raise() -> None:
    for junk in (None, 1, "x", object(), {"pose": 1}):
        assert isinstance(check_body_info(junk), str)
        assert isinstance(check_pose_frame(junk), str)


def test_pose_frame_ranges() -> None:
    assert check_pose_frame(_frame()) is None
    p = standing_pose(BODY)
    far = p.copy()
    far[:3] = (0.0, 0.9, 1e4)
    assert check_pose_frame(_frame(pose=far, joints=fk(p, BODY))) == "pose_position"
    spun = p.copy()
    spun[3:6] = (0.0, 1e4, 0.0)
    assert check_pose_frame(_frame(pose=spun, joints=fk(p, BODY))) == "pose_rotation"
    wrapped = p.copy()
    wrapped[9:12] = (0.0, 1.9 * math.pi, 0.0)  # under 2 pi: a rotation that wraps, allowed
    assert check_pose_frame(_frame(pose=wrapped, joints=fk(p, BODY))) is None
    j = fk(p, BODY)
    assert check_pose_frame(_frame(joints=np.full_like(j, 1e30))) == "pose_joints"
    j2 = j.copy()
    j2[9] += (0.0, 10.0, 0.0)  # a hand 10 m from the body
    assert check_pose_frame(_frame(joints=j2)) == "pose_joints"
    assert POSE_SIZE == len(p)


def test_pose_frame_captured_after_publication_is_refused() -> None:
    ok = dataclasses.replace(_frame(), publish_ts=1_700_000_000.5, capture_wall_ts=1_700_000_000.4)
    assert check_pose_frame(ok) is None
    assert check_pose_frame(dataclasses.replace(ok, capture_wall_ts=ok.publish_ts)) is None  # a replay
    assert check_pose_frame(dataclasses.replace(ok, capture_wall_ts=1_700_000_000.6)) == "pose_clock"


def _run(clock: StreamClock, frames: list[tuple[int, float, float]]) -> list[str | None]:
    return [clock.observe(s, t, now).reason for s, t, now in frames]


def test_stream_clock_accepts_a_monotonic_stream() -> None:
    c = StreamClock()
    v = c.observe(0, 0.0, 100.0)
    assert v.ok and v.new_stream and not v.restart
    assert _run(c, [(k, k / 30, 100 + k / 30) for k in range(1, 60)]) == [None] * 59
    assert c.observe(70, 70 / 30, 100 + 70 / 30).ok  # a few dropped frames: a gap, fine
    assert c.observe(71, 100.0, 103.0).reason == "ts_future"
    assert c.observe(71, math.nan, 103.0).reason == "ts_invalid"
    assert c.observe(-1, 3.0, 103.0).reason == "ts_invalid"


def test_stream_clock_rejects_single_bad_frames_without_losing_the_stream() -> None:
    c = StreamClock()
    c.observe(0, 0.0, 0.0)
    t = 0.0
    seq = 0
    reasons = []
    for k in range(1, 200):
        seq, t = seq + 1, t + 1 / 30
        if k % 7 == 0:
            reasons.append(c.observe(seq, 1e12, t).reason)  # far future
        elif k % 7 == 3:
            reasons.append(c.observe(2**63 - 1, t, t).reason)  # seq jump
        elif k % 7 == 5:
            reasons.append(c.observe(seq - 3, t - 0.1, t).reason)  # stale
        else:
            assert c.observe(seq, t, t).ok
    assert set(reasons) == {"ts_future", "seq_jump", "out_of_order"}
    assert c.streams == 1


def test_stream_clock_two_max_seq_frames_do_not_take_over() -> None:
    c = StreamClock()
    for k in range(10):
        assert c.observe(k, k / 30, k / 30).ok
    assert c.observe(2**63 - 1, 0.4, 0.4).reason == "seq_jump"
    assert c.observe(2**63 - 1, 0.43, 0.43).reason == "seq_jump"
    assert c.observe(10, 10 / 30, 0.45).ok


def test_stream_clock_follows_a_restart_quickly() -> None:
    c = StreamClock()
    for k in range(900):  # 30 s of stream
        c.observe(k, k / 30, k / 30)
    now = 900 / 30 + 0.5  # the tracker restarts half a second later: seq and time from 0 again
    accepted_at = None
    for k in range(60):
        v = c.observe(k, k / 30, now + k / 30)
        if v.ok:
            assert v.new_stream and v.restart
            accepted_at = k / 30
            break
    assert accepted_at is not None and accepted_at <= 0.2
    assert c.observe(k + 1, (k + 1) / 30, now + (k + 1) / 30).ok


def test_stream_clock_follows_an_immediate_restart_within_a_second() -> None:
    """A looping replay: seq and time restart with no pause; the old stream is quiet from then on."""
    c = StreamClock()
    for k in range(300):
        c.observe(k, k / 30, k / 30)
    now0 = 300 / 30
    first_ok = next(k for k in range(60) if c.observe(k, k / 30, now0 + k / 30).ok)
    assert first_ok / 30 <= 0.5


def test_stream_clock_short_old_stream_restart() -> None:
    """Old stream only 0.5 s long: the new one's early frames look stale, still followed quickly."""
    c = StreamClock()
    for k in range(15):
        c.observe(k, k / 30, k / 30)
    now0 = 1.0
    first_ok = next(k for k in range(60) if c.observe(k, k / 30, now0 + k / 30).ok)
    assert first_ok / 30 <= 0.5


def test_stream_clock_first_frame_bogus_heals() -> None:
    c = StreamClock()
    assert c.observe(0, 1e12, 0.0).ok
    first_ok = next(k for k in range(1, 60) if c.observe(k, k / 30, k / 30).ok)
    assert first_ok / 30 <= 0.5


def test_rate_limited_log_one_line_per_reason_per_interval(caplog: pytest.LogCaptureFixture) -> None:
    t = [0.0]
    log = RateLimitedLog(logging.getLogger("test.validate"), interval_s=5.0, clock=lambda: t[0])
    with caplog.at_level(logging.WARNING, logger="test.validate"):
        for k in range(1845):
            t[0] = k * 60.0 / 1845
            log("body_stature", "bad body %s", k)
            log("pose_joints", "bad pose %s", k)
    assert len(caplog.records) <= 2 * (60 / 5 + 1)
    assert log.counts == {"body_stature": 1845, "pose_joints": 1845}
    assert "more since last report" in caplog.records[-1].getMessage()


def test_clamp_count() -> None:
    assert clamp_count(2**64) == COUNT_MAX
    assert clamp_count(-5) == 0
    assert clamp_count(7) == 7
    assert clamp_count("x") == 0
