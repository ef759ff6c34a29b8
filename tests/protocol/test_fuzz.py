"""The fuzzer an integrator points at their own client (``python -m protocol fuzz``): its malformed
cases are refused by the codec, its valid-but-absurd cases decode and are refused by the clients'
meaning checks, and the command publishes them on loopback."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import numpy as np
import pytest

from protocol.__main__ import fuzz_template
from protocol.__main__ import main as protocol_main
from protocol.net.session import build_config, free_tcp_endpoint, open_session, undeclare_quietly
from protocol.wire.codec import ProtocolError, decode
from protocol.wire.fuzz import MALFORMED, cases_for, hostile_payload, hostile_stream
from protocol.wire.messages import BodyInfo, PoseFrame
from protocol.wire.validate import StreamClock, check_body_info, check_pose_frame

POSE_KEY = "mocap/tracker/fz/pose"
BODY_KEY = "mocap/tracker/fz/body"


@pytest.mark.parametrize("key", [POSE_KEY, BODY_KEY])
def test_malformed_cases_are_refused_by_the_codec(key: str) -> None:
    template = fuzz_template(key)
    rng = np.random.default_rng(0)
    for case in MALFORMED:
        for _ in range(5):
            with pytest.raises(ProtocolError):
                decode(hostile_payload(case, template, rng), type(template))


def test_meaning_cases_decode_and_the_clients_checks_refuse_them() -> None:
    rng = np.random.default_rng(1)
    body = fuzz_template(BODY_KEY)
    assert check_body_info(body) is None
    for case in ("giant_body", "tiny_body"):
        msg = decode(hostile_payload(case, body, rng), BodyInfo)
        assert check_body_info(msg) is not None, case
    pose = fuzz_template(POSE_KEY)
    assert check_pose_frame(pose) is None
    for case in ("huge_rotation", "far_joints"):
        msg = decode(hostile_payload(case, pose, rng), PoseFrame)
        assert check_pose_frame(msg) is not None, case
    clock = StreamClock()
    now = 100.0
    for seq in range(1, 31):  # a steady stream at 30 Hz
        assert clock.observe(seq, seq / 30, now + seq / 30).ok
    for case in ("far_future", "max_seq", "seq_backwards"):
        msg = decode(hostile_payload(case, pose, rng, last_seq=30, clock=1.0), PoseFrame)
        assert not clock.observe(msg.seq, msg.capture_ts, now + 1.01).ok, case


def test_same_seed_same_payloads() -> None:
    template = fuzz_template(POSE_KEY)
    a = hostile_stream(template, np.random.default_rng(5))
    b = hostile_stream(template, np.random.default_rng(5))
    assert [next(a) for _ in range(40)] == [next(b) for _ in range(40)]
    assert set(cases_for(template)) >= {"spoof_next_seq", "max_seq", "random_bytes"}
    assert "giant_body" not in cases_for(template)


def test_fuzz_command_publishes_on_loopback(capsys: pytest.CaptureFixture[str]) -> None:
    endpoint = free_tcp_endpoint()
    got: list[bytes] = []
    done = threading.Event()
    rc: list[int] = []

    def fuzz() -> None:
        rc.append(protocol_main(["fuzz", "--key", POSE_KEY, "--duration", "1.5", "--rate", "200", "-q",
                                 "--listen", endpoint, "--seed", "3"]))
        done.set()

    t = threading.Thread(target=fuzz)
    t.start()
    time.sleep(0.3)
    with open_session(build_config(mode="peer", connect=[endpoint], listen=[])) as session:
        sub: Any = session.declare_subscriber(POSE_KEY)
        try:
            while not done.is_set():
                while (s := sub.try_recv()) is not None:
                    got.append(s.payload.to_bytes())
                time.sleep(0.005)
        finally:
            undeclare_quietly(sub)
    t.join(10)
    assert rc == [0]
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["key"] == POSE_KEY and out["sent"] >= 200
    assert len(got) > 20
    assert set(out["cases"]) <= set(cases_for(fuzz_template(POSE_KEY)))


def test_fuzz_refuses_a_case_that_does_not_fit_the_key(capsys: pytest.CaptureFixture[str]) -> None:
    assert protocol_main(["fuzz", "--key", POSE_KEY, "--cases", "giant_body", "--duration", "0.1"]) == 1
    assert "unknown case" in capsys.readouterr().err
    assert protocol_main(["fuzz", "--key", "mocap/tracker/fz/status", "--duration", "0.1"]) == 1
