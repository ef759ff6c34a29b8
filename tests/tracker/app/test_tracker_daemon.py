"""End to end: ``mocap-tracker run`` on a short synthetic clip (pyrender scene, fixture database)
publishes over loopback Zenoh; a subscriber here decodes poses with sane 3D joints, the body
queryable answers, and SIGTERM stops it cleanly. Also ``mocap-tracker eval --json``."""

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zenoh

from protocol.net.session import build_config, free_tcp_endpoint
from protocol.skeleton import JOINT_INDEX
from protocol.wire.codec import decode
from protocol.wire.keys import body_key, pose_key, status_key
from protocol.wire.messages import BodyInfo, PoseFrame, TrackerStatus
from tracker_service.pipeline.process import TrackerConfig

REPO = Path(__file__).resolve().parents[3]
SCRIPT = REPO / "protocol" / "scripts" / "crouch.toml"

pytestmark = pytest.mark.zenoh


def test_daemon_publishes_sane_poses(small_db, weak_appearance_net) -> None:  # type: ignore[no-untyped-def]
    path = small_db[4]
    ep = free_tcp_endpoint()
    cmd = [sys.executable, "-m", "tracker_service", "run", "--source", f"synthetic:{SCRIPT}", "--db", str(path),
           "--body", "mMA", "--id", "e2e", "--frames", "70", "--listen", ep, "--wait-for-subscriber", "20", "-q",
           "--appearance", str(weak_appearance_net),
           "--min-confidence", "0"]  # the small database lacks the crouch: every estimate, however poor
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    poses: list[PoseFrame] = []
    statuses: list[TrackerStatus] = []
    body: BodyInfo | None = None
    pushed: BodyInfo | None = None  # put by the tracker when a body subscriber appears late
    bsub: Any = None
    conf = build_config(mode="peer", connect=[ep], listen=[free_tcp_endpoint()])
    try:
        with zenoh.open(conf) as session:
            sub = session.declare_subscriber(pose_key("e2e"))
            ssub = session.declare_subscriber(status_key("e2e"))
            try:
                deadline = time.monotonic() + 60
                while time.monotonic() < deadline and proc.poll() is None:
                    s = sub.try_recv()
                    if s is not None:
                        poses.append(decode(s.payload.to_bytes(), PoseFrame))
                    t = ssub.try_recv()
                    if t is not None:
                        statuses.append(decode(t.payload.to_bytes(), TrackerStatus))
                    if body is None and len(poses) > 2:
                        for reply in session.get(body_key("e2e"), timeout=2.0):
                            if reply.ok is not None:
                                body = decode(reply.ok.payload.to_bytes(), BodyInfo)
                    if bsub is None and len(poses) > 15:
                        bsub = session.declare_subscriber(body_key("e2e"))
                    if bsub is not None and pushed is None and (b := bsub.try_recv()) is not None:
                        pushed = decode(b.payload.to_bytes(), BodyInfo)
                    if s is None and t is None:
                        time.sleep(0.005)
            finally:
                sub.undeclare()
                ssub.undeclare()
                if bsub is not None:
                    bsub.undeclare()
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    err = proc.stderr.read().decode() if proc.stderr else ""
    assert proc.returncode == 0, err
    assert len(poses) >= 40, err  # 70 frames minus the background-learning ones
    seqs = [p.seq for p in poses]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))) and seqs[0] == 0
    for p in poses:
        j = p.joints
        assert np.all(np.isfinite(j))
        assert j[JOINT_INDEX["head_top"], 1] > j[JOINT_INDEX["pelvis"], 1] > 0.2  # upright, above the floor
        # the person stands on the stage in front of the camera (origin, camera at z = 3 m)
        assert abs(j[JOINT_INDEX["pelvis"], 2]) < 1.0 and abs(j[JOINT_INDEX["pelvis"], 0]) < 1.0
        assert 1.0 < j[JOINT_INDEX["head_top"], 1] < 2.2
        assert p.estimator == "tree" and 0 <= p.confidence <= 1
    assert body is not None and body.body_model == "mMA"
    assert pushed is not None and pushed.body_model == "mMA"
    assert statuses and statuses[-1].state.value in ("tracking", "stopped")


