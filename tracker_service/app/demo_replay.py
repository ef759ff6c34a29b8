"""``mocap-tracker demo --replay``: a real recording's ground truth replayed in a child process and
received here; every pose printed and the frames checked to arrive in order (a seconds-long check)."""

from __future__ import annotations

import itertools
import json
import queue
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from tracker_service.app.children import child_env, pump, stop_child
from tracker_service.app.options import DemoOptions

if TYPE_CHECKING:
    import zenoh

__all__ = ["DEMO_RECORDINGS", "run_replay_demo"]

PROG = "mocap-tracker"
#: Recordings the demo tries, in order (relative to the shared mocap folder).
DEMO_RECORDINGS = (
    "bandai/dataset-2_raise-up-both-hands_normal_001.bvh",
    "bandai/dataset-1_byebye_normal_001.bvh",
    "bandai/dataset-1_bye_normal_001.bvh",
)


def _pick_recording() -> tuple[list[str], str]:
    """Replay arguments for the demo's source and a one-line description of it."""
    from protocol.formats.load import load_motion
    from protocol.formats.mocap_data import mocap_root

    try:
        root = mocap_root()
    except FileNotFoundError as exc:
        return ["--synthetic-wave"], f"built-in synthetic wave ({exc})"
    candidates = [root / rel for rel in DEMO_RECORDINGS] + sorted(root.glob("bandai/*.bvh"))
    path = next((p for p in candidates if p.is_file()), None)
    if path is None:
        return ["--synthetic-wave"], f"built-in synthetic wave (no BVH file under {root})"
    try:
        motion = load_motion(path)
    except NotImplementedError:
        return ["--synthetic-wave"], "built-in synthetic wave (BVH reading is not implemented yet)"
    except (OSError, ValueError) as exc:
        return ["--synthetic-wave"], f"built-in synthetic wave ({path.name} could not be read: {exc})"
    return ["--bvh", str(path)], f"{path.relative_to(root)} ({motion.n_frames} frames at {motion.fps:g} fps)"


def _child_command(options: DemoOptions, tid: str, endpoint: str) -> tuple[list[str], str]:
    """The child process's command line and a description of what it publishes."""
    if options.replay:
        source, described = _pick_recording()
        return [sys.executable, "-m", "tracker_service", "replay", *source, "--id", tid, "--listen", endpoint,
                "--duration", str(options.duration), "--loop", "--wait-for-subscriber", "10"], described
    from tracker_service.app.resources import DEFAULT_SCRIPT, ensure_db

    loaded = ensure_db(None)  # builds the default template database on first use (cached in out/db)
    described = (f"the tracker on the synthetic scene playing {DEFAULT_SCRIPT.name} "
                 f"(database {loaded.body.name}, {loaded.db.n_leaves} templates)")
    return [sys.executable, "-m", "tracker_service", "run", "--source", f"synthetic:{DEFAULT_SCRIPT}",
            "--db", str(loaded.path), "--id", tid, "--listen", endpoint, "--duration", str(options.duration),
            "--wait-for-subscriber", "10"], described


def _wait_ready(proc: subprocess.Popen[str], lines: queue.Queue[str], timeout: float,
                stop: threading.Event) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not stop.is_set():
        try:
            if "publishing" in lines.get(timeout=0.05):
                return True
        except queue.Empty:
            if proc.poll() is not None:
                return False
    return False


def run_replay_demo(options: DemoOptions, stop: threading.Event) -> int:
    from protocol.net.session import build_config, free_tcp_endpoint

    endpoint = free_tcp_endpoint()
    tid = "demo"
    cmd, described = _child_command(options, tid, endpoint)

    def out(line: str) -> None:
        if not options.json:
            print(line)

    out(f"demo: {'replaying ' if options.replay else ''}{described} on {endpoint} for {options.duration:g} s")
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            env=child_env())
    lines: queue.Queue[str] = queue.Queue()
    assert proc.stderr is not None
    threading.Thread(target=pump, args=(proc.stderr, lines, not options.json), daemon=True).start()
    summary: dict[str, Any] = {"source": described, "endpoint": endpoint}
    try:
        # the child warms its pipeline up first: ~2 s, or ~1 min when its kernels compile (first run)
        if not _wait_ready(proc, lines, 300.0, stop):
            why = "interrupted" if stop.is_set() else f"exit code {proc.poll()}"
            print(f"{PROG} demo: the replay process did not start ({why})", file=sys.stderr)
            return 1
        summary.update(_receive(build_config("subscriber", connect=[endpoint]), tid, proc, stop,
                                options.duration + 15.0, out))
    finally:
        summary["replay_exit_code"] = stop_child(proc)
    ok = summary["frames"] > 0 and summary["in_order"] and summary["replay_exit_code"] == 0
    summary["ok"] = ok
    if options.json:
        print(json.dumps(summary))
    else:
        print(f"demo: {summary['frames']} frames received "
              f"(seq {summary['first_seq']}..{summary['last_seq']}), "
              f"in order: {'yes' if summary['in_order'] else 'NO'}, {summary['fps']:.1f} fps, "
              f"mean latency {summary['latency_ms']:.1f} ms, {summary['statuses']} status messages, "
              f"{summary['malformed']} malformed; child exit code {summary['replay_exit_code']}")
        print("demo: OK" if ok else "demo: FAILED")
    return 0 if ok else 1


