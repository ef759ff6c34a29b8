"""``mocap-tracker record``: the pure conversions (frames -> arrays -> BVH / JSON lines / CSV) and the
whole command against PoseFrames and a BodyInfo published here on loopback Zenoh; the BVH read back
with :func:`protocol.formats.bvh.read_bvh` and its forward kinematics gives the published joints."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh

from protocol.formats.bvh import read_bvh
from protocol.formats.load import load_motion
from protocol.kinematics import fk
from protocol.net.session import build_config, free_tcp_endpoint, undeclare_quietly
from protocol.skeleton import JOINT_NAMES, N_PARTS, POSE_SIZE, Body, body_from_measurements, standing_pose
from protocol.wire.codec import encode
from protocol.wire.keys import body_key, pose_key
from protocol.wire.messages import PoseFrame, body_from_body_info, body_info_from_body
from tracker_service.app import cli
from tracker_service.app.options import RecordOptions
from tracker_service.app.record import (
    CONVENTIONAL_NAMES,
    Recording,
    csv_header,
    frames_to_arrays,
    read_recording_bvh,
    save_recording,
    write_recording_bvh,
)
from tracker_service.app.replay_daemon import wait_for_subscriber

REPO = Path(__file__).resolve().parents[3]
TOL_M = 1e-4


def _body() -> Body:
    """A tracked body unlike the default one, as a client rebuilds it from the wire (float32 offsets)."""
    return body_from_body_info(body_info_from_body(body_from_measurements(1.83, arm_ratio=1.05, name="tall"), "rec"))


def _poses(n: int, body: Body, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    p = np.repeat(standing_pose(body)[None], n, axis=0)
    p[:, 0] += np.linspace(0.0, 0.4, n)  # walking sideways
    p[:, 3:] += rng.normal(0.0, 0.35, (n, POSE_SIZE - 3))  # every joint turned, root included
    return p.astype(np.float32).astype(np.float64)  # what a PoseFrame carries


def _frames(poses: np.ndarray, body: Body, tid: str = "rec") -> list[PoseFrame]:
    joints = fk(poses, body)
    return [PoseFrame(tracker_id=tid, seq=k, capture_ts=10.0 + k / 30.0, publish_ts=time.time(),
                      capture_wall_ts=1_700_000_000.0,
                      pose=poses[k].astype(np.float32), joints=joints[k].astype(np.float32),
                      visibility=np.ones(N_PARTS, np.float32), confidence=0.5 + 0.01 * k, estimator="tree",
                      body_model=body.name) for k in range(len(poses))]


# ------------------------------------------------------------------------------- conversions


def test_frames_to_arrays_sorts_by_seq_and_drops_repeats() -> None:
    body = _body()
    frames = _frames(_poses(5, body), body)
    arrays = frames_to_arrays([frames[3], frames[0], frames[1], frames[0], frames[4], frames[2]])
    assert arrays.seq.tolist() == [0, 1, 2, 3, 4]
    assert arrays.poses.shape == (5, POSE_SIZE) and arrays.joints.shape == (5, len(JOINT_NAMES), 3)
    assert arrays.fps() == pytest.approx(30.0)
    assert np.array_equal(arrays.joints[2], frames[2].joints)


@pytest.mark.parametrize("names", ["conventional", "native"])
def test_bvh_on_the_tracked_body_gives_the_published_joints(tmp_path: Path, names: str) -> None:
    body = _body()
    poses = _poses(12, body)
    path = tmp_path / "take.bvh"
    write_recording_bvh(path, poses, body, 30.0, names)  # type: ignore[arg-type]
    bvh = read_bvh(path)
    expected = [n for n in JOINT_NAMES if n not in ("head_top", "l_hand_tip", "r_hand_tip", "l_toe", "r_toe")]
    if names == "conventional":
        expected = [CONVENTIONAL_NAMES[n] for n in expected]
    assert bvh.names == expected and bvh.n_frames == 12 and bvh.fps == pytest.approx(30.0)
    # the hierarchy's bones are the tracked body's
    by_name = {j.name: j for j in bvh.joints}
    knee = by_name["LeftLeg" if names == "conventional" else "l_knee"]
    knee_m = body.bone_lengths[JOINT_NAMES.index("l_knee")]
    assert np.linalg.norm(knee.offset) / 100.0 == pytest.approx(knee_m, abs=1e-6)
    err = np.abs(read_recording_bvh(path) - fk(poses, body)).max()
    assert err < TOL_M
    if names == "native":  # the project's own reader takes it back exactly (no retargeting)
        m = load_motion(path)
        assert np.abs(fk(m.poses, m.body) - fk(poses, body)).max() < TOL_M


def test_save_recording_writes_jsonl_and_csv(tmp_path: Path) -> None:
    body = _body()
    frames = _frames(_poses(6, body), body)
    del frames[3]  # a dropped frame
    rec = Recording(frames=frames, bodies=[body_info_from_body(body, "rec")])
    opts = RecordOptions(bvh=str(tmp_path / "a" / "t.bvh"), jsonl=str(tmp_path / "t.jsonl"),
                         csv=str(tmp_path / "t.csv"), tracker_id="rec")
    s = save_recording(rec, opts)
    assert (s.frames, s.missing, s.body) == (5, 1, "tall") and len(s.files) == 3
    lines = [json.loads(x) for x in Path(opts.jsonl or "").read_text().splitlines()]
    assert [x["seq"] for x in lines] == [0, 1, 2, 4, 5]
    assert set(lines[0]) == {"seq", "capture_ts", "joints", "confidence"}
    assert np.abs(np.array(lines[4]["joints"]) - frames[4].joints).max() < 1e-6
    assert lines[1]["capture_ts"] == pytest.approx(10.0 + 1 / 30) and lines[1]["confidence"] == pytest.approx(0.51)
    with open(opts.csv or "", newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == csv_header() and rows[0][:5] == ["seq", "t", "pelvis_x", "pelvis_y", "pelvis_z"]
    assert len(rows) == 6 and len(rows[1]) == 2 + 3 * len(JOINT_NAMES)
    assert rows[4][0] == "4" and float(rows[4][1]) == pytest.approx(4 / 30, abs=1e-6)
    assert np.abs(np.array(rows[4][2:], float).reshape(-1, 3) - frames[3].joints).max() < 1e-6
    with pytest.raises(RuntimeError, match="no pose"):
        save_recording(Recording(), opts)


def test_record_arguments() -> None:
    parser = cli.build_parser()
    args = parser.parse_args(["record", "--bvh", "o.bvh", "--csv", "o.csv", "--duration", "2", "--id", "cam1",
                              "--connect", "tcp/127.0.0.1:7999"])
    from tracker_service.app.commands import record

    o = record.options_from_args(args)
    assert o == RecordOptions(bvh="o.bvh", csv="o.csv", duration=2.0, tracker_id="cam1",
                              zenoh=o.zenoh) and o.zenoh.connect == ("tcp/127.0.0.1:7999",)
    assert o.zenoh.role == "subscriber" and o.bvh_names == "conventional"
    with pytest.raises(SystemExit):
        cli.main(["record", "--duration", "1"])  # no output file


# ------------------------------------------------------------------------ over loopback Zenoh


@pytest.mark.zenoh
def test_record_command_over_loopback(tmp_path: Path) -> None:
    body = _body()
    poses = _poses(20, body)
    frames = _frames(poses, body)
    info = encode(body_info_from_body(body, "rec"))
    ep = free_tcp_endpoint()
    out = {k: tmp_path / f"take.{k}" for k in ("bvh", "jsonl", "csv")}
    cmd = [sys.executable, "-m", "tracker_service", "record", "--id", "rec", "--duration", "4", "--connect", ep,
           "--listen", "tcp/127.0.0.1:0", *(x for k, p in out.items() for x in (f"--{k}", str(p)))]
    with zenoh.open(build_config(mode="peer", listen=[ep])) as session:
        pose_pub = session.declare_publisher(pose_key("rec"))
        body_pub = session.declare_publisher(body_key("rec"))
        queryable = session.declare_queryable(body_key("rec"), lambda q: q.reply(body_key("rec"), info))
        proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            assert wait_for_subscriber(pose_pub, 30.0, threading.Event()), "the recorder did not subscribe"
            body_pub.put(info)
            for f in frames:
                pose_pub.put(encode(f))
                time.sleep(0.01)
            stdout, stderr = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
            undeclare_quietly(queryable, body_pub, pose_pub)
    assert proc.returncode == 0, stderr
    assert "recorded 20 poses" in stdout, stdout + stderr
    assert "OpenGL_accelerate" not in stderr
    joints = read_recording_bvh(out["bvh"])  # read_bvh + its forward kinematics (+ end sites)
    published = np.array([f.joints for f in frames], np.float64)
    assert joints.shape == published.shape
    err = float(np.abs(joints - published).max())
    assert err < TOL_M, f"BVH joints differ from the published ones by {err:.2e} m"
    bvh = read_bvh(out["bvh"])
    hips = bvh.joints[0]
    assert hips.name == "Hips" and bvh.fps == pytest.approx(30.0)
    assert len(out["jsonl"].read_text().splitlines()) == 20
    assert len(out["csv"].read_text().splitlines()) == 21
