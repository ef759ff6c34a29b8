"""How close the shared recordings come to each threshold of the gesture recogniser.

Usage::

    .venv/bin/python bench/bench_game_margins.py [--json] [--steps N] [--per-script N]

For every main threshold of the five gestures and of the in-place rule, the threshold is moved from
its default towards the permissive side (bisection, ``--steps`` halvings between the default and a
generous limit) until the first non-gesture recording (anything in ``INDEX.tsv`` that may not give
that gesture) yields a false gesture: ``false_at`` is that value and ``nearest`` the take. Then it
is moved towards the strict side until the first positive is lost: the 14 Bandai fire-ring takes
and ``--per-script`` random variants of each single-gesture script (speed, amplitude, body, facing,
jitter, drops, rate; see :func:`game_client.evaluation.random_cases`): ``lost_at``.
The margin on each side is the distance from the default. Boolean rules report how many false
gestures switching them off would let through.

One threshold moves at a time (the others at their defaults), so a margin says how far that one
rule is from letting the nearest look-alike through *given* the other rules. Features are
computed once per sequence (they do not depend on the detectors' parameters); the bisection
assumes the outcome is monotonic in the threshold.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from game_client.evaluation import allowed_gestures, degrade, expected_gestures, random_cases, recording
from game_client.features import FeatureExtractor, FrameFeatures
from game_client.gestures import GestureRecognizer, RecognizerConfig
from game_client.variants import load_labels, variant_labels, variant_motion
from protocol.formats.mocap_data import index_entries
from protocol.kinematics import fk

#: (gesture, parameter, permissive limit); the strict side goes as far the other way.
SCANS: tuple[tuple[str, str, float], ...] = (
    ("transform", "out_min", 0.1), ("transform", "chest_out_max", 0.3), ("transform", "max_gap_s", 6.0),
    ("crouch", "crouch_max", 0.85), ("crouch", "stand_min", 0.7), ("crouch", "landing_s", 0.0),
    ("side_step", "pelvis_min", 0.03), ("side_step", "foot_min", 0.03), ("side_step", "fwd_ratio_max", 1.5),
    ("side_step", "max_turn_deg", 90.0), ("side_step", "min_speed", 0.0), ("side_step", "settle_speed", 1.0),
    ("fire_ring", "raise_up", -0.25), ("fire_ring", "low_up", -0.05), ("fire_ring", "min_raised_s", 0.0),
    ("fire_ring", "max_raised_s", 8.0), ("fire_ring", "max_drop_s", 2.0), ("fire_ring", "min_separation", 0.0),
    ("fire_ring", "max_out", 0.6), ("fire_ring", "max_swings", 30.0), ("fire_ring", "rhythm_gap_s", 0.0),
    ("strike", "raise_up", -0.05), ("strike", "max_band_s", 0.6), ("strike", "left_max_up", 0.4),
    ("strike", "together_max", 0.5), ("strike", "min_left_seen", 0.0), ("strike", "max_swings", 30.0),
    ("strike", "min_drop_fwd", -0.5), ("strike", "max_raised_s", 10.0),
    ("arms", "still_max_turn_deg", 180.0), ("arms", "still_max_travel", 1.0), ("crouch", "crouch_max_travel", 1.0),
)
_ARM = {"transform", "strike", "fire_ring"}
BOOLS: tuple[tuple[str, str], ...] = (("fire_ring", "raise_seen"),)


class _Cached:
    """Stands in for a :class:`FeatureExtractor`: returns precomputed features in order."""

    def __init__(self, feats: list[FrameFeatures]) -> None:
        self.feats, self.k = feats, 0

    def update(self, *_a: Any, **_k: Any) -> FrameFeatures:
        f = self.feats[self.k]
        self.k += 1
        return f

    def reset(self, keep_height: bool = True) -> None:
        """Nothing to forget (the features were computed on the uninterrupted sequence)."""


Seq = tuple[str, np.ndarray, np.ndarray, list[FrameFeatures]]


def _events(seq: Seq, cfg: RecognizerConfig) -> list[tuple[str, float]]:
    _name, t, j, feats = seq
    rec = GestureRecognizer(cfg)
    rec.features = _Cached(feats)  # type: ignore[assignment]
    out = []
    for k in range(len(t)):
        out += [(e.gesture.value, e.t) for e in rec.update(float(t[k]), j[k])]
    return out


def _with(cfg: RecognizerConfig, group: str, name: str, value: float | bool) -> RecognizerConfig:
    if group == "arms":
        return replace(cfg, **{name: value})
    params = getattr(cfg, group)
    cast = type(getattr(params, name))
    return replace(cfg, **{group: replace(params, **{name: cast(value)})})


def load(per_script: int, seed: int) -> tuple[list[Seq], list[Seq], dict[str, frozenset[str]]]:
    """Every recording (as a negative for the gestures its tags do not allow), the positive
    sequences, and per sequence name the gestures it may (negatives) or must (positives) give."""
    negatives, positives = [], []
    gestures: dict[str, frozenset[str]] = {}
    for e in index_entries():
        t, j, _h = recording(e.path)
        seq = (e.path, t, j, FeatureExtractor().run(t, j))
        negatives.append(seq)
        gestures[e.path] = allowed_gestures(e.tags)
        if expected_gestures(e.tags):
            positives.append((e.path + "#expected", t, j, seq[3]))
            gestures[e.path + "#expected"] = frozenset(expected_gestures(e.tags))
    labels = load_labels()
    single = [n for n in labels if labels[n] and not n.startswith("round_")]
    for case in random_cases(np.random.default_rng(seed), per_script, single):
        m = variant_motion(case.script, case.variant)
        t, j = degrade(m.times, fk(m.poses, m.body), np.random.default_rng(case.seed), jitter_m=case.jitter_m,
                       drop_p=case.drop_p)
        positives.append((case.tag, t, j, FeatureExtractor().run(t, j)))
        gestures[case.tag] = frozenset(lb.gesture for lb in variant_labels(labels[case.script], case.variant))
    return negatives, positives, gestures


def _false(negatives: list[Seq], allowed: dict[str, frozenset[str]], cfg: RecognizerConfig,
           which: set[str]) -> list[str]:
    """Recordings giving one of the gestures ``which`` that their tags do not allow."""
    return [s[0] for s in negatives if any(g in which and g not in allowed[s[0]] for g, _ in _events(s, cfg))]


def _lost(positives: list[Seq], expected: dict[str, frozenset[str]], cfg: RecognizerConfig,
          which: set[str]) -> list[str]:
    """Positive sequences in which an expected gesture of ``which`` is not recognised."""
    lost = []
    for s in positives:
        want = expected[s[0]] & which
        if want and not want <= {g for g, _ in _events(s, cfg)}:
            lost.append(s[0])
    return lost


def _bisect(ok: Callable[[float], list[str]], d: float, limit: float, steps: int) -> tuple[float | None, list[str]]:
    """First value from ``d`` towards ``limit`` at which ``ok`` reports failures (None if none at the limit)."""
    bad = ok(limit)
    if not bad:
        return None, []
    lo, hi = d, limit
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        got = ok(mid)
        if got:
            hi, bad = mid, got
        else:
            lo = mid
    return hi, bad


def scan(negatives: list[Seq], positives: list[Seq], gestures: dict[str, frozenset[str]],
         steps: int) -> list[dict[str, Any]]:
    """One row per threshold (see the module docstring)."""
    base = RecognizerConfig()
    rows = []
    for group, name, limit in SCANS:
        top = group == "arms" or name == "crouch_max_travel"
        which = _ARM if group == "arms" else {group}
        d = float(getattr(base if top else getattr(base, group), name))
        strict = max(d + (d - limit), 0.0)  # as far the other way (no threshold here is meaningful below 0)
        if group == "crouch" and name != "landing_s":
            strict = min(strict, 1.0)

        def cfg(v: float, g: str = group, n: str = name, top: bool = top) -> RecognizerConfig:
            return _with(base, "arms" if top else g, n, v)

        t0 = time.perf_counter()
        f_at, f_takes = _bisect(lambda v, c=cfg, w=which: _false(negatives, gestures, c(v), w), d, limit, steps)
        l_at, l_takes = _bisect(lambda v, c=cfg, w=which: _lost(positives, gestures, c(v), w), d, strict, steps)
        rows.append({"gesture": group, "parameter": name, "default": d,
                     "false_at": None if f_at is None else round(f_at, 3),
                     "false_margin": None if f_at is None else round(abs(f_at - d), 3),
                     "nearest": [x.split("/")[-1] for x in f_takes][:3],
                     "lost_at": None if l_at is None else round(l_at, 3),
                     "recall_margin": None if l_at is None else round(abs(l_at - d), 3),
                     "first_lost": [x.split("/")[-1] for x in l_takes][:3], "limits": [limit, round(strict, 3)],
                     "seconds": round(time.perf_counter() - t0, 1)})
    for group, name in BOOLS:
        off = _with(base, group, name, False)
        rows.append({"gesture": group, "parameter": name, "default": True,
                     "false_when_off": [x.split("/")[-1] for x in _false(negatives, gestures, off, {group})]})
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=7, help="bisection halvings per side (default 7)")
    ap.add_argument("--per-script", type=int, default=12, help="random variants of each gesture script (default 12)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args()
    negatives, positives, gestures = load(args.per_script, args.seed)
    rows = scan(negatives, positives, gestures, args.steps)
    if args.json:
        print(json.dumps({"negatives": len(negatives), "positives": len(positives), "rows": rows}))
        return 0
    print(f"{len(negatives)} recordings, {len(positives)} positive sequences")
    print("| gesture | parameter | default | false gesture at (margin; nearest take) "
          "| positive lost at (margin; first) |")
    print("|---|---|---|---|---|")
    for r in rows:
        if "false_when_off" in r:
            print(f"| {r['gesture']} | {r['parameter']} | on | off: {len(r['false_when_off'])} false "
                  f"({', '.join(r['false_when_off'])}) | |")
            continue
        fa = "none up to limit" if r["false_at"] is None else f"{r['false_at']:g} ({r['false_margin']:g}; " \
             f"{', '.join(r['nearest'])})"
        la = "none up to limit" if r["lost_at"] is None else f"{r['lost_at']:g} ({r['recall_margin']:g}; " \
             f"{', '.join(r['first_lost'])})"
        print(f"| {r['gesture']} | {r['parameter']} | {r['default']:g} | {fa} | {la} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
