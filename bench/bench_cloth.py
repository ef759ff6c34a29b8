"""Cloth benchmarks: solver speed, real-time factor with collision, and a quality sweep over every
shared recording. Takes minutes; it is not a test.

    .venv/bin/python bench/bench_cloth.py                 # everything (speed + full sweep, both garments)
    .venv/bin/python bench/bench_cloth.py --skip-sweep    # speed only (about a minute)
    .venv/bin/python bench/bench_cloth.py --limit 20      # sweep only the first 20 recordings
    .venv/bin/python bench/bench_cloth.py --skip-sweep --rt-particles 2000 --out out/bench_cloth/speed.json

Results are printed as Markdown and written to ``out/bench_cloth/results.json``.

Speed figures
-------------
* ``springs+integrate``: substeps/s of the mass-spring model alone (structural, shear and bending
  springs with damping, gravity, semi-implicit Euler) on a free square sheet of 48 x 48 = 2,304 and
  64 x 64 = 4,096 particles, no collision - the model NVIDIA Warp's CPU cloth benchmark times;
* ``warp_cpu``: that benchmark itself, run in the same bench right after our two sheets' figures
  (``bench/peers/warp_cloth.py`` in ``--warp-python``'s environment, by default ``.venv-warp``,
  which ``make bench-warp`` creates; without it the column is empty, never a remembered figure);
* ``full, no collision``: the same sheets with everything our substep does except body collision
  (air drag, long-range attachments, line and Gauss-Seidel strain limiting);
* real-time factor (simulated s per wall s) of a cape and a skirt of about 2,000 and 5,000 particles
  on the first 20 s of a real recording resampled to 60 Hz, collision included, one core.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import subprocess
import sys
import time
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _host import host_probe  # noqa: E402  (bench/ is the script's folder)

from cloth_client.app.offline import simulate_motion  # noqa: E402
from cloth_client.contact.collision import CapsuleTrack  # noqa: E402
from cloth_client.solver.cloth import ClothParams, build_model, initial_state, step  # noqa: E402
from cloth_client.solver.driver import DriverConfig  # noqa: E402
from cloth_client.solver.garment import DEFAULT_PARTICLES, make_sheet  # noqa: E402
from protocol.formats.load import load_motion  # noqa: E402
from protocol.formats.mocap_data import index_entries, mocap_root  # noqa: E402

#: Recording used for the real-time factor (a 63 s dance with spins and crouches).
RT_RECORDING = "bandai/dataset-1_dance-short_normal_001.bvh"
WARP_PYTHON = ROOT / ".venv-warp" / "bin" / "python"


def _substeps_per_s(side: int, params: ClothParams, seconds: float = 3.0) -> float:
    g = make_sheet(side, side, 0.02)
    model = build_model(g, params)
    empty = CapsuleTrack(np.zeros((2, 0, 3)), np.zeros((2, 0, 3)), np.zeros((0, 2)))
    pins = np.repeat(g.rest[g.pin_index][None], 2, axis=0)
    state = initial_state(model)
    chunk = 50
    state = step(state, model, empty, pins, chunk * 1e-3, n_substeps=chunk)  # compile + warm up
    done, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        state = step(state, model, empty, pins, chunk * 1e-3, n_substeps=chunk)
        done += chunk
    return done / (time.perf_counter() - t0)


def warp_sheets(python: Path, sides: tuple[int, ...]) -> dict[int, int]:
    """NVIDIA Warp's CPU cloth benchmark (``bench/peers/warp_cloth.py``) run by ``python``: substeps/s
    per sheet side; empty when that environment is missing or the run fails (said on stdout)."""
    if not python.exists():
        print(f"  warp: {python} not found (make bench-warp creates it); no Warp figures", flush=True)
        return {}
    cmd = [str(python), str(ROOT / "bench" / "peers" / "warp_cloth.py"), "--sides", ",".join(map(str, sides))]
    try:
        run = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=600)
    except (OSError, subprocess.TimeoutExpired) as exc:
        print(f"  warp: the peer did not run: {exc}", flush=True)
        return {}
    try:
        sheets = json.loads(run.stdout.strip().splitlines()[-1])["sheets"]
        return {int(r["side"]): int(r["substeps_per_s"]) for r in sheets}
    except (ValueError, KeyError, IndexError):
        print(f"  warp: the peer failed (exit {run.returncode}): {run.stderr.strip()[-300:]}", flush=True)
        return {}


def speed(rt_particles: tuple[int, ...] = (2000, 5000), overrides: dict[str, Any] | None = None,
          warp_python: Path | None = WARP_PYTHON) -> dict[str, Any]:
    """Substeps/s on free sheets beside Warp's (``warp_python``: its environment; None: not run) and
    real-time factors with collision (garments of ``rt_particles``)."""
    bare = ClothParams(limit_iterations=0, final_sweeps=0, final_rounds=0, air_density=0.0, floor=None, tethers=False)
    full = ClothParams(floor=None)
    out: dict[str, Any] = {"free_sheet": []}
    sides = (48, 64)
    rows: list[dict[str, Any]] = [{"particles": side * side, "springs+integrate": round(_substeps_per_s(side, bare)),
             "full, no collision": round(_substeps_per_s(side, full))} for side in sides]
    warp = warp_sheets(warp_python, sides) if warp_python is not None else {}
    for side, row in zip(sides, rows, strict=True):
        row["warp_cpu"] = warp.get(side)
        if row["warp_cpu"]:
            row["full / warp"] = round(row["full, no collision"] / row["warp_cpu"], 2)
            row["springs+integrate / warp"] = round(row["springs+integrate"] / row["warp_cpu"], 2)
        out["free_sheet"].append(row)
        print(f"  sheet {side}x{side}: {row}", flush=True)
    motion = load_motion(mocap_root() / RT_RECORDING, fps=60.0)  # 60 Hz input, as in the target
    params, config = split_overrides(overrides)
    out["realtime"] = []
    for garment in ("cape", "skirt"):
        for n in rt_particles:
            r = simulate_motion(motion, garment, particles=n, max_frames=1200,  # 20 s
                                params=params, config=config)
            row = {k: r[k] for k in ("garment", "particles", "realtime_factor", "steps_per_s", "sim_time_s",
                                     "max_penetration_mm", "max_strain")}
            out["realtime"].append(row)
            print(f"  realtime {row}", flush=True)
    return out


#: ``--param`` prefix of a ``DriverConfig`` field (no prefix: a ``ClothParams`` field).
CFG = "cfg."


def parse_overrides(items: list[str]) -> dict[str, Any]:
    """``["key=value", ...]`` -> overrides, each value parsed as its field's type: ``key`` a
    ``ClothParams`` field, ``cfg.key`` a ``DriverConfig`` field.

    Raises
    ------
    SystemExit
        On an unknown field or a value of the wrong type.
    """
    fields = {f.name for f in dataclasses.fields(ClothParams)}
    fields |= {CFG + f.name for f in dataclasses.fields(DriverConfig)}
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or key not in fields:
            raise SystemExit(f"--param {item!r}: expected KEY=VALUE with KEY one of {', '.join(sorted(fields))}")
        owner = DriverConfig() if key.startswith(CFG) else ClothParams()
        current = getattr(owner, key.removeprefix(CFG))
        try:
            if isinstance(current, bool):
                if raw not in ("True", "False", "1", "0"):
                    raise ValueError(raw)
                out[key] = raw in ("True", "1")
            elif isinstance(current, (int, float)):
                out[key] = type(current)(raw)
            else:
                raise ValueError(f"{key} cannot be set from the command line")
        except ValueError as exc:
            raise SystemExit(f"--param {item!r}: {exc}") from None
    return out


def split_overrides(overrides: dict[str, Any] | None) -> tuple[ClothParams, DriverConfig]:
    """:func:`parse_overrides`' result as the solver parameters and the driver config."""
    items = (overrides or {}).items()
    return (ClothParams(**{k: v for k, v in items if not k.startswith(CFG)}),
            DriverConfig(**{k.removeprefix(CFG): v for k, v in items if k.startswith(CFG)}))


