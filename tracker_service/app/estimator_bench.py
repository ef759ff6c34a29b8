"""The estimators compared on the very same rendered silhouettes (``mocap-tracker bench`` and
``bench/bench_estimators.py``): the tree filter (Okada & Stenger), Condensation (Isard & Blake), the
cardbox paper's hierarchical particle filter with deterministic (DRS) and stratified (SRS)
resampling, and ELMO (Demirdjian et al.; its hash index is built before the clip, not timed).
``elmo-lite`` (ELMO on a third of the evaluations) can be named too.

The tree filter searches a small database (the four takes of the test suite's fixture, body mMA,
built here in a few seconds); by default the clip is the first of them (the both-hands raise, so
*in* the tree filter's database: the tree's best case). ``take`` picks another recording of the
index by file name, ``bvh`` any BVH files (each a clip; every estimator starts each clip from a
fresh state). Each frame is the subject's capsule silhouette, pre-processed once (nwXOR, as the
pipeline) and handed to every estimator. Each estimator runs two frames first (numba compilation),
then the clips, numpy on one thread. DRS and SRS run ``repeats`` times with seeds ``seed``,
``seed + 1``, ...; the table gives their first run (seed ``seed``), as for the other estimators.

Writes ``table.md``, ``table.json`` and three PNG plots (matplotlib, Agg) into the output folder:
``error_per_frame.png`` (MPJPE against frame number per estimator, ELMO's Fig. 5),
``error_per_joint.png`` (mean ± std error per joint, its Fig. 4) and ``joint_angle_spread.png`` (one
joint's bend angle per frame over the repeated DRS and SRS runs, the cardbox paper's Fig. 9) and
``cost_per_frame.png`` (the estimate's silhouette cost per frame over those runs, its Fig. 8); the
last two only when ``drs`` or ``srs`` runs. The table gives each repeated estimator's spread: the
joint angle's standard deviation over the seeds, averaged over the frames.

This module imports only the standard library at module level (the command line imports it).
"""

from __future__ import annotations

import json
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tracker_service.app.host_probe import host_probe

__all__ = ["ESTIMATOR_NAMES", "PLOTS", "TAKES", "BenchOptions", "host_probe", "main_options", "markdown_table",
           "run_bench", "write_outputs"]

#: The estimators a benchmark can name (``make_estimator``'s and ``elmo-lite``).
ESTIMATOR_NAMES = ("tree", "tree-elmo", "condensation", "drs", "srs", "elmo", "elmo-lite", "drs-cardbox", "srs-cardbox")
#: The takes of the small database (the test suite's ``small_db``); the first is the default clip.
TAKES = ("dataset-2_raise-up-both-hands_normal_001.bvh", "dataset-2_raise-up-both-hands_active_062.bvh",
         "dataset-2_raise-up-right-hand_normal_001.bvh", "dataset-1_bye_normal_001.bvh")
#: The plots written, by file name.
PLOTS = ("error_per_frame.png", "error_per_joint.png", "joint_angle_spread.png", "cost_per_frame.png")
_REPEATED = ("drs", "srs")


@dataclass(frozen=True)
class BenchOptions:
    """What ``mocap-tracker bench`` runs.

    Attributes
    ----------
    estimators : tuple of str
        Names from :data:`ESTIMATOR_NAMES`, in table order.
    out : str
        Output folder (``table.md``, ``table.json``, the PNGs).
    bvh : tuple of str
        BVH files, one clip each (default: ``take`` or the database's first take).
    take : str, optional
        A recording of the index, by file name.
    frames, step : int
        Frames evaluated per clip, taking every ``step``-th frame of the 30 Hz motion.
    subject : str
        Body model rendered (the database's is mMA).
    seed : int
        The stochastic estimators' seed (repeat ``r`` of DRS/SRS uses ``seed + r``).
    repeats : int
        Runs of DRS and SRS (the joint-angle spread plot).
    joint : str
        The joint whose bend angle the spread plot shows.
    plots : bool
        Write the PNGs.
    """

    estimators: tuple[str, ...] = ("tree", "condensation", "drs", "srs", "elmo")
    out: str = "out/bench_estimators"
    bvh: tuple[str, ...] = field(default_factory=tuple)
    take: str | None = None
    frames: int = 60
    step: int = 2
    subject: str = "mMA"
    seed: int = 0
    repeats: int = 3
    joint: str = "r_elbow"
    plots: bool = True


