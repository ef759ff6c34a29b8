"""``python -m protocol``: inspect the live message stream, and fuzz a client.

Subcommand ``fuzz`` publishes hostile payloads (:mod:`protocol.wire.fuzz`: malformed bytes and
valid messages with absurd values) on a key at a steady rate, so that an integrator can check that
their client survives them; it prints how many of each case it sent.

Subcommand ``echo`` subscribes to the pose and status keys of one tracker (``--id ID``) or of all
trackers (``--id '*'``, the default) and prints every decoded message, one per line (``--json``:
one JSON object per line). Payloads that do not decode are counted, reported on stderr and
otherwise skipped; they never stop the command.

Exit status: 0 normally, also after Ctrl-C / SIGTERM; 1 if ``--count N`` pose frames did not arrive
within ``--timeout`` or the session could not be opened; 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from enum import Enum
from typing import Any

import numpy as np

from protocol.net.cli_args import positive_float as _positive
from protocol.net.cli_args import positive_int as _count
from protocol.net.session import add_zenoh_args, config_from_args, open_session, stop_on_signals, undeclare_quietly
from protocol.wire.codec import decode
from protocol.wire.keys import ANY, pose_key, split_key, status_key, validate_id
from protocol.wire.messages import PoseFrame, TrackerStatus

PROG = "python -m protocol"
log = logging.getLogger("protocol.echo")
_EXPECTED: dict[str, type[Any]] = {"pose": PoseFrame, "status": TrackerStatus}
_MAX_WARNINGS = 5


@dataclass
class EchoCounts:
    """What ``echo`` saw: decoded pose frames, status messages and malformed payloads."""

    poses: int = 0
    statuses: int = 0
    malformed: int = 0


def _id_or_any(text: str) -> str:
    try:
        return validate_id(text, allow_any=True)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None






def build_parser() -> argparse.ArgumentParser:
    """The ``python -m protocol`` argument parser."""
    parser = argparse.ArgumentParser(
        prog=PROG, description="Tools for the mocap message protocol on Zenoh."
    )
    sub = parser.add_subparsers(dest="command", metavar="<command>", required=True)
    ep = sub.add_parser(
        "echo", help="print the pose and status messages trackers publish",
        description="Subscribe to mocap/tracker/<id>/pose and mocap/tracker/<id>/status and print every "
                    "decoded message. Malformed payloads are counted and reported, never fatal.",
    )
    ep.add_argument("--id", type=_id_or_any, default=ANY,
                    help="tracker id to follow, or '*' for every tracker (default: '*')")
    ep.add_argument("--count", type=_count, metavar="N", help="stop after N pose frames")
    ep.add_argument("--timeout", type=_positive, metavar="S", help="stop after S seconds")
    ep.add_argument("--json", action="store_true", help="one JSON object per message on stdout")
    ep.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors on stderr")
    add_zenoh_args(ep, "subscriber")
    fp = sub.add_parser(
        "fuzz", help="publish hostile payloads on a key, to check that a client survives them",
        description="Publish malformed payloads and valid messages with absurd values (far-future times, "
                    "the largest sequence numbers, spoofed frames, giant and tiny bodies, NaN, oversized "
                    "arrays, deep nesting) on KEY. The message type follows the key's last segment "
                    "(pose or body). A client under test should count and drop them all and keep running.",
    )
    fp.add_argument("--key", required=True, help="the key to publish on, e.g. mocap/tracker/cam0/pose")
    fp.add_argument("--rate", type=_positive, default=100.0, metavar="HZ", help="payloads a second (default 100)")
    fp.add_argument("--duration", type=_positive, default=10.0, metavar="S", help="seconds (default 10)")
    fp.add_argument("--cases", default="", help="comma-separated cases (default: every case for the key's type)")
    fp.add_argument("--seed", type=int, default=0, help="the payloads' random seed")
    fp.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors on stderr")
    add_zenoh_args(fp, "publisher")
    return parser


def _plain(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, Enum):
        return v.value
    if isinstance(v, tuple):
        return [_plain(x) for x in v]
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    return v


def message_to_json(leaf: str, key: str, msg: Any) -> str:
    """One JSON line for a decoded message: ``{"type": leaf, "key": key, <fields>}``."""
    obj: dict[str, Any] = {"type": leaf, "key": key}
    obj.update({f.name: _plain(getattr(msg, f.name)) for f in fields(msg)})
    return json.dumps(obj)


def message_to_text(leaf: str, msg: Any) -> str:
    """One human-readable line for a decoded ``PoseFrame`` or ``TrackerStatus``."""
    if isinstance(msg, PoseFrame):
        root = ", ".join(f"{x:.2f}" for x in msg.pose[:3])
        return (f"pose   {msg.tracker_id:<12} seq={msg.seq:<6d} t={msg.capture_ts:8.3f} s "
                f"conf={msg.confidence:.2f} root=({root}) est={msg.estimator} model={msg.body_model}")
    if isinstance(msg, TrackerStatus):
        counters = " ".join(f"{k}={v}" for k, v in sorted(msg.counters.items()))
        return (f"status {msg.tracker_id:<12} {msg.state.value:<12} frames={msg.frames} "
                f"fps={msg.fps:.1f} uptime={msg.uptime_s:.1f}s {counters}".rstrip())
    return f"{leaf} {msg!r}"


def handle_payload(key: str, payload: bytes, counts: EchoCounts, emit: Callable[[str], None],
                   as_json: bool) -> None:
    """Decode one received payload, print it through ``emit`` and update ``counts``; never raises."""
    try:
        leaf = split_key(key).leaf
        msg = decode(payload, _EXPECTED[leaf])
    except Exception as exc:  # malformed input of any kind must not stop the echo
        counts.malformed += 1
        if counts.malformed <= _MAX_WARNINGS:
            log.warning("malformed payload on %s (%d bytes): %s", key, len(payload), exc)
        elif counts.malformed == _MAX_WARNINGS + 1:
            log.warning("more malformed payloads; only counting them from now on")
        return
    if leaf == "pose":
        counts.poses += 1
    else:
        counts.statuses += 1
    emit(message_to_json(leaf, key, msg) if as_json else message_to_text(leaf, msg))


def run_echo(args: argparse.Namespace, stop: threading.Event) -> tuple[EchoCounts, bool]:
    """Subscribe and print until ``stop``, ``--count`` or ``--timeout``; return counts and whether
    ``--count`` (if given) was reached."""
    counts = EchoCounts()
    keys = [pose_key(args.id), status_key(args.id)]
    deadline = None if args.timeout is None else time.monotonic() + args.timeout

    def emit(line: str) -> None:
        print(line, flush=True)

    with open_session(config_from_args(args, role="subscriber")) as session:
        subs: list[Any] = []
        try:
            subs = [session.declare_subscriber(k) for k in keys]
            log.info("listening on %s", ", ".join(keys))
            while not stop.is_set():
                if args.count is not None and counts.poses >= args.count:
                    break
                if deadline is not None and time.monotonic() >= deadline:
                    break
                idle = True
                for sub in subs:
                    while (sample := sub.try_recv()) is not None:
                        idle = False
                        handle_payload(str(sample.key_expr), sample.payload.to_bytes(), counts, emit,
                                       args.json)
                        if args.count is not None and counts.poses >= args.count:
                            break
                if idle:
                    stop.wait(0.005)
        finally:
            undeclare_quietly(*subs)
    return counts, args.count is None or counts.poses >= args.count


def fuzz_template(key: str) -> Any:
    """A valid message for ``key``'s leaf (``pose`` or ``body``) to build hostile ones from."""
    from protocol.skeleton import N_JOINTS, N_PARTS, POSE_SIZE, body_from_measurements
    from protocol.wire.messages import body_info_from_body

    leaf = key.rstrip("/").rsplit("/", 1)[-1]
    tid = key.split("/")[2] if key.startswith("mocap/tracker/") and key.count("/") >= 3 else "fuzz"
    if leaf == "pose":
        now = time.time()
        return PoseFrame(tracker_id=tid, seq=1, capture_ts=1.0, publish_ts=now, capture_wall_ts=now,
                         pose=np.zeros(POSE_SIZE, np.float32), joints=np.zeros((N_JOINTS, 3), np.float32),
                         visibility=np.ones(N_PARTS, np.float32), confidence=0.9, estimator="tree",
                         body_model="mMA")
    if leaf == "body":
        return body_info_from_body(body_from_measurements(1.7), tid)
    raise ValueError(f"fuzz: the key's last segment must be pose or body, got {leaf!r}")


