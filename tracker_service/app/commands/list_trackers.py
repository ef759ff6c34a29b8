"""``mocap-tracker list``: every tracker alive on the Zenoh network (its liveliness token), with
its state, frame rate, estimator and body from its latest status message."""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from protocol.net.cli_args import positive_float
from protocol.net.session import add_zenoh_args
from tracker_service.app.commands.common import zenoh_options
from tracker_service.app.options import ZenohOptions

__all__ = ["CLEAN_STOP", "NAME", "ListOptions", "add_parser", "alive_trackers", "main", "options_from_args"]

NAME = "list"
CLEAN_STOP = False


@dataclass(frozen=True)
class ListOptions:
    """``mocap-tracker list``: how long to listen for status messages, and the session."""

    zenoh: ZenohOptions
    wait_s: float = 1.5
    json: bool = False


def add_parser(sub: Any, parents: Sequence[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Add ``list`` to the ``mocap-tracker`` subparsers."""
    lp = sub.add_parser(NAME, parents=list(parents), help="list the trackers alive on the network",
                        description="Ask the network for every tracker's liveliness token "
                                    "(mocap/tracker/*/alive), listen to their status messages for a "
                                    "moment and print one line per tracker: id, state, fps, estimator, body.")
    lp.add_argument("--wait", type=positive_float, default=1.5, metavar="S",
                    help="seconds to listen for status messages (default 1.5; they come once a second)")
    lp.add_argument("--json", action="store_true", help="print one JSON object per tracker")
    add_zenoh_args(lp, "subscriber")
    return lp


def options_from_args(args: argparse.Namespace) -> ListOptions:
    return ListOptions(zenoh=zenoh_options(args), wait_s=args.wait, json=args.json)


def alive_trackers(session: Any, wait_s: float) -> dict[str, dict[str, Any]]:
    """``{tracker id: {state, fps, estimator, body_model, frames}}`` of every tracker whose token is
    alive (the status fields None when no status arrived within ``wait_s``)."""
    from protocol.net.session import undeclare_quietly
    from protocol.wire.codec import ProtocolError, decode
    from protocol.wire.keys import ALL_ALIVE, ALL_STATUS, split_key
    from protocol.wire.messages import TrackerStatus

    statuses: dict[str, dict[str, Any]] = {}
    sub = session.declare_subscriber(ALL_STATUS)
    try:  # the status messages first: meanwhile the session's links come up
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:
            sample = sub.try_recv()
            if sample is None:
                time.sleep(0.02)
                continue
            try:
                st = decode(sample.payload.to_bytes(), TrackerStatus)
            except ProtocolError:
                continue
            statuses[st.tracker_id] = {"state": str(st.state), "fps": round(st.fps, 1), "estimator": st.estimator,
                                       "body_model": st.body_model, "frames": st.frames}
    finally:
        undeclare_quietly(sub)
    unknown = {"state": None, "fps": None, "estimator": None, "body_model": None, "frames": None}
    found: dict[str, dict[str, Any]] = {}
    for reply in session.liveliness().get(ALL_ALIVE, timeout=2.0):
        if reply.ok is not None:
            try:
                tid = split_key(str(reply.ok.key_expr)).id
            except ValueError:  # a token that is not a tracker's: not ours to list
                continue
            found[tid] = statuses.get(tid, unknown)
    return found


def main(options: ListOptions) -> int:
    """Print the trackers alive; exit status 0 (1 when the session cannot be opened)."""
    from protocol.net.session import open_session

    try:
        with open_session(options.zenoh.config()) as session:
            found = alive_trackers(session, options.wait_s)
    except Exception as exc:  # a bad endpoint or config: one line, not a traceback
        print(f"mocap-tracker list: {exc}", file=sys.stderr)
        return 1
    for tid in sorted(found):
        info = found[tid]
        if options.json:
            print(json.dumps({"id": tid, **info}))
        else:
            fps = "-" if info["fps"] is None else f"{info['fps']:.1f} fps"
            print(f"{tid}  {info['state'] or '?'}  {fps}  {info['estimator'] or '?'}  {info['body_model'] or '?'}")
    if not found and not options.json:
        print("no tracker alive", file=sys.stderr)
    return 0
