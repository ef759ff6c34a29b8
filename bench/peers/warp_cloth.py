"""NVIDIA Warp's CPU cloth benchmark on this machine: the peer of ``bench/bench_cloth.py``'s free sheet.

Runs in its own environment (``.venv-warp``: ``warp-lang`` from its wheel, which carries its own
CPU compiler; ``make bench-warp`` creates it and runs the comparison), so the product's environment
does not depend on it. It runs the very benchmark Warp ships
(``warp/examples/benchmarks/benchmark_cloth.py``, mode ``warp_cpu``): its square sheet (structural,
shear and bending springs with damping, gravity, semi-implicit Euler, two pinned corners) and its
integrator (``benchmark_cloth_warp.WpIntegrator``), 16 substeps a 60 Hz frame, positions read back
after each frame. The benchmark's module runs its own timings when imported (on a GPU by default),
so its ``Cloth`` class is taken from its source file as it is, without running the module.

Prints one JSON object: ``{"warp": VERSION, "sheets": [{"side": N, "particles": N*N, "springs": S,
"substeps_per_s": X, "frames": F}, ...]}``.

Usage::

    .venv-warp/bin/python bench/peers/warp_cloth.py [--sides 48,64] [--seconds 3]
"""

import argparse
import ast
import importlib
import json
import sys
import time
from pathlib import Path

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sides", default="48,64", help="sheet sides (particles = side * side), comma-separated")
    ap.add_argument("--seconds", type=float, default=3.0, help="time each sheet for at least this long")
    args = ap.parse_args()
    import warp as wp

    wp.config.quiet = True
    wp.init()
    folder = Path(wp.__file__).parent / "examples" / "benchmarks"
    source = folder / "benchmark_cloth.py"
    try:  # written against warp-lang 1.19.0's layout: say plainly if another release moved it
        tree = ast.parse(source.read_text(encoding="utf-8"))
        classes = [n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Cloth"]
        namespace = {"np": np, "wp": wp}
        exec(compile(ast.Module(body=classes, type_ignores=[]), str(source), "exec"), namespace)
        cloth_class = namespace["Cloth"]
        sys.path.insert(0, str(folder))
        integrator_class = importlib.import_module("benchmark_cloth_warp").WpIntegrator
    except (OSError, SyntaxError, KeyError, ImportError, AttributeError) as exc:
        print(f"warp {wp.__version__}: its CPU cloth benchmark is not where 1.19.0 has it "
              f"({source}): {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    dt, substeps = 1.0 / 60.0, 16  # the benchmark's frame and substeps
    out = {"warp": wp.__version__, "sheets": []}
    for side in (int(s) for s in args.sides.split(",")):
        cloth = cloth_class(lower=(0.0, 0.0, 0.0), dx=side, dy=side, radius=0.1, stretch_stiffness=1000.0,
                            bend_stiffness=1000.0, shear_stiffness=1000.0, mass=0.1, fix_corners=True)
        integrator = integrator_class(cloth, "cpu")
        integrator.simulate(dt, substeps)  # compiles the kernels
        frames, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < args.seconds:
            integrator.simulate(dt, substeps)
            frames += 1
        elapsed = time.perf_counter() - t0
        out["sheets"].append({"side": side, "particles": cloth.num_particles, "springs": cloth.num_springs,
                              "substeps_per_s": round(frames * substeps / elapsed), "frames": frames})
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
