"""Child processes of the demo: their environment, their output pumped to a queue, a clean stop."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
from typing import Any

from tracker_service.paths import REPO_ROOT

__all__ = ["child_env", "pump", "stop_child"]


def child_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), env.get("PYTHONPATH", "")) if p)
    return env


def pump(stream: Any, lines: queue.Queue[str], echo: bool) -> None:
    for line in stream:
        lines.put(line)
        if echo:
            sys.stderr.write(f"  [child] {line}")


def stop_child(proc: subprocess.Popen[str], timeout: float = 3.0, signalled: bool = False) -> int:
    """Stop a child with SIGINT (once) and wait; its exit status, 0 for a child that died of that
    SIGINT (the stop it was asked for)."""
    if proc.poll() is None:
        if not signalled:
            proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    rc = int(proc.returncode)
    return 0 if rc == -signal.SIGINT else rc
