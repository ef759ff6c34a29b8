"""What the benchmarks share: the host-speed probe they record
(:mod:`tracker_service.app.host_probe`), the held-out takes spread over the list, and the ``meta``
block of their JSON (command, date, machine, probe, wall time)."""

from __future__ import annotations

import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from protocol.formats.mocap_data import IndexEntry, index_entries
from tracker_service.app.host_probe import host_probe
from tracker_service.build.database import is_held_out

__all__ = ["bench_meta", "held_out_spread", "host_probe"]


def held_out_spread(n: int) -> list[IndexEntry]:
    """``n`` of the held-out takes (never in the database), spread evenly over the list."""
    held = [e for i, e in enumerate(index_entries()) if is_held_out(i)]
    return [held[int(k)] for k in np.linspace(0, len(held) - 1, min(n, len(held)))]


def bench_meta(script: str, t0: float, **extra: Any) -> dict[str, Any]:
    """The ``meta`` block: the command as run, date, machine, host probe, ``extra`` and the wall
    time since ``t0`` (``time.time()``)."""
    return {"command": f"bench/{script} " + " ".join(sys.argv[1:]), "date": time.strftime("%Y-%m-%d"),
            "machine": f"{platform.machine()} {platform.processor() or ''}".strip(), "host": host_probe(),
            **extra, "wall_s": round(time.time() - t0)}


def write_report(out: Path, name: str, report: dict[str, Any], lines: list[str]) -> None:
    """Write ``out/NAME.json`` (``report``) and ``out/NAME.md`` (the table ``lines``), and print the table."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(report, indent=1, default=str))
    (out / f"{name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
