"""Bringing camera frames of common sizes to the tracker's working size: the shipped
:func:`tracker_service.sources.frame_source.fit_frame` (the centre crop, halvings, a bilinear
rest) against one area-averaging resize of the whole frame followed by the centre crop (the
straightforward form, and the previous one), on one thread.

Usage::

    .venv/bin/python bench/bench_frame_fit.py [--repeats R] [--json]

A random frame per size (the cost does not depend on the content); the two forms alternate, the
best of ``R`` rounds of 20 calls each. Prints per input size the milliseconds a frame of both
forms and their ratio. Not a test.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENCV_FOR_THREADS_NUM", "1")  # one thread, as the tracker's frame loop

import argparse  # (the thread setting above must precede cv2)
import json
import time
from typing import Any

import cv2
import numpy as np
from _host import bench_meta  # bench/ is the script's folder
from numpy.typing import NDArray

from tracker_service.sources.frame_source import fit_frame

SIZES = ((640, 480), (800, 600), (1280, 720), (1920, 1080), (3840, 2160))
WORKING = (320, 240)


def one_resize(img: NDArray[np.uint8], size: tuple[int, int]) -> NDArray[np.uint8]:
    """The whole frame area-averaged to cover ``size`` in one resize, then the centre cropped."""
    W, H = size
    h, w = img.shape[:2]
    s = max(W / w, H / h)
    rw, rh = max(W, round(w * s)), max(H, round(h * s))
    out = cv2.resize(img, (rw, rh), interpolation=cv2.INTER_AREA if s < 1.0 else cv2.INTER_LINEAR)
    x0, y0 = (rw - W) // 2, (rh - H) // 2
    return np.asarray(out[y0:y0 + H, x0:x0 + W], np.uint8)


def _ms_per_call(f: Any, img: NDArray[np.uint8], calls: int = 20) -> float:
    """Mean milliseconds of ``calls`` calls of ``f`` on ``img`` (one round)."""
    t = time.perf_counter()
    for _ in range(calls):
        f(img, WORKING)
    return (time.perf_counter() - t) / calls * 1e3


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7, help="rounds of 20 calls per form and size (the best counts)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    t0 = time.time()
    rng = np.random.default_rng(0)
    rows = []
    for w, h in SIZES:
        img = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        fit_frame(img, WORKING)  # first calls apart
        one_resize(img, WORKING)
        new, old = [], []
        for _ in range(args.repeats):  # alternated, so the machine's load falls on both alike
            new.append(_ms_per_call(fit_frame, img))
            old.append(_ms_per_call(one_resize, img))
        rows.append({"input": f"{w}x{h}", "fit_frame_ms": round(min(new), 3), "one_resize_ms": round(min(old), 3),
                     "speed_up": round(min(old) / min(new), 2)})
    out = {"meta": bench_meta("bench_frame_fit.py", t0, opencv=cv2.__version__), "rows": rows}
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        print(f"{'input':>10} {'fit_frame ms':>13} {'one resize ms':>14} {'ratio':>6}")
        for r in rows:
            print(f"{r['input']:>10} {r['fit_frame_ms']:13.3f} {r['one_resize_ms']:14.3f} {r['speed_up']:6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