def _clips(options: BenchOptions, body: Any, motions: list[Any]) -> list[tuple[str, Any]]:
    import numpy as np

    from protocol.formats.load import load_motion
    from protocol.formats.mocap_data import index_entries
    from tracker_service.build.database import heading_of, set_heading, training_motions

    raw: list[tuple[str, Any]] = []
    if options.bvh:
        raw = [(str(p), load_motion(p, body=body, fps=30.0).poses) for p in options.bvh]
    elif options.take:
        entries = [e for e in index_entries() if e.path.split("/")[-1] == options.take]
        if not entries:
            raise ValueError(f"no recording {options.take!r} in the index")
        raw = [(options.take, training_motions(body, entries)[0].poses)]
    else:
        raw = [(TAKES[0] + " (in the tree's database)", motions[0].poses)]
    out = []
    for name, p in raw:
        poses = np.asarray(p, np.float64)[: options.frames * options.step: options.step].copy()
        if len(poses) == 0:
            raise ValueError(f"{name}: no frames")
        out.append((name, set_heading(poses, heading_of(poses) - heading_of(poses[:1])[0])))
    return out


def _bend_deg(joints: Any, j: int) -> Any:
    """Bend angle (degrees, 0 = straight) at joint ``j`` of ``(..., J, 3)`` positions."""
    import numpy as np

    from protocol.skeleton import PARENTS

    child = PARENTS.index(j)
    a = joints[..., j, :] - joints[..., PARENTS[j], :]
    b = joints[..., child, :] - joints[..., j, :]
    cos = (a * b).sum(-1) / np.maximum(np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1), 1e-12)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _run(est: Any, clips: list[list[Any]], truths: list[Any], cam: Any, body: Any, joint: int) -> dict[str, Any]:
    import numpy as np

    from protocol import fk
    from tracker_service.estimators.particles import world_pose

    st = est.init()
    for obs in clips[0][:2]:  # compile
        st, _ = est.step(st, obs)
    ms: list[float] = []
    err_mean: list[Any] = []
    err_map: list[float] = []
    evals: list[int] = []
    angles: list[float] = []
    cost: list[float] = []
    for observations, truth in zip(clips, truths, strict=True):
        st = est.init()
        for obs, tj in zip(observations, truth, strict=True):
            t0 = time.perf_counter()
            st, e = est.step(st, obs)
            ms.append(1000.0 * (time.perf_counter() - t0))
            evals.append(sum(e.evaluations))
            cost.append(float(e.distance))
            for mean in (True, False):
                j = fk(world_pose(e, cam, mean=mean), body)
                per_joint = np.linalg.norm((j - j[0]) - (tj - tj[0]), axis=1)
                if mean:
                    err_mean.append(per_joint)
                    angles.append(float(_bend_deg(j, joint)))
                else:
                    err_map.append(float(per_joint.mean()))
    pj = np.asarray(err_mean)  # (frames, J), metres
    em = pj.mean(axis=1)
    return {"mpjpe_cm": 100 * float(em.mean()), "mpjpe_map_cm": 100 * float(np.mean(err_map)),
            "within_10cm": float(np.mean(em < 0.10)), "ms_min": float(np.min(ms)), "ms_avg": float(np.mean(ms)),
            "ms_max": float(np.max(ms)), "evals_per_frame": float(np.mean(evals)),
            "per_frame_cm": [round(100 * float(v), 2) for v in em],
            "per_joint_mean_cm": [round(100 * float(v), 2) for v in pj.mean(axis=0)],
            "per_joint_std_cm": [round(100 * float(v), 2) for v in pj.std(axis=0)],
            "joint_angle_deg": [round(v, 2) for v in angles], "cost_per_frame": [round(v, 5) for v in cost]}


