"""``mocap-tracker``: command-line entry point of the tracker service.

Subcommands
-----------
``replay``
    Publish a recorded (``--bvh``) or scripted (``--script``) motion over Zenoh as if a tracker
    saw it live, or the built-in ``--synthetic-wave`` self-test motion that needs no files.
``demo``
    What ``make demo`` runs: replays a real recording in a child process on a free loopback port,
    subscribes to it here, prints every received pose and checks that all frames arrived in order.

Exit status: 0 on success (including a clean stop by Ctrl-C / SIGTERM), 1 when the command failed
(one line on stderr says why), 2 for bad command-line arguments.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from protocol.net.cli_args import positive_float as _positive_float
from protocol.net.cli_args import positive_int as _positive_int
from protocol.net.session import (
    add_zenoh_args,
    build_config,
    free_tcp_endpoint,
    open_session,
    stop_on_signals,
    undeclare_quietly,
)
from protocol.skeleton import JOINT_INDEX
from protocol.wire.codec import ProtocolError, decode
from protocol.wire.keys import DEFAULT_TRACKER_ID, body_key, pose_key, status_key, validate_id
from protocol.wire.messages import BodyInfo, PoseFrame, TrackerStatus
from tracker_service.app.entry import default_sigterm
from tracker_service.paths import REPO_ROOT

__all__ = ["build_parser", "main"]

PROG = "mocap-tracker"
#: Commands that install :func:`protocol.net.session.stop_on_signals` and exit 0 on SIGTERM; until they
#: do, :mod:`tracker_service.app.entry`'s start-up handler gives the same clean exit.
_CLEAN_STOP_COMMANDS = frozenset({"run", "replay", "demo"})
_REPO_ROOT = REPO_ROOT
#: Recordings the demo tries, in order (relative to the shared mocap folder).
DEMO_RECORDINGS = (
    "bandai/dataset-2_raise-up-both-hands_normal_001.bvh",
    "bandai/dataset-1_byebye_normal_001.bvh",
    "bandai/dataset-1_bye_normal_001.bvh",
)
_J_HEAD, _J_LHAND, _J_RHAND = JOINT_INDEX["head_top"], JOINT_INDEX["l_hand_tip"], JOINT_INDEX["r_hand_tip"]






def _tracker_id(text: str) -> str:
    try:
        return validate_id(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    """The ``mocap-tracker`` argument parser (subcommands ``replay`` and ``demo``)."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log output on stderr (-vv for debug)")
    common.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors on stderr")
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Single-camera motion capture service: tracks (or replays) a person's pose and "
                    "streams it over Eclipse Zenoh on mocap/tracker/<id>/pose.",
        epilog=f"Run '{PROG} <command> --help' for the options of a command.",
    )
    sub = parser.add_subparsers(dest="command", metavar="<command>", required=True)

    rp = sub.add_parser(
        "replay", parents=[common], help="publish a recorded or scripted motion as a live pose stream",
        description="Publish a motion over Zenoh exactly like a live tracker: PoseFrames at the motion's "
                    "frame rate on mocap/tracker/<id>/pose, the body description on .../body (also "
                    "answered to queries), a status message every second on .../status and a "
                    "liveliness token on .../alive. Stops at the end of the motion (unless --loop), "
                    "after --duration or --frames, or on Ctrl-C.",
    )
    src = rp.add_argument_group("motion source (choose one)").add_mutually_exclusive_group(required=True)
    src.add_argument("--bvh", metavar="FILE", help="BVH recording, retargeted onto the shared skeleton")
    src.add_argument("--script", metavar="FILE", help="gesture script (.toml)")
    src.add_argument("--synthetic-wave", action="store_true",
                     help="built-in 4 s right-arm wave at 30 fps; a self-test source that needs no files")
    rp.add_argument("--rate", type=_positive_float, metavar="HZ",
                    help="frames per second to publish (default: the motion's own rate); frames are "
                         "repeated or skipped to match")
    rp.add_argument("--loop", action="store_true", help="start again at the end (seq and time continue)")
    rp.add_argument("--duration", type=_positive_float, metavar="S", help="stop after S seconds")
    rp.add_argument("--frames", type=_positive_int, metavar="N", help="stop after N frames")
    rp.add_argument("--id", type=_tracker_id, default=DEFAULT_TRACKER_ID,
                    help=f"tracker id used in the key expressions (default: '{DEFAULT_TRACKER_ID}'; "
                         "letters, digits, '_' and '-')")
    rp.add_argument("--wait-for-subscriber", type=float, default=0.0, metavar="S",
                    help="wait up to S seconds for a pose subscriber before the first frame, so it "
                         "receives the stream from seq 0 (default: start at once)")
    add_zenoh_args(rp, "publisher")
    rp.set_defaults(func=_cmd_replay)

    dp = sub.add_parser(
        "demo", parents=[common], help="replay a real recording and print what a subscriber receives",
        description="End-to-end check: runs the tracker daemon on the built-in synthetic scene (building "
                    "the default template database first if it is missing: a few minutes, once) in a "
                    "child process on a free loopback port, subscribes to it, prints one line per "
                    "received pose (sequence number, time, confidence, head and hand heights) and a "
                    "summary. With --replay it replays a real recording's ground truth instead. "
                    "Exits 0 only if frames arrived, all in order.",
    )
    dp.add_argument("--duration", type=_positive_float, default=6.0, metavar="S",
                    help="seconds to run (default: 6)")
    dp.add_argument("--json", action="store_true", help="print only a JSON summary on stdout")
    dp.add_argument("--replay", action="store_true",
                    help="replay the recording's ground truth instead of tracking the synthetic video")
    dp.set_defaults(func=_cmd_demo)

    from tracker_service.app.render_cli import add_render_parser
    from tracker_service.app.tracker_cli import add_tracker_parsers

    add_tracker_parsers(sub, [common])
    add_render_parser(sub, [common])
    return parser