# ------------------------------------------------------------------------------- the subscriber


@dataclass
class _Received:
    """What the demo's subscriber has seen."""

    out: Callable[[str], None]
    seqs: list[int] = field(default_factory=list)
    arrivals: list[float] = field(default_factory=list)
    latencies: list[float] = field(default_factory=list)
    statuses: int = 0
    malformed: int = 0

    def body(self, payload: bytes) -> None:
        from protocol.wire.codec import ProtocolError, decode
        from protocol.wire.messages import BodyInfo

        try:
            info = decode(payload, BodyInfo)
        except ProtocolError:
            self.malformed += 1
            return
        height = info.measurements.get("height_m", 0.0)
        self.out(f"demo: body model {info.body_model!r}, height {height:.2f} m")

    def pose(self, payload: bytes) -> None:
        from protocol.skeleton import JOINT_INDEX
        from protocol.wire.codec import ProtocolError, decode
        from protocol.wire.messages import PoseFrame

        try:
            f = decode(payload, PoseFrame)
        except ProtocolError:
            self.malformed += 1
            return
        self.seqs.append(f.seq)
        self.arrivals.append(time.monotonic())
        self.latencies.append(time.time() - f.publish_ts)
        j = f.joints
        head, lhand, rhand = JOINT_INDEX["head_top"], JOINT_INDEX["l_hand_tip"], JOINT_INDEX["r_hand_tip"]
        self.out(f"seq {f.seq:5d}  t={f.capture_ts:7.3f} s  conf={f.confidence:.2f}  "
                 f"head={j[head, 1]:.2f} m  l_hand={j[lhand, 1]:.2f} m  r_hand={j[rhand, 1]:.2f} m")

    def status(self, payload: bytes) -> None:
        from protocol.wire.codec import ProtocolError, decode
        from protocol.wire.messages import TrackerStatus

        try:
            st = decode(payload, TrackerStatus)
            self.statuses += 1
            self.out(f"status: {st.state.value}, {st.frames} frames, {st.fps:.1f} fps")
        except ProtocolError:
            self.malformed += 1

    def summary(self) -> dict[str, Any]:
        seqs, arrivals, latencies = self.seqs, self.arrivals, self.latencies
        span = arrivals[-1] - arrivals[0] if len(arrivals) > 1 else 0.0
        return {
            "frames": len(seqs),
            "first_seq": seqs[0] if seqs else None,
            "last_seq": seqs[-1] if seqs else None,
            "in_order": bool(seqs) and all(b == a + 1 for a, b in itertools.pairwise(seqs)),
            "fps": (len(seqs) - 1) / span if span > 0 else 0.0,
            "latency_ms": 1000.0 * sum(latencies) / len(latencies) if latencies else 0.0,
            "statuses": self.statuses,
            "malformed": self.malformed,
        }


def _receive(conf: zenoh.Config, tid: str, proc: subprocess.Popen[str], stop: threading.Event,
             timeout: float, out: Callable[[str], None]) -> dict[str, Any]:
    """Subscribe to the demo tracker, print what arrives and summarise it."""
    from protocol.net.session import open_session, undeclare_quietly
    from protocol.wire.keys import body_key, pose_key, status_key

    got = _Received(out)
    with open_session(conf) as session:
        pose_sub = status_sub = None
        try:
            pose_sub = session.declare_subscriber(pose_key(tid))
            status_sub = session.declare_subscriber(status_key(tid))
            for reply in session.get(body_key(tid), timeout=3.0):
                if reply.ok is not None:
                    got.body(reply.ok.payload.to_bytes())
            deadline = time.monotonic() + timeout
            exited_at: float | None = None
            while not stop.is_set() and time.monotonic() < deadline:
                any_sample = False
                while (sample := pose_sub.try_recv()) is not None:
                    any_sample = True
                    got.pose(sample.payload.to_bytes())
                while (sample := status_sub.try_recv()) is not None:
                    any_sample = True
                    got.status(sample.payload.to_bytes())
                if not any_sample:
                    if exited_at is None and proc.poll() is not None:
                        exited_at = time.monotonic()
                    if exited_at is not None and time.monotonic() - exited_at > 0.3:  # late arrivals
                        break
                    stop.wait(0.005)
        finally:
            undeclare_quietly(pose_sub, status_sub)
    return got.summary()


# ------------------------------------------------------------------------- the whole system