def _recovery(est: Any, clips: list[list[Any]], truths: list[Any], cam: Any, body: Any) -> dict[str, Any]:
    """A forced loss in the middle of every clip (the estimator started afresh, as on a lost track):
    frames until its error is back within ``max(10 cm, 1.25 x its error before the loss)``."""
    import numpy as np

    from protocol import fk
    from tracker_service.estimators.particles import world_pose

    frames: list[int] = []
    lost = 0
    for observations, truth in zip(clips, truths, strict=True):
        st = est.init()
        k_loss = len(observations) // 2
        before: list[float] = []
        back: int | None = None
        for k, (obs, tj) in enumerate(zip(observations, truth, strict=True)):
            if k == k_loss:
                st = est.init()
            st, e = est.step(st, obs)
            j = fk(world_pose(e, cam, mean=True), body)
            err = float(np.linalg.norm((j - j[0]) - (tj - tj[0]), axis=1).mean())
            if k < k_loss:
                before.append(err)
            elif back is None and err <= max(0.10, 1.25 * float(np.mean(before or [0.0]))):
                back = k - k_loss + 1
        if back is None:
            lost += 1
        else:
            frames.append(back)
    return {"recovery_frames_avg": float(np.mean(frames)) if frames else None,
            "recovery_frames_max": int(max(frames)) if frames else None, "recovered": len(frames),
            "losses": len(frames) + lost}