def _setup_logging(args: argparse.Namespace) -> None:
    level = logging.WARNING if args.quiet else logging.INFO if args.verbose < 2 else logging.DEBUG
    logging.basicConfig(level=level, format=f"{PROG}: %(levelname)s %(name)s: %(message)s", stream=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    """Run ``mocap-tracker`` with ``argv`` (default ``sys.argv[1:]``) and return the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command not in _CLEAN_STOP_COMMANDS:
        default_sigterm()  # no clean stop of their own: a SIGTERM ends them with its usual status
    _setup_logging(args)
    if getattr(args, "wait_for_subscriber", 0.0) < 0:
        parser.error("--wait-for-subscriber must be >= 0")
    try:
        return int(args.func(args))
    except KeyboardInterrupt:  # only before a command installed its own signal handlers
        print(f"{PROG} {args.command}: interrupted", file=sys.stderr)
        return 130
    except NotImplementedError as exc:
        print(f"{PROG} {args.command}: not available yet: {exc}", file=sys.stderr)
    except (OSError, ValueError, ConnectionError, ProtocolError, RuntimeError) as exc:
        print(f"{PROG} {args.command}: {exc}", file=sys.stderr)
    return 1


def _cmd_replay(args: argparse.Namespace) -> int:
    from tracker_service.app.replay_daemon import run_replay

    return run_replay(args)


# ----------------------------------------------------------------------------------------- demo


def _pick_recording() -> tuple[list[str], str]:
    """Replay arguments for the demo's source and a one-line description of it."""
    from protocol.formats.mocap_data import mocap_root
    from protocol.motion import load_motion

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


def _child_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(_REPO_ROOT), env.get("PYTHONPATH", "")) if p)
    return env


def _pump(stream: Any, lines: queue.Queue[str], echo: bool) -> None:
    for line in stream:
        lines.put(line)
        if echo:
            sys.stderr.write(f"  [child] {line}")


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


def _stop_child(proc: subprocess.Popen[str]) -> int:
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=3.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return int(proc.returncode)


def _cmd_demo(args: argparse.Namespace) -> int:
    with stop_on_signals(threading.Event()) as stop:
        return _run_demo(args, stop)


