"""eclipse-zenoh's memory growth per new session on the same host (the hostile-input soak's
+19 MB a minute, ``docs/BENCHMARKS.md``), reproduced without the product, and the setting that ends it.

Usage::

    .venv/bin/python bench/diag_zenoh_session_leak.py [--sessions 10] [--messages 20] [--size 280000]
        [--no-subscriber] [--set KEY=JSON5 ...] [--client-set KEY=JSON5 ...]

This process is a Zenoh router on loopback, configured as the product configures every session
(:func:`protocol.net.session.build_config`), with a subscriber on ``test/**`` unless
``--no-subscriber``. ``--sessions`` times, a child process -- a stranger: Zenoh's default
configuration in client mode, shared memory on -- opens a session to it, puts ``--messages``
payloads of ``--size`` bytes on ``test/x`` 10 ms apart, and closes. The router's resident and
locked memory and its mapped shared-memory segments are printed after each session. ``--set``
inserts keys in the router's config, ``--client-set`` in the stranger's.

Cause (eclipse-zenoh 1.6.2-1.10.2, 2026-12-06, the 2-core VM): with shared memory enabled on both
ends, a client on the same host sends every payload of 3,072 bytes or more through its 16 MiB
shared-memory pool (set up after its first message); the receiver maps that pool and its 1.25 MiB
of metadata, locks them in memory (``mlock``, since 1.6.2), and never unmaps them after the client
is gone: **+19.4 MB per session**, linear (14 sessions: +272 MB), whatever the message size above
3 KB, the rx buffers, ``max_message_size``, the allocator or the arena count. Where the process
may not lock that much (a user's default 8 MiB ``RLIMIT_MEMLOCK``), it receives only the first
message of each session and drops the rest without an error. Upstream: eclipse-zenoh/zenoh#2787
(and #2788). Eclipse-zenoh 1.6.1 maps without locking (+2.2 MB a session); 1.5.1's wheel has no
shared memory.

The product turns shared memory off in every session it opens (``build_config``; a config file
may turn it back on), and the receiver's setting alone decides it: with the router's default here
the stranger's sessions grow nothing (+2 MB in all after 12, every message received);
``--set transport/shared_memory/enabled=true`` brings the growth back.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from protocol.net.session import build_config, free_tcp_endpoint, open_session, undeclare_quietly  # noqa: E402

_CHILD = """
import json, time, zenoh
c = zenoh.Config()
for k, v in [("mode", '"client"'), ("connect/endpoints", json.dumps([{ep!r}])),
             ("scouting/multicast/enabled", "false"), *[kv.split("=", 1) for kv in {client_set!r}]]:
    c.insert_json5(k, v)
with zenoh.open(c) as s:
    for _ in range({messages}):
        s.put("test/x", b"x" * {size})
        time.sleep(0.01)
    time.sleep(0.3)
"""


def status_mb(field: str = "VmRSS") -> float:
    """A memory figure of this process from ``/proc/self/status`` (``VmRSS``: resident, ``VmLck``:
    locked), MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def shm_segments() -> int:
    """Zenoh shared-memory segments mapped into this process."""
    return sum(".zenoh" in line for line in Path("/proc/self/maps").read_text().splitlines())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=10)
    ap.add_argument("--messages", type=int, default=20)
    ap.add_argument("--size", type=int, default=280_000)
    ap.add_argument("--no-subscriber", action="store_true")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=JSON5", help="a key of the router's config")
    ap.add_argument("--client-set", action="append", default=[], metavar="KEY=JSON5",
                    help="a key of the stranger's config")
    args = ap.parse_args()
    ep = free_tcp_endpoint()
    conf = build_config(mode="router", listen=[ep])
    for kv in args.set:
        key, value = kv.split("=", 1)
        conf.insert_json5(key, value)
    received = [0]
    child = _CHILD.format(ep=ep, messages=args.messages, size=args.size, client_set=args.client_set)
    with open_session(conf) as session:
        sub = None if args.no_subscriber else session.declare_subscriber(
            "test/**", lambda _s: received.__setitem__(0, received[0] + 1))
        try:
            time.sleep(0.5)
            base = status_mb()
            print(f"router: transport/shared_memory = {conf.get_json('transport/shared_memory/enabled')}", flush=True)
            for i in range(args.sessions):
                rc = subprocess.run([sys.executable, "-c", child], capture_output=True, timeout=120).returncode
                print(f"{i + 1} sessions{'' if rc == 0 else ' (refused)'}: +{status_mb() - base:.1f} MB "
                      f"({status_mb('VmLck'):.1f} MB locked, {shm_segments()} shared-memory segments mapped), "
                      f"{received[0]} messages received", flush=True)
        finally:
            if sub is not None:
                undeclare_quietly(sub)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
