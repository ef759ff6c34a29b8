"""Before/after on a fixed sample of recordings: one garment, one process, against a baseline sweep.

    .venv/bin/python bench/bench_cloth_sample.py --baseline ../main/out/bench_cloth_s3 [--garment skirt]

The sample: 22 skirt recordings that once failed the strain target
(waistband row, hands on the hip, dressing, borderline) and 4 that passed, for regressions. Prints
per recording the baseline and new max strain, max penetration, frames over 10 % and real-time
factor, then the counts within 10 % strain and 1 cm penetration. Not a test.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cloth_client.app.offline import simulate_motion  # noqa: E402
from protocol.formats.load import load_motion  # noqa: E402
from protocol.formats.mocap_data import mocap_root  # noqa: E402

SAMPLE = [f"bandai/dataset-{name}.bvh" for name in (
    "1_walk-right_sad_001", "1_bow_sad_001", "1_walk-left_sad_001", "1_walk_not-confident_001", "1_bow_normal_001",
    "2_wave-right-hand_masculine_019", "2_wave-left-hand_elderly_010", "2_wave-left-hand_elderly_019",
    "1_bow_old_001", "2_raise-up-left-hand_elderly_015", "1_walk_normal_001", "1_kick_normal_001",
    "2_walk-turn-left_feminine_011", "1_call_normal_001", "2_run_normal_026", "2_walk-turn-right_active_014",
    "1_bow_active_001", "1_walk-back_tired_001", "2_raise-up-left-hand_youthful_042",
    "2_wave-right-hand_youthful_001", "2_wave-right-hand_active_012", "2_raise-up-right-hand_youthful_036",
    "1_bow_tired_001", "2_walk_normal_001", "1_bow_proud_001", "2_wave-both-hands_active_001")]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", required=True,
                    help="results.json of a bench_cloth.py sweep, or the --out of an earlier run of this script")
    ap.add_argument("--garment", default="skirt")
    ap.add_argument("--out", default=None, help="write the new results here (JSON)")
    args = ap.parse_args(argv)
    data = json.loads(Path(args.baseline).read_text())
    rows = data if isinstance(data, list) else data["sweep"]["results"]
    base = {(r["recording"], r.get("garment", args.garment)): r for r in rows}
    out: list[dict[str, Any]] = []
    counts = [0, 0, 0, 0]
    for rel in SAMPLE:
        r = simulate_motion(load_motion(mocap_root() / rel), args.garment)
        b = base[(rel, args.garment)]
        out.append({**r, "recording": rel, "garment": args.garment})
        counts[0] += b["max_strain"] <= 0.10
        counts[1] += r["max_strain"] <= 0.10
        counts[2] += b["max_penetration_mm"] <= 10.0
        counts[3] += r["max_penetration_mm"] <= 10.0
        print(f"{rel:58s} strain {b['max_strain']:.3f} -> {r['max_strain']:.3f}  pen {b['max_penetration_mm']:5.1f} -> "
              f"{r['max_penetration_mm']:5.1f} mm  frames>10% {b['frames_over_10pct_strain']} -> "
              f"{r['frames_over_10pct_strain']}  rtf {b['realtime_factor']} -> {r['realtime_factor']}", flush=True)
    print(f"strain <= 10 %: {counts[0]} -> {counts[1]} / {len(SAMPLE)}; "
          f"penetration <= 1 cm: {counts[2]} -> {counts[3]}")
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
