"""Where a garment's strain comes from, frame by frame: for every frame whose largest structural
strain is over 10 %, the worst spring's grid row and the body capsules nearest to its two particles.
Not a test; a diagnosis aid (it found the waistband-row class of the skirt).

    .venv/bin/python bench/diag_cloth_strain.py skirt bandai/dataset-1_bow_sad_001.bvh [more.bvh ...]

Prints one summary per recording: the worst frame (time, spring, nearest capsules and distances in
mm, sunk-limb state) and how the frames over 10 % split by row (``r0`` = the pinned row) and by the
nearest capsules.
"""

from __future__ import annotations

import collections
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cloth_client.contact.collision import round_cone_reference  # noqa: E402
from cloth_client.solver.cloth import structural_strain  # noqa: E402
from cloth_client.solver.driver import ClothDriver  # noqa: E402
from cloth_client.solver.garment import make_garment  # noqa: E402
from protocol.formats.load import load_motion  # noqa: E402
from protocol.formats.mocap_data import mocap_root  # noqa: E402
from protocol.skeleton import CAPSULE_INDEX  # noqa: E402

NAMES = {v: k for k, v in CAPSULE_INDEX.items()}


def diagnose(rel: str, garment: str, particles: int = 2000) -> str:
    """Summary line of recording ``rel`` (relative to the shared mocap folder)."""
    m = load_motion(mocap_root() / rel)
    g = make_garment(garment, m.body, particles)
    d = ClothDriver(m.body, g)
    cols = g.grid_shape[1]
    keep = np.asarray(m.valid, dtype=bool)
    poses, times = m.poses[keep], m.times[keep]
    rows: collections.Counter[str] = collections.Counter()
    caps: collections.Counter[tuple[str, ...]] = collections.Counter()
    worst, where = 0.0, "no frame over 10 %"
    r = m.body.capsule_radii
    for i in range(len(poses)):
        st = d.feed(poses[i], float(times[i]))
        if st is None or st.max_strain <= 0.10 or d.state is None or d._body_end is None:
            continue
        k = int(np.argmax(structural_strain(d.model, d.state.x)))
        i0, i1 = (int(v) for v in g.structural[k])
        a, b = d._body_end
        dist, _, _ = round_cone_reference(d.state.x[[i0, i1]], a, b, r[:, 0], r[:, 1])
        row = min(i0, i1) // cols
        rows["r0" if row == 0 else "r1-2" if row <= 2 else "r3+"] += 1
        caps[tuple(sorted({NAMES[int(np.argmin(dist[j]))] for j in range(2)}))] += 1
        if st.max_strain > worst:
            near = [(NAMES[int(c)], round(float(dist[j, c]) * 1000, 1))
                    for j in range(2) for c in np.argsort(dist[j])[:2]]
            worst = st.max_strain
            where = (f"t={times[i] - times[0]:.2f} s r{i0 // cols}c{i0 % cols}-r{i1 // cols}c{i1 % cols} near={near} "
                     f"sunk={d._ghost.astype(int).tolist()}")
    return f"{rel}: max={worst:.3f} {where}\n   rows={dict(rows)} caps={caps.most_common(4)}"


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__)
        return 2
    for rel in argv[1:]:
        print(diagnose(rel, argv[0]), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