def _stderr_lines(proc: subprocess.Popen[bytes]) -> "queue.Queue[str]":
    lines: queue.Queue[str] = queue.Queue()

    def pump() -> None:
        assert proc.stderr is not None
        for raw in proc.stderr:
            lines.put(raw.decode(errors="replace"))

    threading.Thread(target=pump, daemon=True).start()
    return lines


@pytest.mark.parametrize("when", ["start-up", "tracking"])
def test_daemon_stops_on_sigterm(small_db, when: str) -> None:  # type: ignore[no-untyped-def]
    """SIGTERM ends the daemon promptly with exit code 0, during its start-up (database, EGL,
    warm-up: no Zenoh session yet) or once it publishes (the loop checks the stop per frame)."""
    path = small_db[4]
    cmd = [sys.executable, "-m", "tracker_service", "run", "--source", f"synthetic:{SCRIPT}", "--db", str(path),
           "--body", "mMA", "--listen", free_tcp_endpoint(), "--appearance", "off"]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    lines = _stderr_lines(proc)
    try:
        if when == "tracking":  # wait until it has opened its session and announced itself
            deadline = time.monotonic() + 180.0
            while time.monotonic() < deadline:
                try:
                    if "publishing poses" in lines.get(timeout=0.5):
                        break
                except queue.Empty:
                    assert proc.poll() is None, "the daemon exited before publishing"
            else:
                pytest.fail("the daemon did not start publishing")
            time.sleep(0.5)
        else:
            time.sleep(1.0)
        assert proc.poll() is None
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)
        assert time.monotonic() - t0 < 3.0
        assert proc.returncode == 0
        if when == "tracking":  # the clean path: the loop ended and the counters were logged
            time.sleep(0.2)
            rest = []
            while not lines.empty():
                rest.append(lines.get())
            assert any("tracker stopped" in line for line in rest), rest[-5:]
    finally:
        if proc.poll() is None:
            proc.kill()


