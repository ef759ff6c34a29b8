"""The live cloth client compiles its solver before the first pose (``cloth_client.app.live.warm_up``)."""

from __future__ import annotations

import threading

import pytest

import cloth_client.app.live as live
from cloth_client.app.live import LiveOptions, run_live, warm_up


def test_the_warm_up_runs_the_solver_and_stops_when_asked() -> None:
    assert warm_up(LiveOptions(tracker_id="t", particles=400)) > 0.0
    calls: list[int] = []

    def stop() -> bool:
        calls.append(1)
        return True

    warm_up(LiveOptions(tracker_id="t", particles=400), stop)
    assert calls == [1]  # asked before the first step, and no step taken after


def test_a_stop_during_the_warm_up_opens_no_session(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_session(*a: object, **kw: object) -> None:
        raise AssertionError("the session opened after a stop during the warm-up")

    monkeypatch.setattr(live, "open_session", no_session)
    stop = threading.Event()
    stop.set()
    result = run_live(None, LiveOptions(tracker_id="t", particles=400), stop)  # type: ignore[arg-type]
    assert result.reason == "signal" and result.frames == 0
