"""The live cloth client's message handling against hostile or odd input, in-process (no Zenoh).

``ClothClient`` is fed encoded payloads directly with a synthetic local clock. Most tests use a
stand-in driver that records what reaches the solver (fast, no JIT); the last one runs the real
solver. Cases measured on loopback before the fix: one ``PoseFrame`` with capture_ts = 1e12
stopped the simulation for good; a ``BodyInfo`` at 1/1000 scale pegged a core; one at 100x kept a
170 m giant; one huge rotation gave strain 5.66; after a tracker restart the client resumed only
after 27-33 s; body warnings were not rate-limited.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

import cloth_client.app.live as live
from cloth_client.app.live import MAX_SUBSTEPS_PER_FRAME, ClothClient, LiveOptions, substep_bound
from cloth_client.solver.driver import DriverConfig, FrameStats
from protocol.kinematics import fk
from protocol.skeleton import default_body, standing_pose
from protocol.wire.codec import encode
from protocol.wire.messages import BodyInfo, PoseFrame, body_info_from_body

BODY = default_body()
INFO = body_info_from_body(BODY, "t")
FPS = 30.0


class FakeDriver:
    """Records every (pose, t) the solver would get."""

    def __init__(self, info: BodyInfo, stable_dt: float = 1 / 200) -> None:
        self.info = info
        self.config = DriverConfig()
        self.model = SimpleNamespace(stable_dt=stable_dt, params=SimpleNamespace(max_substep_dt=1 / 240,
                                                                                 max_substeps=48))
        self.garment = SimpleNamespace(n_particles=4, kind="cape")
        self.state = SimpleNamespace(x=np.zeros((4, 3)))
        self.fed: list[tuple[np.ndarray, float]] = []

    def feed(self, pose: np.ndarray, t: float) -> FrameStats | None:
        if self.fed and not t > self.fed[-1][1]:
            return None
        self.fed.append((pose, t))
        return FrameStats(t, 8, 0.0, 0.0, 0, 0.01, False)


def _client(**kw: Any) -> tuple[ClothClient, list[FakeDriver]]:
    made: list[FakeDriver] = []

    def factory(info: BodyInfo, opts: LiveOptions) -> Any:
        d = FakeDriver(info, **kw)
        made.append(d)
        return d

    return ClothClient(LiveOptions(tracker_id="t"), driver_factory=factory), made


def _scaled(s: float) -> BodyInfo:
    return dataclasses.replace(INFO, offsets=INFO.offsets * s, capsule_radii=INFO.capsule_radii * s,
                               measurements={**INFO.measurements, "height_m": BODY.height * s})


def _frame(seq: int, ts: float, pose: np.ndarray | None = None) -> PoseFrame:
    p = standing_pose(BODY) if pose is None else pose
    p = p.copy()
    p[0] = 0.3 * np.sin(ts)  # a slow sway
    return PoseFrame("t", seq, ts, 0.0, 0.0, p, fk(p, BODY), np.ones(15), 1.0, "replay", BODY.name)


def _stream(client: ClothClient, n: int, seq0: int = 0, t0: float = 0.0, now0: float = 0.0) -> float:
    now = now0
    for k in range(n):
        now = now0 + k / FPS
        client.on_poses([encode(_frame(seq0 + k, t0 + k / FPS))], now)
    return now


def _solver_times(d: FakeDriver) -> np.ndarray:
    return np.array([t for _, t in d.fed])


def test_far_future_stamp_does_not_stop_the_simulation() -> None:
    client, made = _client()
    assert client.on_body(encode(INFO))
    now = _stream(client, 60)
    client.on_poses([encode(_frame(60, 1e12))], now + 0.01)
    _stream(client, 60, seq0=61, t0=61 / FPS, now0=now + 1 / FPS)
    d, = made
    assert len(d.fed) == 120  # every real frame simulated, the bogus one never
    assert np.all(np.diff(_solver_times(d)) > 0) and _solver_times(d).max() < 10
    assert client.result.counters["invalid_ts_future"] == 1


def test_tiny_and_giant_bodies_are_refused_and_the_body_kept() -> None:
    client, made = _client()
    assert client.on_body(encode(INFO))
    t0 = time.monotonic()
    assert not client.on_body(encode(_scaled(1e-3)))
    assert not client.on_body(encode(_scaled(100.0)))
    assert time.monotonic() - t0 < 1.0
    assert len(made) == 1 and client.info == INFO
    assert client.result.counters["invalid_body_stature"] == 2
    _stream(client, 30)
    assert len(made[0].fed) == 30


def test_huge_rotation_never_reaches_the_solver() -> None:
    client, made = _client()
    client.on_body(encode(INFO))
    now = _stream(client, 30)
    p = standing_pose(BODY)
    p[3:6] = (0.0, 1e4, 0.0)
    bad = dataclasses.replace(_frame(30, 30 / FPS), pose=p)
    client.on_poses([encode(bad)], now + 0.01)
    d = made[0]
    assert len(d.fed) == 30
    assert all(np.linalg.norm(pose[3:].reshape(-1, 3), axis=1).max() < 7 for pose, _ in d.fed)
    assert client.result.counters["invalid_pose_rotation"] == 1


def test_tracker_restart_followed_within_two_seconds() -> None:
    client, made = _client()
    client.on_body(encode(INFO))
    client.want_body = False  # the app's query at the start answered
    now = _stream(client, 900)  # 30 s, then the tracker restarts: seq and time from 0 again
    assert not client.want_body
    d = made[0]
    n_before = len(d.fed)
    restart_at = now + 0.5
    resumed = None
    for k in range(120):
        client.on_poses([encode(_frame(k, k / FPS))], restart_at + k / FPS)
        if resumed is None and len(d.fed) > n_before:
            resumed = k / FPS
    assert resumed is not None and resumed <= 2.0
    assert client.result.counters["tracker_restarts"] == 1
    assert client.want_body  # the app asks for the new stream's body
    times = _solver_times(d)
    assert np.all(np.diff(times) > 0)
    assert np.diff(times).max() <= 1.01 * d.config.continuity.max_gap_s + 1e-3 + 1e-9


def test_solver_steps_are_bounded_even_across_a_long_pause() -> None:
    client, made = _client()
    client.on_body(encode(INFO))
    now = _stream(client, 30)
    _stream(client, 30, seq0=30, t0=30 / FPS + 20.0, now0=now + 20.0)  # the tracker paused for 20 s
    d = made[0]
    steps = np.diff(_solver_times(d))
    assert len(d.fed) == 60 and steps.max() <= 0.52
    assert substep_bound(d) <= MAX_SUBSTEPS_PER_FRAME  # type: ignore[arg-type]


def test_garment_needing_too_many_substeps_or_failing_is_refused() -> None:
    client, _ = _client(stable_dt=1e-6)
    assert not client.on_body(encode(INFO))
    assert client.driver is None and client.result.counters["invalid_garment_substeps"] == 1

    def broken(info: BodyInfo, opts: LiveOptions) -> Any:
        raise ValueError("cannot convert float NaN to integer")

    client2 = ClothClient(LiveOptions(tracker_id="t"), driver_factory=broken)
    assert not client2.on_body(encode(INFO))
    assert client2.result.counters["invalid_garment_failed"] == 1


def test_over_budget_steps_switch_the_cloth_off(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(live, "STEP_BUDGET_S", -1.0)  # every step is over budget
    client, _ = _client()
    client.on_body(encode(INFO))
    _stream(client, 10)
    assert client.driver is None
    assert client.result.counters["sim_disabled"] == 1
    assert client.result.counters["sim_over_budget"] == live.OVER_BUDGET_LIMIT
    assert client.on_body(encode(INFO))  # another body message brings it back


def test_body_warnings_are_rate_limited(caplog: pytest.LogCaptureFixture) -> None:
    client, _ = _client()
    client.on_body(encode(INFO))
    t = [0.0]
    client.warn.clock = lambda: t[0]
    with caplog.at_level(logging.WARNING, logger="cloth_client.app.live"):
        for k in range(1845):
            t[0] = k * 60.0 / 1845
            client.on_body(encode(_scaled(100.0 if k % 2 else 1e-3)))
    assert len(caplog.records) <= 60 / 5 + 2
    assert client.result.counters["invalid_body_stature"] == 1845


@pytest.mark.slow
def test_real_solver_survives_the_hostile_messages() -> None:
    """The real solver (400-particle cape): a far-future stamp, a huge rotation, a 100x body and a
    restart in one stream; the cloth keeps simulating with a sane strain, each step bounded."""
    client = ClothClient(LiveOptions(tracker_id="t", particles=400))
    assert client.on_body(encode(INFO))
    now = _stream(client, 45)
    p = standing_pose(BODY)
    p[3:6] = (0.0, 1e4, 0.0)
    client.on_poses([encode(dataclasses.replace(_frame(45, 1.5), pose=p)), encode(_frame(46, 1e12))], now + 0.01)
    assert not client.on_body(encode(_scaled(100.0)))
    frames = client.result.frames
    now = _stream(client, 30, seq0=47, t0=47 / FPS, now0=now + 2 / FPS)
    assert client.result.frames >= frames + 29
    t0 = time.monotonic()
    _stream(client, 30, now0=now + 0.5)  # a restart
    assert client.result.counters["tracker_restarts"] == 1
    assert client.result.frames >= frames + 29 + 25
    assert time.monotonic() - t0 < 60
    assert client.result.max_strain < 0.10
    client.close()


def test_every_pose_of_a_batch_is_simulated_unless_it_is_too_far_behind() -> None:
    """Poses that piled up while the client rendered are all simulated, in order; only those more
    than ``MAX_BACKLOG_S`` behind the newest are skipped."""
    client, made = _client()
    assert client.on_body(encode(INFO))
    now = _stream(client, 30)
    d, = made
    fed = len(d.fed)
    assert client.on_poses([encode(_frame(30 + k, (30 + k) / FPS)) for k in range(6)], now + 0.2)
    assert len(d.fed) == fed + 6 and client.result.skipped_behind == 0
    times = _solver_times(d)
    assert (np.diff(times) > 0).all()
    n = int(2 * live.MAX_BACKLOG_S * FPS)  # twice the backlog allowed, at once
    batch = [encode(_frame(36 + k, (36 + k) / FPS)) for k in range(n)]
    assert client.on_poses(batch, now + 0.2 + n / FPS)
    stamps = np.array([(36 + k) / FPS for k in range(n)])
    kept = int(np.sum(stamps[-1] - stamps <= live.MAX_BACKLOG_S))  # the client's own comparison
    assert 0 < kept < n and len(d.fed) == fed + 6 + kept and client.result.skipped_behind == n - kept


def test_a_batch_stops_at_max_frames() -> None:
    """``--max-frames N`` simulates exactly N poses, even when the last look brought a batch."""
    made: list[FakeDriver] = []

    def factory(info: BodyInfo, opts: LiveOptions) -> Any:
        made.append(FakeDriver(info))
        return made[-1]

    client = ClothClient(LiveOptions(tracker_id="t", max_frames=10), driver_factory=factory)
    assert client.on_body(encode(INFO))
    now = _stream(client, 7)
    frames, fed = client.result.frames, len(made[0].fed)
    assert frames <= 7
    assert client.on_poses([encode(_frame(7 + k, (7 + k) / FPS)) for k in range(6)], now + 0.2)
    assert client.result.frames == 10 and len(made[0].fed) == fed + 10 - frames  # the batch's first 3 only
    assert not client.on_poses([encode(_frame(13, 13 / FPS))], now + 0.3)  # nothing beyond the limit
    assert client.result.frames == 10


def test_poses_before_the_body_are_simulated_when_it_comes() -> None:
    """The first poses often beat the ``BodyInfo`` reply: they wait (within ``MAX_BACKLOG_S``) and are
    simulated, in order, with the first poses after it."""
    client, made = _client()
    assert not client.on_poses([encode(_frame(k, k / FPS)) for k in range(3)], 0.1)
    assert not made and len(client.waiting) == 3
    assert client.on_body(encode(INFO))
    assert client.on_poses([encode(_frame(3, 3 / FPS))], 0.2)
    d, = made
    assert len(d.fed) == 4 and client.result.frames == 4 and not client.waiting
    assert (np.diff(_solver_times(d)) > 0).all()
    # a long wait keeps only the last MAX_BACKLOG_S of them
    late, _ = _client()
    n = int(3 * live.MAX_BACKLOG_S * FPS)
    for k in range(n):
        late.on_poses([encode(_frame(k, k / FPS))], k / FPS)
    assert len(late.waiting) <= int(live.MAX_BACKLOG_S * FPS) + 1 and late.result.skipped_behind > 0