def run_bench(options: BenchOptions, progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Build the small database, render the clips, run every estimator; the ``table.json`` object
    (``meta``, ``results`` per estimator, ``repeats`` of DRS/SRS)."""
    import numpy as np
    from threadpoolctl import threadpool_limits

    from protocol import fk
    from protocol.formats.mocap_data import index_entries
    from protocol.skeleton import JOINT_INDEX, JOINT_NAMES, PARENTS
    from tracker_service.body.family import body_model
    from tracker_service.body.raster import render_silhouette
    from tracker_service.build.database import DbBuildConfig, build_filter_db, training_motions
    from tracker_service.camera import default_camera
    from tracker_service.estimators import make_estimator
    from tracker_service.estimators.base import Observation
    from tracker_service.estimators.tree_filter.filter import FilterParams
    from tracker_service.silhouette.features import preprocess
    from tracker_service.silhouette.placement import observed_placement

    bad = [k for k in options.estimators if k not in ESTIMATOR_NAMES]
    if bad or not options.estimators:
        raise ValueError(f"unknown estimator(s) {bad}; choose from {', '.join(ESTIMATOR_NAMES)}")
    joint = JOINT_INDEX.get(options.joint, -1)
    if joint <= 0 or joint not in PARENTS:
        raise ValueError(f"--joint {options.joint!r}: name a joint with a parent and a child")
    say = progress or (lambda _msg: None)
    cam = default_camera()
    db_body = body_model("mMA").body
    say("building the small database")
    motions = training_motions(db_body, [e for e in index_entries() if e.path.split("/")[-1] in TAKES])
    if not motions:
        raise ValueError("the database's takes are not in the recordings index (../shared/mocap or $MOCAP_DATA)")
    cfg = DbBuildConfig(yaw_offsets_deg=(0.0,), level_thresholds=(0.02, 0.008, 0.004))
    db, _ = build_filter_db(motions, db_body, cam, cfg, rng=np.random.default_rng(1))
    subject = body_model(options.subject).body
    clips = _clips(options, subject, motions)
    truths = [fk(poses, subject) for _, poses in clips]
    observations = []
    for truth in truths:
        obs = []
        for tj in truth:
            mask = render_silhouette(tj, subject.capsule_radii, cam)
            obs.append(Observation(preprocess(mask), observed_placement(mask, cam)))
        observations.append(obs)

    def make(key: str, seed: int) -> Any:
        if key == "elmo-lite":  # ELMO on a smaller budget: 20 hypotheses, 2 refined, 2 rounds, 1 mode
            from tracker_service.estimators.elmo import Elmo, ElmoParams

            return Elmo(db, db_body, cam, ElmoParams(n_hypotheses=20, n_refine=2, iterations=2, max_modes=1),
                        np.random.default_rng(seed))
        return make_estimator(key, db, db_body, cam, FilterParams(), seed=seed)

    results: dict[str, dict[str, Any]] = {}
    repeats: dict[str, list[dict[str, Any]]] = {}
    with threadpool_limits(1):
        for key in options.estimators:
            say(f"running {key}")
            results[key] = _run(make(key, options.seed), observations, truths, cam, db_body, joint)
            say(f"running {key} with a forced loss in every clip")
            results[key] |= _recovery(make(key, options.seed), observations, truths, cam, db_body)
            if key in _REPEATED:
                runs = [results[key]]
                for r in range(1, options.repeats):
                    say(f"running {key}, seed {options.seed + r}")
                    runs.append(_run(make(key, options.seed + r), observations, truths, cam, db_body, joint))
                repeats[key] = [{"seed": options.seed + i, "mpjpe_cm": x["mpjpe_cm"],
                                 "joint_angle_deg": x["joint_angle_deg"], "cost_per_frame": x["cost_per_frame"]}
                                for i, x in enumerate(runs)]
    ref = results.get("tree")
    for res in results.values():
        res["time_vs_tree"] = res["ms_avg"] / ref["ms_avg"] if ref else None
        res["error_vs_tree"] = res["mpjpe_cm"] / ref["mpjpe_cm"] if ref else None
    truth_angle = np.concatenate([_bend_deg(t, joint) for t in truths])
    meta = {"clips": [name for name, _ in clips], "clip_frames": [len(p) for _, p in clips],
            "frames": sum(len(p) for _, p in clips), "step": options.step, "subject": options.subject,
            "seed": options.seed, "repeats": options.repeats, "joint": options.joint,
            "joint_names": list(JOINT_NAMES), "truth_joint_angle_deg": [round(float(v), 2) for v in truth_angle],
            "host_probe_s": host_probe(), "python": platform.python_version(), "machine": platform.machine()}
    return {"meta": meta, "results": results, "repeats": repeats}


def markdown_table(report: dict[str, Any]) -> str:
    """The Markdown table of a :func:`run_bench` report (a line on the clip first)."""
    m = report["meta"]
    has_ref = "tree" in report["results"]
    lines = [f"clip: {', '.join(m['clips'])}; {m['frames']} frames (every {m['step']}), subject {m['subject']}, "
             f"seed {m['seed']}", "",
             "| estimator | MPJPE mean (cm) | MPJPE MAP (cm) | frames < 10 cm | ms/frame min / avg / max "
             "| evaluations / frame | back after a forced loss (frames, avg / max) | time / tree | error / tree |",
             "|---|---|---|---|---|---|---|---|---|"]
    for key, r in report["results"].items():
        ratio = (f"{r['time_vs_tree']:.2f}", f"{r['error_vs_tree']:.2f}") if has_ref else ("—", "—")
        rec = ("—" if "losses" not in r else f"{r['recovered']}/{r['losses']} back"
               + (f", {r['recovery_frames_avg']:.1f} / {r['recovery_frames_max']}" if r["recovered"] else ""))
        lines.append(f"| {key} | {r['mpjpe_cm']:.1f} | {r['mpjpe_map_cm']:.1f} | {100 * r['within_10cm']:.0f} % "
                     f"| {r['ms_min']:.1f} / {r['ms_avg']:.1f} / {r['ms_max']:.1f} | {r['evals_per_frame']:.0f} "
                     f"| {rec} | {ratio[0]} | {ratio[1]} |")
    spread = [(key, runs) for key, runs in report.get("repeats", {}).items() if len(runs) > 1]
    lines += [""] if spread else []
    for key, runs in spread:
        errs = [x["mpjpe_cm"] for x in runs]
        lines.append(f"- {key} over {len(errs)} seeds: MPJPE {min(errs):.1f} … {max(errs):.1f} cm "
                     f"(mean {sum(errs) / len(errs):.1f}); {m['joint']} angle's spread over the seeds "
                     f"{spread_per_frame(runs, 'joint_angle_deg'):.1f}° (std per frame, averaged); 2D cost "
                     f"{cost_mean(runs):.4f}, its spread {spread_per_frame(runs, 'cost_per_frame'):.4f}")
    return "\n".join(lines) + "\n"


def spread_per_frame(runs: Sequence[dict[str, Any]], key: str = "joint_angle_deg") -> float:
    """Run-to-run spread of repeated runs: the standard deviation of the per-frame series ``key``
    (``joint_angle_deg``, degrees, or ``cost_per_frame``) over the runs at each frame, averaged over
    the frames."""
    import numpy as np

    return float(np.asarray([x[key] for x in runs]).std(axis=0).mean())


def cost_mean(runs: Sequence[dict[str, Any]]) -> float:
    """The estimates' silhouette cost averaged over the frames and the repeated runs."""
    import numpy as np

    return float(np.mean([x["cost_per_frame"] for x in runs]))


def _plots(report: dict[str, Any], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    m, results = report["meta"], report["results"]
    written = []
    bounds = np.cumsum(m["clip_frames"])[:-1]

    fig, ax = plt.subplots(figsize=(8, 4))
    for key, r in results.items():
        ax.plot(np.arange(len(r["per_frame_cm"])), r["per_frame_cm"], label=key, lw=1.2)
    ax.set(xlabel="frame", ylabel="mean joint error (cm)", title="Error per frame (cf. ELMO Fig. 5)")
    written.append(_finish(plt, fig, ax, bounds, out / PLOTS[0]))

    names = m["joint_names"][1:]  # the root is the reference: no error
    x = np.arange(len(names))
    w = 0.8 / max(len(results), 1)
    fig, ax = plt.subplots(figsize=(11, 4))
    for i, (key, r) in enumerate(results.items()):
        ax.bar(x + (i - (len(results) - 1) / 2) * w, r["per_joint_mean_cm"][1:], w, yerr=r["per_joint_std_cm"][1:],
               label=key, capsize=1.5, error_kw={"lw": 0.6})
    ax.set_xticks(x, names, rotation=60, ha="right", fontsize=8)
    ax.set(ylabel="error (cm), mean ± std", title="Error per joint (cf. ELMO Fig. 4)")
    ax.grid(axis="y", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    written.append(out / PLOTS[1])
    fig.savefig(written[-1], dpi=100)
    plt.close(fig)

    reps = report.get("repeats", {})
    if reps:
        fig, ax = plt.subplots(figsize=(8, 4))
        truth = m["truth_joint_angle_deg"]
        ax.plot(np.arange(len(truth)), truth, color="k", lw=1.5, label="truth")
        for key, color in (("drs", "tab:blue"), ("srs", "tab:red")):
            if key not in reps:
                continue
            a = np.asarray([x["joint_angle_deg"] for x in reps[key]])
            f = np.arange(a.shape[1])
            ax.fill_between(f, a.min(0), a.max(0), color=color, alpha=0.2)
            for i, row in enumerate(a):
                ax.plot(f, row, color=color, lw=0.7, alpha=0.7,
                        label=f"{key} ({len(a)} seeds, min–max shaded)" if i == 0 else None)
        ax.set(xlabel="frame", ylabel=f"{m['joint']} bend (degrees)",
               title="Spread over seeds, DRS vs SRS (cf. cardbox paper Fig. 9)")
        written.append(_finish(plt, fig, ax, bounds, out / PLOTS[2]))

        fig, ax = plt.subplots(figsize=(8, 4))
        for key, color in (("drs", "tab:blue"), ("srs", "tab:red")):
            if key not in reps or "cost_per_frame" not in reps[key][0]:
                continue
            c = np.asarray([x["cost_per_frame"] for x in reps[key]])
            f = np.arange(c.shape[1])
            ax.fill_between(f, c.min(0), c.max(0), color=color, alpha=0.2)
            ax.plot(f, c.mean(0), color=color, lw=1.2, label=f"{key}, mean of {len(c)} seeds (min–max shaded)")
        ax.set(xlabel="frame", ylabel="silhouette cost of the estimate",
               title="2D cost per frame, DRS vs SRS (cf. cardbox paper Fig. 8)")
        written.append(_finish(plt, fig, ax, bounds, out / PLOTS[3]))
    return written


def _finish(plt: Any, fig: Any, ax: Any, bounds: Any, path: Path) -> Path:
    """A per-frame plot finished: the clips' bounds dashed, grid, legend, saved to ``path``, closed."""
    for b in bounds:
        ax.axvline(b - 0.5, color="0.6", ls="--", lw=0.8)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def write_outputs(report: dict[str, Any], out: str | Path, plots: bool = True) -> list[Path]:
    """Write ``table.md``, ``table.json`` and (``plots``) the PNGs into ``out``; the paths written."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "table.md").write_text(markdown_table(report))
    (folder / "table.json").write_text(json.dumps(report, indent=1))
    written = [folder / "table.md", folder / "table.json"]
    if plots:
        written += _plots(report, folder)
    return written


def main_options(options: BenchOptions, progress: Callable[[str], None] | None = None) -> tuple[str, Sequence[Path]]:
    """Run and write; the Markdown table and the paths written."""
    report = run_bench(options, progress)
    return markdown_table(report), write_outputs(report, options.out, options.plots)
