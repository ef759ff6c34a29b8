"""One template tree for the whole body family, or a tree per body? Accuracy on people far from the
database's body (children, tall and heavy men) with the shared tree scaled to the chosen model
against a tree built for a model of their own size, and what each costs in memory and build time.

Usage::

    .venv/bin/python bench/bench_body_databases.py [--takes 4] [--frames 90]
        [--subjects 6:cSA,13:cSA,35:mTA,48:mLB] [--jobs 2] [--out DIR]

Each subject is a synthetic person drawn by the scene seed with the ``body`` variation axis
(``eval --vary body --seed S``: seeds 6 and 13 are children of 1.19 and 1.17 m, 35 a man of 2.02 m
with a chest of 118 cm, 48 a man of 1.83 m with a chest of 130 cm). Every subject is tracked on the
same held-out takes twice: with the default database (``mMA``, templates scaled to the model the
silhouette chooses, :mod:`tracker_service.pipeline.body_selection`) and with the database of the
family model after the colon (``build-db --bodies NAME``, built first if missing; the body is still
chosen automatically). Writes ``body_databases.md`` and ``.json`` to ``--out`` (default
``out/bench_body_databases``).
"""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from _host import bench_meta, held_out_spread  # bench/ is the script's folder
from tqdm import tqdm

from protocol.formats.mocap_data import mocap_root

ROOT = Path(__file__).resolve().parent.parent
DB_ROOT = ROOT / "out" / "db"


def _eval(bvh: Path, seed: int, frames: int, db: str | None) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "tracker_service", "eval", "-q", "--json", "--bvh", str(bvh), "--seed", str(seed),
           "--frames", str(frames), "--vary", "body", *(["--db", str(DB_ROOT / db)] if db else [])]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, check=False)
    if r.returncode != 0:
        return {"error": (r.stderr.strip().splitlines() or [f"exit {r.returncode}"])[-1]}
    return dict(json.loads(r.stdout.strip().splitlines()[-1]))


#: A ``rss()`` of the child process's resident MB (Linux's /proc).
_RSS = ("import re; rss = lambda: int(re.search(r'VmRSS:\\s+(\\d+)', open('/proc/self/status').read())"
        ".group(1)) / 1024; ")


def _resident_mb(db: str) -> dict[str, float]:
    """What a process holds once it has loaded the database whole (MB): its resident growth after
    the load (``rss``), the peak during it (``peak``); what the tracker holds, which maps the arrays
    and builds the distance kernel's rectangles (``tracking_rss``); and the arrays' size on disk
    (``files``)."""
    code = (_RSS + "import gc, resource, sys; from tracker_service.templates.database import load_db; "
            "gc.collect(); r0 = rss(); p0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024; "
            "d = load_db(sys.argv[1], mmap=False); gc.collect(); "
            "print(rss() - r0, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - p0)")
    tracking = (_RSS + "import gc, sys; from tracker_service.templates.database import load_db; "
                "gc.collect(); r0 = rss(); d = load_db(sys.argv[1]); "
                "[rs.rectangles() for rs in d.db.level_runs]; gc.collect(); print(rss() - r0)")
    out: dict[str, float] = {}
    for key, c in (("whole", code), ("tracking", tracking)):
        r = subprocess.run([sys.executable, "-c", c, str(DB_ROOT / db)], capture_output=True, text=True, cwd=ROOT,
                           check=False)
        ok = r.returncode == 0 and r.stdout.strip()
        out[key] = r.stdout.strip().splitlines()[-1] if ok else ""
    files = sum(f.stat().st_size for f in (DB_ROOT / db).iterdir() if f.is_file()) / 2**20
    nan = float("nan")
    rss, peak = (float(x) for x in out["whole"].split()) if out["whole"] else (nan, nan)
    return {"rss": round(rss, 1), "peak": round(max(peak, rss), 1), "files": round(files, 1),
            "tracking_rss": round(float(out["tracking"]), 1) if out["tracking"] else nan}


