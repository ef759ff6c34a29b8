"""Run every benchmark in ``bench/`` one after the other (``make bench``); minutes, not a test.

Each script prints its own figures; copy them into docs/BENCHMARKS.md with the command line.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: Script -> arguments (kept small enough to finish in a few minutes each).
BENCHES = {
    "bench_foundation.py": [],
    "bench_render.py": [],
    "bench_game.py": ["--per-script", "40", "--loops", "1"],
    "bench_cloth.py": [],
    "bench_tracker.py": ["--takes", "4", "--frames", "90"],
    "bench_preview.py": [],
    "bench_frame_fit.py": [],
}


def main() -> int:
    failed = []
    for script, extra in BENCHES.items():
        path = HERE / script
        if not path.is_file():
            print(f"== {script}: missing, skipped", flush=True)
            continue
        print(f"== {script} {' '.join(extra)}", flush=True)
        if subprocess.run([sys.executable, str(path), *extra], check=False).returncode != 0:
            failed.append(script)
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
