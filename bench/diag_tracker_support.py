"""Where the tracker's error is: the published pose against the filter's own support leaves.

For every tracking frame of held-out takes rendered as synthetic video, the published pose
(tempered posterior mean, smoothed), the MAP support leaf and the best of the 48 support leaves
(the "support oracle": the leaf nearest the truth) are compared with the ground truth, root-relative,
on the selected body's skeleton. A support oracle far below the published error says the likelihood
ranks the right leaf too low; a support oracle near it says the proposals miss the pose.

Usage::

    .venv/bin/python bench/diag_tracker_support.py [--seed S] [--takes N | --take-index I ...]
        [--frames N] [--true-height] [--json]

``--true-height`` gives the tracker the subject's true stature instead of the body selection's
choice (the templates' scale; the output skeleton stays the selected model's): an upper bound of
what a better height estimate can give (measured: -0.18 / +0.02 / -0.20 cm on subjects 11 / 7 / 3
over all 51 held-out takes). A diagnostic, not a test: it takes minutes. No forced losses
(the loop is :func:`tracker_service.app.evaluate.evaluate_motion`'s, with a per-frame hook).
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np
from tqdm import tqdm

from protocol import fk
from protocol.formats.load import load_motion
from protocol.formats.mocap_data import index_entries, mocap_root
from tracker_service.app.evaluate import EvalOptions, evaluate_motion
from tracker_service.app.resources import ensure_db
from tracker_service.body.family import BODY_MODELS
from tracker_service.build.database import is_held_out
from tracker_service.estimators.tree_filter.model import Estimate
from tracker_service.pipeline import body_selection as body_selection
from tracker_service.pipeline import process as pipeline
from tracker_service.pipeline.process import FrameResult, TrackerConfig, TrackerState
from tracker_service.scene.subject import random_subject_spec
from tracker_service.scene.synthetic import SceneFrame

LEGS = [16, 17, 18, 19, 20, 21, 22, 23]
ARMS = [7, 8, 9, 10, 12, 13, 14, 15]


def _root_relative(j: np.ndarray) -> np.ndarray:
    return j - j[..., :1, :]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=7, help="scene seed (the subject)")
    ap.add_argument("--takes", type=int, default=8, help="held-out takes spread over the list (51: all)")
    ap.add_argument("--take-index", type=int, nargs="*", help="explicit held-out take indices (0-50)")
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--true-height", action="store_true", help="templates scaled to the subject's true stature")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    loaded = ensure_db(None)
    db = loaded.db
    held = [e for i, e in enumerate(index_entries()) if is_held_out(i)]
    if args.take_index:
        if any(not 0 <= k < len(held) for k in args.take_index):
            raise SystemExit(f"--take-index: 0..{len(held) - 1}")
        pick = [held[k] for k in args.take_index]
    else:
        pick = [held[int(k)] for k in np.linspace(0, len(held) - 1, min(args.takes, len(held)))]

    # diagnostic hooks: keep the filter's last estimate; optionally force the body's size
    last: dict[str, Estimate] = {}
    step = pipeline.step

    def keep(*a: Any, **kw: Any) -> Any:
        st, est = step(*a, **kw)
        last["est"] = est
        return st, est

    pipeline.step = keep  # type: ignore[assignment]
    # the scene's subject is drawn from the seed alone (tracker_service.scene.synthetic.SyntheticScene)
    subject_height = random_subject_spec(np.random.default_rng([args.seed, 0])).height
    if args.true_height:
        choose = body_selection.BodyChoice.from_scores

        def forced(scores: Any, db_body: Any, stature: float = float("nan"), tolerance_m: float = 0.06) -> Any:
            c = choose(scores, db_body, stature, tolerance_m)
            return body_selection.BodyChoice(c.body, subject_height / db_body.height, c.mean_distance)

        body_selection.BodyChoice.from_scores = staticmethod(forced)  # type: ignore[method-assign]

    cfg = TrackerConfig(distance="xor", body_candidates=tuple(m.name for m in BODY_MODELS))
    opts = EvalOptions(frames=args.frames, seed=args.seed)
    rows = []
    for e in tqdm(pick, desc="held-out takes", disable=args.json):
        acc: dict[str, list[float]] = {k: [] for k in ("pub", "map", "best", "legs", "arms", "legs_best")}
        bodies: list[str] = []

        def observe(fr: SceneFrame, state: TrackerState, res: FrameResult, acc: dict[str, list[float]] = acc,
                    bodies: list[str] = bodies) -> None:
            if (not fr.truth.present or res.joints is None or res.phase != "tracking" or "est" not in last
                    or not len(state.filter.leaves)):  # no support right after a re-initialisation
                return
            truth = _root_relative(fr.truth.joints)
            ep = np.linalg.norm(_root_relative(res.joints) - truth, axis=1)
            poses = db.leaf_poses[state.filter.leaves].astype(np.float64)
            poses[:, :3] = 0.0
            sup = np.linalg.norm(_root_relative(fk(poses, state.body)) - truth, axis=2)  # (K, J)
            for k, v in (("pub", ep.mean()), ("legs", ep[LEGS].mean()), ("arms", ep[ARMS].mean()),
                         ("map", sup[0].mean()), ("best", sup.mean(axis=1).min()),
                         ("legs_best", sup[:, LEGS].mean(axis=1).min())):
                acc[k].append(float(v))
            bodies[:] = [state.body.name]
            last.clear()

        evaluate_motion(load_motion(mocap_root() / e.path, fps=30.0), loaded, cfg, opts, observe=observe)
        if acc["pub"]:
            pub, best = np.asarray(acc["pub"]), np.asarray(acc["best"])
            rows.append({"take": e.path, "frames": len(pub), "body": bodies[0],
                         "published_cm": 100 * float(pub.mean()), "map_cm": 100 * float(np.mean(acc["map"])),
                         "support_oracle_cm": 100 * float(best.mean()),
                         "within_10cm": float(np.mean(pub < 0.1)),
                         "support_oracle_within_10cm": float(np.mean(best < 0.1)),
                         "legs_cm": 100 * float(np.mean(acc["legs"])), "arms_cm": 100 * float(np.mean(acc["arms"])),
                         "legs_support_oracle_cm": 100 * float(np.mean(acc["legs_best"]))})
    keys = ("published_cm", "map_cm", "support_oracle_cm", "within_10cm", "support_oracle_within_10cm",
            "legs_cm", "arms_cm", "legs_support_oracle_cm")
    summary = {k: round(float(np.mean([r[k] for r in rows])), 3) for k in keys} if rows else {}
    out = {"seed": args.seed, "true_height": args.true_height, "takes": len(rows), "summary": summary,
           "per_take": [{k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.items()} for r in rows]}
    if args.json:
        print(json.dumps(out))
    else:
        for r in rows:
            print(f"{r['take'][-44:]:44s} {r['body']:4s} published {r['published_cm']:5.1f}  MAP {r['map_cm']:5.1f}  "
                  f"support oracle {r['support_oracle_cm']:5.1f}  within 10 cm {r['within_10cm']:.2f} / "
                  f"{r['support_oracle_within_10cm']:.2f}")
        print("mean", json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
