"""Where the avatar's sunk-limb correction jumps: for every recording, the frame pairs on which a
forearm or hand that is active (not ghosted: sunk at most ``DriverConfig.ghost_depth`` into the
trunk after the correction) on both frames moves more than 2 cm further than the recorded one.
Not a test; a diagnosis aid (it found the flips of the nearest trunk surface
that :func:`cloth_client.avatar.limb_clearance.clear_limbs_track` now carries over). As in the cloth
driver, the correction runs over interpolation keys at most ``DriverConfig.key_dt`` apart; the
pairs compared are the recording's consecutive frames.

    .venv/bin/python bench/diag_limb_jumps.py [--max-push M] [name-substring ...]

Prints one line per recording with such a pair (the largest excess, where, how many pairs) and the
total number of pairs.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cloth_client.avatar.capsules import capsule_endpoints, interpolate_poses  # noqa: E402
from cloth_client.avatar.limb_clearance import LIMBS, MAX_PUSH, TRUNK, _axis_depth, clear_limbs  # noqa: E402
from cloth_client.solver.driver import DriverConfig  # noqa: E402
from protocol.formats.load import load_motion  # noqa: E402
from protocol.formats.mocap_data import index_entries, recording_path  # noqa: E402
from protocol.skeleton import CAPSULES  # noqa: E402

EXCESS = 0.02  # metres


def jumps(rel: str, max_push: float) -> tuple[int, float, str]:
    """(pairs over :data:`EXCESS`, largest excess in metres, where) for recording ``rel``."""
    m = load_motion(recording_path(rel))
    keep = np.asarray(m.valid, dtype=bool)
    poses, times = m.poses[keep], m.times[keep]
    radii = m.body.capsule_radii
    key_dt = DriverConfig().key_dt
    keys, at = [poses[:1]], [0]  # driver-like keys between frames; at[i]: index of frame i's key
    for i in range(1, len(poses)):
        n = max(1, math.ceil((times[i] - times[i - 1]) / key_dt - 1e-9))
        keys.append(interpolate_poses(poses[i - 1], poses[i], np.arange(1, n + 1) / n))
        at.append(at[-1] + n)
    ak, bk = capsule_endpoints(m.body, np.concatenate(keys))
    ack, bck = clear_limbs(ak, bk, radii, max_push=max_push)
    b, ac, bc = bk[at], ack[at], bck[at]
    s = np.linspace(0.0, 1.0, 9)
    depth = np.concatenate([_axis_depth(ac[k:k + 24], bc[k:k + 24], radii, LIMBS, TRUNK, s)[0].max(axis=2)
                            for k in range(0, len(ac), 24)])  # (K, 4)
    active = depth.reshape(-1, 2, 2).max(axis=2).repeat(2, axis=1) <= DriverConfig().ghost_depth
    both = active[1:] & active[:-1]
    raw = np.linalg.norm(np.diff(b[:, LIMBS], axis=0), axis=2)
    fixed = np.linalg.norm(np.diff(bc[:, LIMBS], axis=0), axis=2)
    excess = np.where(both, fixed - raw, 0.0)
    k, limb = np.unravel_index(int(excess.argmax()), excess.shape)
    where = (f"{CAPSULES[LIMBS[limb]][0]} at t={times[k + 1] - times[0]:.3f} s "
             f"(recorded step {raw[k, limb] * 100:.1f} cm)")
    return int((excess > EXCESS).sum()), float(excess.max()), where


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-push", type=float, default=MAX_PUSH)
    ap.add_argument("names", nargs="*", help="only recordings whose path contains one of these")
    args = ap.parse_args(argv)
    total = 0
    for e in index_entries():
        if args.names and not any(n in e.path for n in args.names):
            continue
        n, worst, where = jumps(e.path, args.max_push)
        total += n
        if n:
            print(f"{e.path}: {n} pairs, largest excess {worst * 100:.1f} cm, {where}", flush=True)
    print(f"total: {total} frame pairs over {EXCESS * 100:.0f} cm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
