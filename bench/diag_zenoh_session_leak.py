"""A minimal reproduction of eclipse-zenoh's memory growth per new session sending fragmented
messages (the hostile-input soak's +19 MB a minute, ``docs/BENCHMARKS.md``), for an upstream report.

Usage::

    .venv/bin/python bench/diag_zenoh_session_leak.py [--sessions 10] [--messages 20] [--size 280000]
        [--no-subscriber] [--set KEY=JSON5 ...]

This process is a Zenoh router on loopback (with a subscriber on ``test/**`` unless
``--no-subscriber``); ``--sessions`` times, a child process opens a client session to it, puts
``--messages`` payloads of ``--size`` bytes on ``test/x`` 10 ms apart, and closes. The router's
resident memory (``VmRSS``) is printed after each session. ``--set`` inserts configuration keys in
the router's config (e.g. ``transport/link/rx/buffer_size=16384``).

Measured 2026-12-06, eclipse-zenoh 1.10.2, the 2-core VM: **+19.4 MB per session** whenever a
client sends two or more messages larger than one 64 KB batch in one session (100 or 280 kB
alike, two or a hundred of them), with or without a subscriber; unchanged by
``transport/link/rx/buffer_size`` (16 KiB or 64 KiB), ``transport/link/rx/max_message_size``
(100 kB, so the messages are dropped), one-batch transmit queues, 100 ms between messages and
``MALLOC_ARENA_MAX=2``. One message per session, or the same
messages from one long-lived session, grow nothing. A router that requires user/password
authentication (``--set 'transport/auth/usrpwd/dictionary_file="FILE"'``, as ``deploy/``'s configs)
refuses those sessions and stays flat (+0.5 MB after 4).
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
import sys, time, zenoh
sys.path.insert(0, {root!r})
from protocol.net.session import build_config
with zenoh.open(build_config(mode="client", connect=[{ep!r}])) as s:
    for _ in range({messages}):
        s.put("test/x", b"x" * {size})
        time.sleep(0.01)
    time.sleep(0.3)
"""


def rss_mb() -> float:
    """This process's resident memory (MB)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=10)
    ap.add_argument("--messages", type=int, default=20)
    ap.add_argument("--size", type=int, default=280_000)
    ap.add_argument("--no-subscriber", action="store_true")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=JSON5")
    args = ap.parse_args()
    ep = free_tcp_endpoint()
    conf = build_config(mode="router", listen=[ep])
    for kv in args.set:
        key, value = kv.split("=", 1)
        conf.insert_json5(key, value)
    received = [0]
    child = _CHILD.format(root=str(ROOT), ep=ep, messages=args.messages, size=args.size)
    with open_session(conf) as session:
        sub = None if args.no_subscriber else session.declare_subscriber(
            "test/**", lambda _s: received.__setitem__(0, received[0] + 1))
        try:
            time.sleep(0.5)
            base = rss_mb()
            for i in range(args.sessions):
                rc = subprocess.run([sys.executable, "-c", child], capture_output=True, timeout=120).returncode
                print(f"{i + 1} sessions{'' if rc == 0 else ' (refused)'}: +{rss_mb() - base:.1f} MB, "
                      f"{received[0]} messages received", flush=True)
        finally:
            if sub is not None:
                undeclare_quietly(sub)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
