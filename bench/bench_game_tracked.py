"""Game gestures tracked from pixels: scripts rendered as synthetic video, tracked, recognised.

Usage::

    .venv/bin/python bench/bench_game_tracked.py [--db PATH] [--scripts a,b,...] [--variants N]
                                                 [--lead-in S] [--seed S] [--appearance PATH|off]
                                                 [--cache DIR] [--json]

For every bundled single-gesture script (positives and near-misses; ``--rounds`` adds the
whole-round scripts) and a few variants of it (speed x seed; the seed picks the synthetic person,
so it varies body size and shape, outfit, room and lighting), the motion is

1. preceded by ``--lead-in`` seconds of its first pose (the player standing in front of the camera
   while the tracker learns the background and locks on; the labels move by as much),
2. rendered as synthetic video by :class:`tracker_service.scene.synthetic.SyntheticScene` (320x240, 30 Hz,
   sensor noise, 12 empty-room frames first, the person facing the camera),
3. tracked frame by frame from the pixels with :func:`tracker_service.pipeline.process.process_frame` (the
   loop of :func:`tracker_service.app.evaluate.evaluate_motion`, without forced losses; settings as
   ``mocap-tracker eval``: xor distance, occlusion dynamics, body model chosen automatically, and the
   appearance cue when its network file exists, as ``mocap-tracker run`` does;
   ``--appearance off`` is the tracker without it, which is what this benchmark measured before.
   The game's scripts are in the default database and in the network's
   training data too, played by other synthetic people: the paper built its game database from
   the game's own motions),
4. fed to a fresh :class:`game_client.gestures.GestureRecognizer` with the tracker's joints,
   visibility and confidence (frames without a pose are skipped, as the game client would).

With ``--cache DIR`` the tracked (and true) joint sequences are stored in ``DIR`` (one ``.npz`` per
sequence, keyed by the script, speed, seed, lead-in, tracker settings, database, a hash of the
tracker's source and a hash of that script's source) and reused on later runs, so the recogniser can
be iterated on without re-tracking; without it every sequence is rendered and tracked afresh.

The same recogniser also runs on the scene's ground-truth joints (``truth``: the rendered person's
true pose), which separates tracker errors from what rendering on another body changes. Events are
matched to the scripts' labels as in ``bench/bench_game.py``; precision and recall per gesture.

Not a test: the tracker is slow (tens of ms per frame on one core) and still being improved.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

import tracker_service
from game_client.evaluation import Score, match_events
from game_client.gestures import GestureEvent, GestureRecognizer, RecognizerConfig
from game_client.variants import Label, Variant, load_labels, script_path, variant_labels, variant_motion
from protocol.motion import Motion
from protocol.skeleton import N_JOINTS, N_PARTS
from tracker_service.app.resources import ensure_appearance, ensure_db
from tracker_service.body.family import BODY_MODELS
from tracker_service.cues.appearance import AppearanceNet
from tracker_service.estimators.tree_filter.filter import FilterParams
from tracker_service.pipeline.process import TrackerConfig, new_state, process_frame
from tracker_service.scene.synthetic import SceneConfig, SyntheticScene
from tracker_service.templates.database import LoadedDatabase

#: Speeds of the variants, cycled (1.0 = as authored).
SPEEDS: tuple[float, ...] = (1.0, 0.8, 1.25)
EMPTY_PREFIX = 12
FPS = 30.0


def with_lead_in(m: Motion, seconds: float) -> Motion:
    """``m`` preceded by ``seconds`` of its first pose (poses ``(F + n, P)``)."""
    n = round(seconds * m.fps)
    poses = np.concatenate([np.repeat(m.poses[:1], n, axis=0), m.poses])
    return Motion(poses=poses, fps=m.fps, name=m.name, body=m.body, source=m.source)


def track_sequence(m: Motion, loaded: LoadedDatabase, cfg: TrackerConfig, seed: int) -> dict[str, Any]:
    """Render and track one motion; keep the tracked and the true joints of every frame with a person.

    Returns
    -------
    dict
        Arrays ``t`` (F,), ``joints`` (F, 24, 3) (NaN where the tracker gave no pose), ``has_pose``
        (F,), ``visibility`` (F, 15), ``confidence`` (F,), ``truth_joints`` (F, 24, 3),
        ``truth_visibility`` (F, 15); and ``meta``: the offset (s) of motion frame 0 in stream time,
        frames, tracked-frame fraction, root-relative MPJPE (cm), subject height, chosen body model
        and seconds taken.
    """
    scfg = SceneConfig(width=loaded.camera.width, height=loaded.camera.height, fps=FPS, empty_prefix=EMPTY_PREFIX)
    t0 = time.perf_counter()
    scene = SyntheticScene(m, seed=seed, config=scfg)
    ts: list[float] = []
    joints: list[NDArray[np.float64]] = []
    vis: list[NDArray[np.float64]] = []
    conf: list[float] = []
    tj: list[NDArray[np.float64]] = []
    tv: list[NDArray[np.float64]] = []
    try:
        state = new_state(loaded.body)
        tcfg = replace(cfg, background_frames=EMPTY_PREFIX)
        for i in range(scene.n_frames):
            fr = scene.frame(i)
            state, res = process_frame(state, fr.image, loaded.db, loaded.body, loaded.camera, tcfg, fr.timestamp)
            if not fr.truth.present:
                continue
            ts.append(fr.timestamp)
            tj.append(np.asarray(fr.truth.joints, dtype=np.float64))
            tv.append(np.asarray(fr.truth.visibility, dtype=np.float64))
            if res.joints is None:
                joints.append(np.full((N_JOINTS, 3), np.nan))
                vis.append(np.zeros(N_PARTS))
                conf.append(0.0)
            else:
                joints.append(np.asarray(res.joints, dtype=np.float64))
                vis.append(np.asarray(res.visibility, dtype=np.float64))
                conf.append(float(res.confidence))
        height = float(scene.subject.spec.height)
    finally:
        scene.close()
    j = np.asarray(joints).reshape(-1, N_JOINTS, 3)
    truth = np.asarray(tj).reshape(-1, N_JOINTS, 3)
    has = np.isfinite(j).all(axis=(1, 2))
    errs = np.linalg.norm((j - j[:, :1]) - (truth - truth[:, :1]), axis=2).mean(axis=1)[has]
    meta = {"offset_s": EMPTY_PREFIX / FPS, "frames": len(ts),
            "tracked_fraction": round(int(has.sum()) / max(len(ts), 1), 3),
            "mpjpe_cm": round(100 * float(errs.mean()), 1) if len(errs) else None,
            "subject_height_m": round(height, 3), "body": state.body.name,
            "seconds": round(time.perf_counter() - t0, 1)}
    return {"t": np.asarray(ts, dtype=np.float64), "joints": j, "has_pose": has,
            "visibility": np.asarray(vis).reshape(-1, N_PARTS), "confidence": np.asarray(conf),
            "truth_joints": truth, "truth_visibility": np.asarray(tv).reshape(-1, N_PARTS), "meta": meta}


def recognise_sequence(seq: dict[str, Any], config: RecognizerConfig | None = None
                       ) -> tuple[list[GestureEvent], list[GestureEvent]]:
    """Run fresh recognisers over a tracked sequence: on the tracked joints (frames without a pose
    skipped, as the game client would) and on the true joints. Returns ``(tracked, truth)`` events."""
    rec_tracked, rec_truth = GestureRecognizer(config), GestureRecognizer(config)
    tracked: list[GestureEvent] = []
    truth: list[GestureEvent] = []
    for k in range(len(seq["t"])):
        t = float(seq["t"][k])
        truth += rec_truth.update(t, seq["truth_joints"][k], seq["truth_visibility"][k])
        if seq["has_pose"][k]:
            tracked += rec_tracked.update(t, seq["joints"][k], seq["visibility"][k], float(seq["confidence"][k]))
    return tracked, truth


def _source_hash() -> str:
    """Hash of what a tracked sequence depends on besides its arguments: the tracker's and the
    scripts' source, as imported (in a git worktree whose venv's editable install points at another
    checkout, that checkout's tracker runs, so its source is what the key must name)."""
    root = Path(tracker_service.__file__).resolve().parent.parent
    h = hashlib.sha256()
    for p in sorted([*(root / "tracker_service").rglob("*.py"), root / "game_client" / "variants.py",
                     root / "protocol" / "motion.py"]):
        h.update(p.relative_to(root).as_posix().encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def _script_hash(name: str) -> str:
    """Hash of one script's source (part of its sequences' cache key, so adding or editing another
    script does not invalidate them)."""
    return hashlib.sha256(script_path(name).read_bytes()).hexdigest()[:16]


def _net_digest(net: AppearanceNet | None) -> str | None:
    """A short digest of the appearance network's weights (None without the cue): part of the
    cache key and of the report."""
    if net is None:
        return None
    h = hashlib.sha256()
    for layers in net.networks:
        for layer in layers:
            h.update(np.ascontiguousarray(layer.matrix).tobytes())
            h.update(np.ascontiguousarray(layer.bias).tobytes())
    return h.hexdigest()[:16]


def cached_track(cache: Path | None, key: dict[str, Any], m: Motion, loaded: LoadedDatabase, cfg: TrackerConfig,
                 seed: int) -> tuple[dict[str, Any], bool]:
    """:func:`track_sequence`, through the cache folder ``cache`` if given. Returns the sequence and
    whether it came from the cache."""
    if cache is None:
        return track_sequence(m, loaded, cfg, seed), False
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
    path = cache / f"{key['script']}_x{key['speed']:g}_s{seed}_{digest}.npz"
    if path.exists():
        with np.load(path) as z:
            seq: dict[str, Any] = {k: z[k] for k in z.files if k != "meta"}
            seq["meta"] = json.loads(str(z["meta"]))
        return seq, True
    seq = track_sequence(m, loaded, cfg, seed)
    cache.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, **{k: v for k, v in seq.items() if k != "meta"},
                        meta=np.asarray(json.dumps({**seq["meta"], "key": key})))
    tmp.replace(path)
    return seq, False