def run_fuzz(args: argparse.Namespace, stop: threading.Event) -> dict[str, int]:
    """Publish until ``stop`` or ``--duration``; return the count of each case sent."""
    from protocol.wire.fuzz import cases_for, hostile_stream

    template = fuzz_template(args.key)
    allowed = cases_for(template)
    cases = tuple(c.strip() for c in args.cases.split(",") if c.strip())
    if unknown := [c for c in cases if c not in allowed]:
        raise ValueError(f"fuzz: unknown case(s) {', '.join(unknown)} for {args.key}; choose from {', '.join(allowed)}")
    sent: dict[str, int] = {}
    rng = np.random.default_rng(args.seed)
    t0 = time.monotonic()
    with open_session(config_from_args(args, role="publisher")) as session:
        pub = session.declare_publisher(args.key)
        try:
            stream = hostile_stream(template, rng, cases, last_seq=1, clock=0.0)
            k = 0
            while not stop.is_set() and time.monotonic() - t0 < args.duration:
                case, payload = next(stream)
                pub.put(payload)
                sent[case] = sent.get(case, 0) + 1
                k += 1
                stop.wait(max(0.0, t0 + k / args.rate - time.monotonic()))
        finally:
            undeclare_quietly(pub)
    return sent


def main(argv: list[str] | None = None) -> int:
    """Run ``python -m protocol`` with ``argv`` and return the exit status."""
    args = build_parser().parse_args(argv)
    if args.command == "fuzz":
        logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO, format="fuzz: %(message)s",
                            stream=sys.stderr)
        try:
            with stop_on_signals(threading.Event()) as stop:
                sent = run_fuzz(args, stop)
        except (OSError, ValueError, ConnectionError) as exc:
            print(f"{PROG} fuzz: {exc}", file=sys.stderr)
            return 1
        print(json.dumps({"key": args.key, "sent": sum(sent.values()), "cases": dict(sorted(sent.items()))}))
        return 0
    logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO,
                        format="echo: %(message)s", stream=sys.stderr)
    try:
        with stop_on_signals(threading.Event()) as stop:
            counts, complete = run_echo(args, stop)
    except (OSError, ValueError, ConnectionError) as exc:
        print(f"{PROG} echo: {exc}", file=sys.stderr)
        return 1
    print(f"echo: {counts.poses} pose, {counts.statuses} status, {counts.malformed} malformed",
          file=sys.stderr)
    if not complete:
        print(f"{PROG} echo: only {counts.poses} of {args.count} pose frames arrived within "
              f"{args.timeout:g} s", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