def _ensure(db: str) -> float:
    """Build the database of family model ``db`` if missing; the build's wall time (0 if it existed)."""
    if (DB_ROOT / db / "manifest.json").is_file():
        return 0.0
    t0 = time.time()
    subprocess.run([sys.executable, "-m", "tracker_service", "build-db", "--bodies", db, "-q"], cwd=ROOT, check=True)
    return round(time.time() - t0, 1)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--takes", type=int, default=4, help="held-out takes spread over the list")
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--subjects", default="6:cSA,13:cSA,35:mTA,48:mLB", metavar="SEED:MODEL,...")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "out" / "bench_body_databases"))
    args = ap.parse_args()
    subjects = [(int(s), m) for s, m in (t.split(":") for t in args.subjects.split(",") if t.strip())]
    t0 = time.time()
    builds = {m: _ensure(m) for m in dict.fromkeys(m for _, m in subjects)}
    root = mocap_root()
    pick = held_out_spread(args.takes)
    cells = [(seed, db, take) for (seed, own), take in itertools.product(subjects, pick) for db in (None, own)]
    with ThreadPoolExecutor(args.jobs) as ex:
        runs = list(tqdm(ex.map(lambda c: _eval(root / c[2].path, c[0], args.frames, c[1]), cells),
                         total=len(cells), desc="body databases", unit="run"))
    records = [{"seed": s, "db": db or "mMA (shared, scaled)", "take": t.path, **r}
               for (s, db, t), r in zip(cells, runs, strict=True)]
    lines = ["| subject | database | MPJPE cm | frames within 10 cm | model chosen | stature error cm |",
             "|---|---|---|---|---|---|"]
    summary: list[dict[str, Any]] = []
    for (seed, own), db in itertools.product(subjects, (None, "own")):
        name = "mMA (shared, scaled)" if db is None else own
        ok = [r for r in records if r["seed"] == seed and r["db"] == name and r.get("mpjpe_cm") is not None]
        if not ok:
            lines.append(f"| seed {seed} | {name} | failed | | | |")
            continue
        subj = ok[0]["subject"]
        who = (f"seed {seed}: {subj['group']} {ok[0]['subject_height_m']:.2f} m, "
               f"chest {subj.get('chest_m', 0) * 100:.0f} cm")
        row = {"seed": seed, "database": name, "runs": len(ok),
               "mpjpe_cm": round(float(np.mean([r["mpjpe_cm"] for r in ok])), 2),
               "within_10cm": round(float(np.mean([r["frames_within_10cm"] for r in ok])), 3),
               "chosen": sorted({str(r.get("body_selected")) for r in ok}),
               "stature_error_cm": round(float(np.mean([abs(r["body_height_m"] - r["subject_height_m"]) * 100
                                                        for r in ok])), 1)}
        summary.append(row)
        lines.append(f"| {who} | {name} | {row['mpjpe_cm']} | {row['within_10cm']} | {', '.join(row['chosen'])} | "
                     f"{row['stature_error_cm']} |")
    memory = {db: _resident_mb(db) for db in ("mMA", *builds)}
    lines += ["", "| database | files MB | resident MB once loaded whole (peak while loading) "
                  "| resident MB as the tracker holds it (mapped, with the rectangles) | build s (0: existed) |",
              "|---|---|---|---|---|"]
    lines += [f"| {db} | {mb['files']} | {mb['rss']} ({mb['peak']}) | {mb['tracking_rss']} | {builds.get(db, '-')} |"
              for db, mb in memory.items()]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    meta = bench_meta("bench_body_databases.py", t0, takes=args.takes, frames=args.frames, subjects=args.subjects)
    (out / "body_databases.json").write_text(json.dumps({"meta": meta, "rows": summary, "memory_mb": memory,
                                                        "builds_s": builds, "runs": records}, indent=1, default=str))
    (out / "body_databases.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