def _shift(labels: tuple[Label, ...], dt: float) -> list[Label]:
    return [Label(lb.gesture, lb.end_s + dt, lb.direction) for lb in labels]


def _fmt(score: Score) -> dict[str, dict[str, Any]]:
    return {g: {"precision": round(score.precision(g), 3), "recall": round(score.recall(g), 3),
                "tp": score.tp.get(g, 0), "fp": score.fp.get(g, 0), "fn": score.fn.get(g, 0)}
            for g in score.gestures()}


def _ev(events: list[GestureEvent]) -> list[list[Any]]:
    return [[e.gesture.value, round(e.t, 2)] + ([e.direction] if e.direction else []) for e in events]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--db", help="template database (default: the tracker's default, out/db/mMA, which "
                                 "includes the game's scripts; built on first use)")
    ap.add_argument("--scripts", help="comma-separated script names (default: every single-gesture script)")
    ap.add_argument("--rounds", action="store_true", help="also the whole-round scripts (one variant each)")
    ap.add_argument("--variants", type=int, default=3, help="variants per script: speeds 1, 0.8, 1.25 with "
                                                            "different scene seeds (default 3)")
    ap.add_argument("--lead-in", type=float, default=1.0, help="seconds of standing before each script (default 1)")
    ap.add_argument("--seed", type=int, default=0, help="first scene seed")
    ap.add_argument("--max-heading", type=float, default=35.0, metavar="DEG",
                    help="the tracker's game mode: the player faces the screen within DEG degrees (default 35, "
                         "as `mocap-tracker run --max-heading 35`; 0: any heading)")
    ap.add_argument("--pose", choices=("mean", "map"), default="mean",
                    help="the tracker's published pose, as `mocap-tracker run --pose` (default mean)")
    ap.add_argument("--appearance", metavar="PATH|off",
                    help="the appearance cue's network (default: the one shipped in the package, as "
                         "`mocap-tracker run`; off: the tracker without the cue)")
    ap.add_argument("--cache", metavar="DIR", help="reuse tracked sequences stored in DIR and store new ones there "
                                                   "(e.g. out/game_tracked_cache; default: track everything afresh)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args()

    loaded = ensure_db(args.db)
    cfg = TrackerConfig(distance="xor", occlusion=True, body_candidates=tuple(b.name for b in BODY_MODELS),
                        filter=FilterParams(max_heading=math.radians(args.max_heading) if args.max_heading else None),
                        use_mean_pose=args.pose == "mean", appearance=ensure_appearance(args.appearance, False))
    labels = load_labels()
    names = (args.scripts.split(",") if args.scripts
             else [n for n in labels if not n.startswith("round_")])
    jobs = [(n, Variant(speed=SPEEDS[k % len(SPEEDS)], fps=FPS), args.seed + k)
            for n in names for k in range(args.variants)]
    if args.rounds:
        jobs += [(n, Variant(fps=FPS), args.seed) for n in labels if n.startswith("round_")]

    cache = Path(args.cache) if args.cache else None
    base_key = {"lead_in": args.lead_in, "max_heading": args.max_heading, "pose": args.pose, "fps": FPS,
                "db": str(loaded.path), "templates": int(loaded.db.n_leaves),
                "source": _source_hash() if cache else None,
                "appearance": _net_digest(cfg.appearance)}
    score_tracked, score_truth = Score(), Score()
    rows = []
    reused = 0
    t_start = time.perf_counter()
    for k, (name, v, seed) in enumerate(jobs):
        m = with_lead_in(variant_motion(name, v), args.lead_in)
        key = {**base_key, "script": name, "script_source": _script_hash(name) if cache else None,
               "speed": v.speed, "seed": seed}
        seq, hit = cached_track(cache, key, m, loaded, cfg, seed)
        reused += hit
        tracked, truth = recognise_sequence(seq)
        out = {**seq["meta"], "tracked": tracked, "truth": truth}
        lbs = _shift(variant_labels(labels[name], v), out["offset_s"] + args.lead_in)
        mt, mg = match_events(out["tracked"], lbs), match_events(out["truth"], lbs)
        score_tracked.add(mt)
        score_truth.add(mg)
        row = {"script": name, "speed": v.speed, "seed": seed,
               "labels": [[lb.gesture, round(lb.end_s, 2)] for lb in lbs],
               "tracked_events": _ev(out["tracked"]), "truth_events": _ev(out["truth"]),
               "tracked_misses": [lb.gesture for lb in mt.misses], "tracked_false": _ev(list(mt.false_positives)),
               **{key: out[key] for key in ("frames", "tracked_fraction", "mpjpe_cm", "subject_height_m", "body",
                                           "seconds")}}
        rows.append(row)
        print(f"[{k + 1}/{len(jobs)}] {name} x{v.speed:g} seed {seed}: tracked {row['tracked_events']} "
              f"truth {row['truth_events']} (mpjpe {row['mpjpe_cm']} cm, {row['seconds']} s"
              f"{', cached' if hit else ''})", file=sys.stderr)
    res = {"machine": f"{platform.node()} {platform.processor() or platform.machine()}",
           "database": {"path": str(loaded.path), "templates": int(loaded.db.n_leaves),
                        "scripts": loaded.meta.get("scripts", []), "body": loaded.body.name},
           "tracker": {"distance": cfg.distance, "occlusion": cfg.occlusion, "body": "auto",
                       "max_heading_deg": args.max_heading or None, "skin": cfg.skin is not None,
                       "smoothing": cfg.smoothing is not None, "pose": args.pose,
                       "appearance": base_key["appearance"]},
           "lead_in_s": args.lead_in, "fps": FPS, "sequences": len(rows), "seeds": sorted({r["seed"] for r in rows}),
           "cache": str(cache) if cache else None, "reused_from_cache": reused,
           "tracked": _fmt(score_tracked), "truth": _fmt(score_truth),
           "tracked_latency_p50_ms": round(score_tracked.latency_percentile(50), 1),
           "tracked_latency_p95_ms": round(score_tracked.latency_percentile(95), 1),
           "mpjpe_cm_mean": round(float(np.mean([r["mpjpe_cm"] for r in rows if r["mpjpe_cm"] is not None])), 1),
           "seconds": round(time.perf_counter() - t_start, 1), "rows": rows}
    if args.json:
        print(json.dumps(res))
        return 0
    print(f"database {res['database']['path']} ({res['database']['templates']} templates, "
          f"{len(res['database']['scripts'])} scripts); {len(rows)} sequences, {res['seconds']} s")
    print("| gesture | tracked precision | tracked recall | TP | FP | FN | truth precision | truth recall |")
    print("|---|---|---|---|---|---|---|---|")
    for g in sorted(set(res["tracked"]) | set(res["truth"])):
        a, b = res["tracked"].get(g, {}), res["truth"].get(g, {})
        print(f"| {g} | {a.get('precision', 1.0):.3f} | {a.get('recall', 1.0):.3f} | {a.get('tp', 0)} | "
              f"{a.get('fp', 0)} | {a.get('fn', 0)} | {b.get('precision', 1.0):.3f} | {b.get('recall', 1.0):.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