def test_missing_database_is_a_clear_error(tmp_path: Path) -> None:
    r = subprocess.run([sys.executable, "-m", "tracker_service", "run", "--db", str(tmp_path / "nope"),
                        "--frames", "1"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert "build-db" in r.stderr and "Traceback" not in r.stderr


def test_eval_prints_the_json_contract(small_db, weak_appearance_net) -> None:  # type: ignore[no-untyped-def]
    path = small_db[4]
    r = subprocess.run([sys.executable, "-m", "tracker_service", "eval", "--script", str(SCRIPT), "--db", str(path),
                        "--body", "mMA", "--frames", "40", "--json", "-q", "--appearance", str(weak_appearance_net)],
                       cwd=REPO, capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    for key in ("mpjpe_cm", "root_error_cm", "mpjpe_2d_px", "frames_within_10cm", "accel_error_cm",
                "reacquire_s_max", "fps", "ms_per_frame", "distance_evals_per_level", "templates", "estimator",
                "distance", "body_selected", "frames"):
        assert key in out
    assert out["frames"] == 40 and out["estimator"] == "tree" and out["appearance_cue"] is True
    assert set(out["ms_per_frame"]) == {"preprocess", "estimate", "total"}
    assert out["mpjpe_cm"] is not None and 0 < out["mpjpe_cm"] < 100
    assert out["accel_error_cm"] is not None and 0 <= out["accel_error_cm"] < 20
    assert len(out["distance_evals_per_level"]) == 3
    # steady-state timing starts after the frame that ends initialisation (which may score bodies); the
    # first confirm_frames - 1 of the initialising frames are withheld (confirming), not tracked
    cfg = TrackerConfig()
    assert out["steady_frames"] == out["tracked_frames"] - (cfg.init_frames - (cfg.confirm_frames - 1))
    assert out["withheld"].get("confirming") == cfg.confirm_frames - 1


def test_evaluate_motion_shows_every_frame_to_its_observer(small_db) -> None:  # type: ignore[no-untyped-def]
    from protocol.formats.load import load_motion
    from tracker_service.app.evaluate import EvalOptions, evaluate_motion
    from tracker_service.templates.database import load_db

    loaded = load_db(small_db[4], verify=False)
    seen: list[tuple[float, str, bool]] = []
    out = evaluate_motion(load_motion(SCRIPT, fps=30.0), loaded, TrackerConfig(distance="xor"),
                          EvalOptions(frames=20, seed=3, empty_prefix=6),
                          observe=lambda fr, st, res: seen.append((fr.timestamp, res.phase, res.joints is not None)))
    assert len(seen) == 6 + 20  # the empty prefix and every motion frame, in order
    assert [t for t, _, _ in seen] == sorted(t for t, _, _ in seen)
    assert seen[0][1] == "learning" and seen[-1][1] == "tracking"
    assert sum(j for _, _, j in seen) == out["tracked_frames"] > 0


def test_eval_can_give_the_tracker_the_persons_own_measurements(small_db) -> None:  # type: ignore[no-untyped-def]
    from protocol.formats.load import load_motion
    from protocol.skeleton import JOINT_INDEX
    from tracker_service.app.evaluate import EvalOptions, evaluate_motion, subject_measurements
    from tracker_service.body.measured import given_body
    from tracker_service.scene.subject import random_subject_spec
    from tracker_service.templates.database import load_db

    loaded = load_db(small_db[4], verify=False)
    states = []
    cfg = TrackerConfig(distance="xor", body_candidates=("mMA",))  # replaced by the given body
    out = evaluate_motion(load_motion(SCRIPT, fps=30.0), loaded, cfg,
                          EvalOptions(frames=12, seed=3, empty_prefix=6, subject_measurements=("leg", "group")),
                          observe=lambda fr, st, res: states.append(st))
    spec = random_subject_spec(np.random.default_rng([3, 0]))  # the scene's person for seed 3
    assert out["body_selected"] == "given"
    assert states[-1].body.height == pytest.approx(spec.height)
    assert states[-1].body_scale == pytest.approx(spec.height / loaded.body.height)
    expected = given_body({"height": spec.height, "group": spec.group, "leg": spec.leg_ratio})
    knee = JOINT_INDEX["l_knee"]
    assert states[-1].body.bone_lengths[knee] == pytest.approx(expected.bone_lengths[knee])
    assert subject_measurements(spec)["leg"] == spec.leg_ratio
    with pytest.raises(ValueError, match="unknown measurement"):
        evaluate_motion(load_motion(SCRIPT, fps=30.0), loaded, TrackerConfig(distance="xor"),
                        EvalOptions(frames=2, seed=3, empty_prefix=2, subject_measurements=("inseam",)))


def test_start_up_sigterm_handler_is_kept_only_for_commands_with_a_clean_stop() -> None:
    """``entry``'s start-up handler turns SIGTERM into exit status 0; ``default_sigterm`` (called
    for build-db and eval) puts the default action back, and leaves any other handler alone."""
    from tracker_service.app import entry as _entry

    previous = signal.getsignal(signal.SIGTERM)
    try:
        signal.signal(signal.SIGTERM, _entry._stop_during_import)
        with pytest.raises(SystemExit) as stop:
            _entry._stop_during_import(signal.SIGTERM, None)
        assert stop.value.code == 0
        _entry.default_sigterm()
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL

        def mine(signum: int, frame: object) -> None:
            pass

        signal.signal(signal.SIGTERM, mine)
        _entry.default_sigterm()  # a command's (or a test runner's) own handler stays
        assert signal.getsignal(signal.SIGTERM) is mine
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_per_frame_commands_run_blas_on_one_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    """``mocap-tracker`` pins BLAS to one thread for the per-frame commands (unless the user set it),
    and leaves every core to the batch commands (build-db, train-appearance)."""
    import tracker_service.app.cli as cli
    from tracker_service.app import entry as _entry

    monkeypatch.setattr(cli, "main", lambda argv, **_: 0)
    before = signal.getsignal(signal.SIGTERM)  # main() installs its start-up handler
    try:
        for cmd, want in ((["run"], "1"), (["eval", "--bvh", "x"], "1"), (["build-db"], None),
                          (["train-appearance"], None)):
            for name in _entry._BLAS_THREADS:
                monkeypatch.delenv(name, raising=False)
            assert _entry.main(cmd) == 0
            assert os.environ.get("OPENBLAS_NUM_THREADS") == want, cmd
        monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")  # the user's own setting wins
        assert _entry.main(["run"]) == 0 and os.environ["OPENBLAS_NUM_THREADS"] == "2"
    finally:
        signal.signal(signal.SIGTERM, before)