def _one(job: tuple[str, str, int, dict[str, Any]]) -> dict[str, Any]:
    rel, garment, particles, overrides = job
    try:
        motion = load_motion(mocap_root() / rel)
        params, config = split_overrides(overrides)
        r = simulate_motion(motion, garment, particles=particles, params=params, config=config)
        r["recording"] = rel
        return r
    except Exception as exc:  # report and keep sweeping
        return {"recording": rel, "garment": garment, "error": f"{type(exc).__name__}: {exc}"}


def sweep(garments: list[str], particles: int, jobs: int, limit: int | None,
          overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Every recording of the shared index, each garment: NaN, penetration, strain."""
    entries = index_entries()
    entries.sort(key=lambda e: -e.frames / e.fps)  # longest first for better load balance
    if limit is not None:
        entries = entries[:limit]
    work = [(e.path, g, particles, dict(overrides or {})) for g in garments for e in entries]
    results: list[dict[str, Any]] = []
    with get_context("spawn").Pool(jobs) as pool:
        for i, r in enumerate(pool.imap_unordered(_one, work), 1):
            results.append(r)
            flag = r.get("error") or (f"strain {r['max_strain']:.3f} pen {r['max_penetration_mm']:.1f} mm "
                                      f"rtf {r['realtime_factor']}")
            print(f"  [{i}/{len(work)}] {r['garment']:5s} {r['recording']}: {flag}", flush=True)
    summary: dict[str, Any] = {}
    for g in garments:
        rs = [r for r in results if r["garment"] == g and "error" not in r]
        if not rs:
            continue
        summary[g] = {
            "recordings": len(rs),
            "errors": sum(1 for r in results if r["garment"] == g and "error" in r),
            "nan": any(r["nan"] for r in rs),
            "max_penetration_mm": max(r["max_penetration_mm"] for r in rs),
            "mean_penetration_mm": float(np.mean([r["mean_penetration_mm"] for r in rs])),
            "max_strain": max(r["max_strain"] for r in rs),
            "recordings_over_10pct_strain": sum(1 for r in rs if r["max_strain"] > 0.10),
            "recordings_over_1cm_penetration": sum(1 for r in rs if r["max_penetration_mm"] > 10.0),
            "frames_over_10pct_strain": sum(r["frames_over_10pct_strain"] for r in rs),
            "frames": sum(r["frames"] for r in rs),
            "max_energy_drift": max(r["energy_drift"] for r in rs),
            "resets": sum(r["resets"] for r in rs),
            "realtime_factor_median": float(np.median([r["realtime_factor"] for r in rs])),
            "worst_strain": sorted(((r["max_strain"], r["recording"]) for r in rs), reverse=True)[:5],
            "worst_penetration": sorted(((r["max_penetration_mm"], r["recording"]) for r in rs), reverse=True)[:5],
        }
    return {"summary": summary, "results": results}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--particles", type=int, default=DEFAULT_PARTICLES, help="particles per garment in the sweep")
    ap.add_argument("--garments", default="cape,skirt", help="comma-separated garments for the sweep")
    ap.add_argument("--jobs", type=int, default=max(1, (os.cpu_count() or 1)), help="sweep processes")
    ap.add_argument("--limit", type=int, default=None, help="sweep only the N longest recordings")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--skip-sweep", action="store_true")
    ap.add_argument("--rt-particles", default="2000,5000", help="garment sizes for the real-time factor")
    ap.add_argument("--out", default=str(ROOT / "out" / "bench_cloth" / "results.json"))
    ap.add_argument("--warp-python", type=Path, default=WARP_PYTHON, metavar="PATH",
                    help="Python of the environment holding warp-lang, for Warp's CPU cloth benchmark beside the "
                         "free sheet (default: .venv-warp/bin/python, made by make bench-warp)")
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE",
                    help="override a ClothParams field (or cfg.FIELD a DriverConfig field) in the real-time "
                         "runs and the sweep (repeatable), e.g. extra_rounds=12 or cfg.slide_fraction=0")
    args = ap.parse_args(argv)
    overrides = parse_overrides(args.param)
    res: dict[str, Any] = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                       "processor": platform.processor() or platform.machine(),
                                       "host_probe_s": host_probe()},
                           "params": overrides}
    if not args.skip_speed:
        print("speed:", flush=True)
        res["speed"] = speed(tuple(int(n) for n in args.rt_particles.split(",")), overrides, args.warp_python)
    if not args.skip_sweep:
        print("sweep:", flush=True)
        res["sweep"] = sweep(args.garments.split(","), args.particles, args.jobs, args.limit, overrides)
        print(json.dumps(res["sweep"]["summary"], indent=2))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1))
    print(f"results written to {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
