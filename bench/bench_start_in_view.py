"""A person already in view at start: the tracker started with nobody out of the way, against the
same takes begun in an empty room.

Usage::

    .venv/bin/python bench/bench_start_in_view.py [--seeds 1,5] [--takes N] [--frames N]
        [--vary AXES] [--jobs J] [--out DIR]

Every cell is ``mocap-tracker eval --json --empty-prefix P`` (a subprocess, as a user runs it),
once with ``P = 12`` (the empty room first: the reference) and once with ``P = 0`` (the person in
the first frame, so the background is learned with them in it). Per pair it reports the MPJPE
from 3 s after the person appears (``mpjpe_after_3s_cm``), the poses published, the worst
published root error, the frames withheld as ghosts and the background re-learnings, and judges
the start as the cameras issue does:

``tracks``   from 3 s on, MPJPE within 1.5 cm of the empty-room start
``refuses``  from 3 s on, no pose published (the status asks the person to step aside)
``fails``    anything else

and, over all runs, whether any published root was more than 50 cm off (never allowed). Writes
``start_in_view.md`` and ``start_in_view.json`` to ``--out`` (default ``out/bench_start_in_view``).
Not a test: it takes minutes.
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

from _host import bench_meta, held_out_spread, write_report  # bench/ is the script's folder
from tqdm import tqdm

from protocol.formats.mocap_data import mocap_root

ROOT = Path(__file__).resolve().parent.parent
PREFIXES = (12, 0)


#: A person who stands half a second where the tracker first sees them, then side-steps 1.35 m and
#: raises their arms: the shared takes never leave the spot they start on.
STEP_ASIDE = ROOT / "protocol" / "scripts" / "step_aside.toml"


def _eval(motion: Path, seed: int, prefix: int, frames: int, vary: str) -> dict[str, Any]:
    kind = "--script" if motion.suffix == ".toml" else "--bvh"
    cmd = [sys.executable, "-m", "tracker_service", "eval", "-q", "--json", kind, str(motion), "--seed", str(seed),
           "--frames", str(frames), "--empty-prefix", str(prefix), "--vary", vary]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, check=False)
    if r.returncode != 0:
        return {"error": r.stderr.strip().splitlines()[-1:] or [f"exit {r.returncode}"]}
    return dict(json.loads(r.stdout.strip().splitlines()[-1]))


def judge(empty: dict[str, Any], in_view: dict[str, Any], tolerance_cm: float = 1.5) -> str:
    """``tracks``, ``refuses`` or ``fails`` (module docstring) for one take started both ways."""
    late, ref = in_view.get("mpjpe_after_3s_cm"), empty.get("mpjpe_after_3s_cm")
    if late is None:
        return "refuses"
    return "tracks" if ref is not None and late <= ref + tolerance_cm else "fails"


def _cell(v: Any, fmt: str = "{:.2f}") -> str:
    return "-" if v is None else fmt.format(v)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1,5", help="scene seeds (the subjects)")
    ap.add_argument("--takes", type=int, default=4, help="held-out takes spread over the list, besides the "
                                                          "step-aside script")
    ap.add_argument("--frames", type=int, default=240, help="frames with the person in view at most (8 s at 30 fps)")
    ap.add_argument("--vary", default="", help="domain-randomisation axes of the scene (eval --vary)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "out" / "bench_start_in_view"))
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    root = mocap_root()
    pick = [STEP_ASIDE, *(root / e.path for e in held_out_spread(args.takes))]
    cells = list(itertools.product(pick, seeds, PREFIXES))
    t0 = time.time()
    with ThreadPoolExecutor(args.jobs) as ex:
        runs = list(tqdm(ex.map(lambda c: _eval(c[0], c[1], c[2], args.frames, args.vary), cells),
                         total=len(cells), desc="start in view", unit="run"))
    by = {(e, s, p): r for (e, s, p), r in zip(cells, runs, strict=True)}
    lines = ["| take | seed | MPJPE from 3 s, empty room first cm | person in view at start cm | poses published "
             "(in view / empty) | worst root cm | withheld as ghost | relearned | verdict |",
             "|---|---|---|---|---|---|---|---|---|"]
    records, verdicts, worst_root = [], {"tracks": 0, "refuses": 0, "fails": 0}, 0.0
    for e, s in itertools.product(pick, seeds):
        empty, in_view = by[(e, s, 12)], by[(e, s, 0)]
        if "error" in empty or "error" in in_view:
            lines.append(f"| {e.stem} | {s} | error | | | | | | |")
            continue
        v = judge(empty, in_view)
        verdicts[v] += 1
        worst_root = max(worst_root, in_view.get("root_error_max_cm") or 0.0)
        take = str(e.relative_to(root) if e.is_relative_to(root) else e.relative_to(ROOT))
        records.append({"take": take, "seed": s, "verdict": v, "empty_room": empty, "in_view": in_view})
        lines.append(f"| {e.stem} | {s} | {_cell(empty.get('mpjpe_after_3s_cm'))} | "
                     f"{_cell(in_view.get('mpjpe_after_3s_cm'))} | {in_view['tracked_frames']} / "
                     f"{empty['tracked_frames']} | {_cell(in_view.get('root_error_max_cm'), '{:.0f}')} | "
                     f"{in_view.get('withheld', {}).get('ghost', 0)} | {in_view.get('background_relearns', 0)} | "
                     f"{v} |")
    summary = {**verdicts, "worst_published_root_cm": round(worst_root, 1)}
    lines.append("")
    lines.append(f"{verdicts['tracks']} track, {verdicts['refuses']} refuse, {verdicts['fails']} fail; worst published "
                 f"root error with the person in view at start: {worst_root:.0f} cm (never more than 50 cm allowed)")
    meta = bench_meta("bench_start_in_view.py", t0, seeds=seeds, takes=[r["take"] for r in records][::len(seeds)],
                      frames=args.frames, vary=args.vary)
    write_report(Path(args.out), "start_in_view", {"meta": meta, "summary": summary, "runs": records}, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
