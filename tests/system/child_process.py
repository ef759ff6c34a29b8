"""A child process for the system tests: its stdout and stderr lines collected by reader threads."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]


def child_env() -> dict[str, str]:
    """The environment of a child: unbuffered output, the checkout first on the import path."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH", "")) if p)
    return env


class Proc:
    """A child process whose stdout/stderr lines are collected by reader threads."""

    def __init__(self, argv: list[str]):
        self.popen = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                      env=child_env(), cwd=REPO)
        self.out: list[str] = []
        self.err: list[str] = []
        self._err_q: queue.Queue[str] = queue.Queue()
        for stream, sink, q in ((self.popen.stdout, self.out, None), (self.popen.stderr, self.err, self._err_q)):
            threading.Thread(target=self._pump, args=(stream, sink, q), daemon=True).start()

    @staticmethod
    def _pump(stream: Any, sink: list[str], q: queue.Queue[str] | None) -> None:
        for line in stream:
            sink.append(line.rstrip("\n"))
            if q is not None:
                q.put(line)

    def wait_for(self, needle: str, timeout: float = 15.0) -> bool:
        """Wait for a stderr line containing ``needle`` (False on timeout or exit)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                if needle in self._err_q.get(timeout=0.05):
                    return True
            except queue.Empty:
                if self.popen.poll() is not None:
                    return False
        return False

    def stop(self, sig: signal.Signals = signal.SIGINT, timeout: float = 2.0) -> tuple[int | None, float]:
        """Send ``sig`` and wait up to ``timeout`` s: (exit status or None, seconds taken)."""
        t0 = time.monotonic()
        if self.popen.poll() is None:
            self.popen.send_signal(sig)
        try:
            rc = self.popen.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            rc = None
        return rc, time.monotonic() - t0

    def kill(self) -> None:
        if self.popen.poll() is None:
            self.popen.kill()
        self.popen.wait(timeout=5)