def _run_demo(args: argparse.Namespace, stop: threading.Event) -> int:
    endpoint = free_tcp_endpoint()
    tid = "demo"
    if args.replay:
        source, described = _pick_recording()
        cmd = [sys.executable, "-m", "tracker_service", "replay", *source, "--id", tid, "--listen", endpoint,
               "--duration", str(args.duration), "--loop", "--wait-for-subscriber", "10"]
    else:
        from tracker_service.app.tracker_cli import DEFAULT_SCRIPT, ensure_db

        loaded = ensure_db(None)  # builds the default template database on first use (cached in out/db)
        described = (f"the tracker on the synthetic scene playing {DEFAULT_SCRIPT.name} "
                     f"(database {loaded.body.name}, {loaded.db.n_leaves} templates)")
        cmd = [sys.executable, "-m", "tracker_service", "run", "--source", f"synthetic:{DEFAULT_SCRIPT}",
               "--db", str(loaded.path), "--id", tid, "--listen", endpoint, "--duration", str(args.duration),
               "--wait-for-subscriber", "10"]
    def out(line: str) -> None:
        if not args.json:
            print(line)

    out(f"demo: {'replaying ' if args.replay else ''}{described} on {endpoint} for {args.duration:g} s")
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                            env=_child_env())
    lines: queue.Queue[str] = queue.Queue()
    assert proc.stderr is not None
    threading.Thread(target=_pump, args=(proc.stderr, lines, not args.json), daemon=True).start()
    summary: dict[str, Any] = {"source": described, "endpoint": endpoint}
    try:
        # the child warms its pipeline up first: ~2 s, or ~1 min when its kernels compile (first run)
        if not _wait_ready(proc, lines, 300.0, stop):
            why = "interrupted" if stop.is_set() else f"exit code {proc.poll()}"
            print(f"{PROG} demo: the replay process did not start ({why})", file=sys.stderr)
            return 1
        summary.update(_receive(build_config("subscriber", connect=[endpoint]), tid, proc, stop,
                                args.duration + 15.0, out))
    finally:
        summary["replay_exit_code"] = _stop_child(proc)
    ok = summary["frames"] > 0 and summary["in_order"] and summary["replay_exit_code"] == 0
    summary["ok"] = ok
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"demo: {summary['frames']} frames received "
              f"(seq {summary['first_seq']}..{summary['last_seq']}), "
              f"in order: {'yes' if summary['in_order'] else 'NO'}, {summary['fps']:.1f} fps, "
              f"mean latency {summary['latency_ms']:.1f} ms, {summary['statuses']} status messages, "
              f"{summary['malformed']} malformed; child exit code {summary['replay_exit_code']}")
        print("demo: OK" if ok else "demo: FAILED")
    return 0 if ok else 1


def _receive(conf: zenoh.Config, tid: str, proc: subprocess.Popen[str], stop: threading.Event,
             timeout: float, out: Callable[[str], None]) -> dict[str, Any]:
    """Subscribe to the demo tracker, print what arrives and summarise it."""
    seqs: list[int] = []
    arrivals: list[float] = []
    latencies: list[float] = []
    statuses, malformed = 0, 0
    with open_session(conf) as session:
        pose_sub = status_sub = None
        try:
            pose_sub = session.declare_subscriber(pose_key(tid))
            status_sub = session.declare_subscriber(status_key(tid))
            for reply in session.get(body_key(tid), timeout=3.0):
                if reply.ok is not None:
                    try:
                        info = decode(reply.ok.payload.to_bytes(), BodyInfo)
                    except ProtocolError:
                        malformed += 1
                        continue
                    height = info.measurements.get("height_m", 0.0)
                    out(f"demo: body model {info.body_model!r}, height {height:.2f} m")
            deadline = time.monotonic() + timeout
            exited_at: float | None = None
            while not stop.is_set() and time.monotonic() < deadline:
                got = False
                while (sample := pose_sub.try_recv()) is not None:
                    got = True
                    try:
                        f = decode(sample.payload.to_bytes(), PoseFrame)
                    except ProtocolError:
                        malformed += 1
                        continue
                    seqs.append(f.seq)
                    arrivals.append(time.monotonic())
                    latencies.append(time.time() - f.publish_ts)
                    j = f.joints
                    out(f"seq {f.seq:5d}  t={f.capture_ts:7.3f} s  conf={f.confidence:.2f}  "
                        f"head={j[_J_HEAD, 1]:.2f} m  l_hand={j[_J_LHAND, 1]:.2f} m  "
                        f"r_hand={j[_J_RHAND, 1]:.2f} m")
                while (sample := status_sub.try_recv()) is not None:
                    got = True
                    try:
                        st = decode(sample.payload.to_bytes(), TrackerStatus)
                        statuses += 1
                        out(f"status: {st.state.value}, {st.frames} frames, {st.fps:.1f} fps")
                    except ProtocolError:
                        malformed += 1
                if not got:
                    if exited_at is None and proc.poll() is not None:
                        exited_at = time.monotonic()
                    if exited_at is not None and time.monotonic() - exited_at > 0.3:  # late arrivals
                        break
                    stop.wait(0.005)
        finally:
            undeclare_quietly(pose_sub, status_sub)
    span = arrivals[-1] - arrivals[0] if len(arrivals) > 1 else 0.0
    return {
        "frames": len(seqs),
        "first_seq": seqs[0] if seqs else None,
        "last_seq": seqs[-1] if seqs else None,
        "in_order": bool(seqs) and all(b == a + 1 for a, b in itertools.pairwise(seqs)),
        "fps": (len(seqs) - 1) / span if span > 0 else 0.0,
        "latency_ms": 1000.0 * sum(latencies) / len(latencies) if latencies else 0.0,
        "statuses": statuses,
        "malformed": malformed,
    }
