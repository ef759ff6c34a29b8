"""A host-speed probe for the benchmarks' JSON: the same machine kind runs 2x faster or slower
from one run to the next (docs/BENCHMARKS.md), so every result records how long
this host takes for a fixed piece of work, and figures from two runs can be compared through it."""

from __future__ import annotations

import time

__all__ = ["host_probe"]


def host_probe(repeats: int = 3) -> float:
    """Median seconds of a CPython loop of 10^7 integer additions (about 1.5 s on the 2-core benchmark VM)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        s = 0
        for i in range(10_000_000):
            s += i
        times.append(time.perf_counter() - t0)
    return round(sorted(times)[len(times) // 2], 3)
