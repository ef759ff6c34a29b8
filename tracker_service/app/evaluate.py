"""Evaluation from pixels: render the synthetic scene for a motion (a subject unlike the database's
body models), run the whole tracker pipeline on its frames and compare with the ground truth.

The result is the JSON contract every benchmark uses (``mocap-tracker eval --json``): accuracy
(root-relative MPJPE, root error, 2D error, fraction of frames within 10 cm), re-acquisition time
after forced losses, speed per stage (the paper's Table 1) and distance evaluations per level
(Table 2).
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from protocol.motion import Motion
from tracker_service.body.measured import given_body
from tracker_service.estimators.tree_filter.filter import initial_state
from tracker_service.pipeline.process import FrameResult, TrackerConfig, TrackerState, new_state, process_frame
from tracker_service.scene.subject import SubjectSpec
from tracker_service.scene.synthetic import SceneConfig, SceneFrame, SyntheticScene
from tracker_service.templates.database import LoadedDatabase

__all__ = ["EvalOptions", "acceleration_error", "evaluate_motion", "reacquisition_times", "subject_measurements"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EvalOptions:
    """Options of :func:`evaluate_motion`.

    Attributes
    ----------
    frames : int, optional
        Evaluate at most this many motion frames.
    seed : int
        Scene seed (subject, room, lighting, noise).
    empty_prefix : int
        Empty-room frames for background learning.
    force_loss_every_s : float
        Force a tracking loss (the filter is reset to a wrong pose) every this many seconds of
        tracking (0: never); re-acquisition time is measured after each: the time until three
        frames in a row are back within 10 cm (or within 1.25 x the median error of the second
        before the loss, where the track was worse than 10 cm). A loss not yet back in the clip's
        last second is not judged.
    fps : float
        Frame rate of the rendered video.
    in_place_travel_m : float
        Motions whose root travels farther than this are played on the spot (a treadmill), so
        the person stays in view.
    subject_measurements : tuple of str
        Give the tracker these of the scene person's own measurements (keys of
        :func:`subject_measurements`: ``height``, ``group``, girths, ``shoulder``, ``arm``, ``leg``)
        instead of letting it choose a body model: what a user who enters them gets. Empty: the
        tracker's own choice.
    """

    frames: int | None = None
    seed: int = 0
    empty_prefix: int = 12
    force_loss_every_s: float = 0.0
    fps: float = 30.0
    in_place_travel_m: float = 2.0
    subject_measurements: tuple[str, ...] = ()


def subject_measurements(spec: SubjectSpec) -> dict[str, Any]:
    """The synthetic person's measurements in the form of :func:`~tracker_service.body.measured.parse_measurements`."""
    return {"height": spec.height, "group": spec.group, "chest": spec.chest, "waist": spec.waist, "hip": spec.hip,
            "shoulder": spec.shoulder_frac * spec.height, "arm": spec.arm_ratio, "leg": spec.leg_ratio}


def _stats(v: list[float]) -> dict[str, float]:
    a = np.asarray(v, dtype=np.float64)
    if a.size == 0:
        return {"min": float("nan"), "avg": float("nan"), "max": float("nan")}
    return {"min": round(float(a.min()), 3), "avg": round(float(a.mean()), 3), "max": round(float(a.max()), 3)}


def acceleration_error(frame: NDArray[np.int64], est: NDArray[np.float64], true: NDArray[np.float64]) -> float:
    """Mean joint acceleration error (metres per frame squared): the jitter of the published pose.

    Over every three consecutive frames ``i - 1, i, i + 1`` that were all tracked steadily (the
    caller leaves out initialisation, forced losses until the track is back, re-initialisations and
    the frame a new skeleton is published, whose jumps are not jitter), the second
    difference of the estimated root-relative joints minus that of the true ones, its norm averaged
    over the joints and the triples (the "Accel" error of temporal human-pose papers). A pose that
    trembles from frame to frame scores high even when its mean error is low.

    Parameters
    ----------
    frame : (F,) int64
        Frame number of each tracked frame (increasing).
    est, true : (F, J, 3) float64
        Root-relative joints.

    Returns
    -------
    float
        NaN when no three consecutive frames were tracked.
    """
    frame = np.asarray(frame)
    if len(frame) < 3:
        return float("nan")
    ok = (frame[2:] - frame[:-2]) == 2
    if not ok.any():
        return float("nan")
    d = np.asarray(est, np.float64) - np.asarray(true, np.float64)
    acc = d[2:] - 2.0 * d[1:-1] + d[:-2]
    return float(np.linalg.norm(acc[ok], axis=-1).mean())


def reacquisition_times(t: NDArray[np.float64], err: NDArray[np.float64], losses: list[int], fps: float,
                        within_m: float = 0.10, relative: float = 1.25, run: int = 3,
                        min_left_s: float = 1.0) -> list[float]:
    """Time (s) from each forced loss until the track is back.

    Back means ``run`` frames in a row within ``within_m`` of the truth, or, where the track was
    worse than that in the second before the loss, within ``relative`` x its median error then
    (a take the tracker follows at 12 cm is back at 15 cm, not never). The time counts from the
    loss to the first frame of the run. A loss not yet back with less than ``min_left_s`` of the
    clip after it is not judged; one never back is ``inf``.

    Parameters
    ----------
    t : (F,) float64
        Timestamps of the evaluated frames.
    err : (F,) float64
        Root-relative mean joint error of each (metres).
    losses : list of int
        Index (into ``t``) of the frame at which each loss was forced.
    fps : float

    Returns
    -------
    list of float
    """
    out: list[float] = []
    n_before = max(round(fps), 1)
    for k in losses:
        before = err[max(k - n_before, 0): k]
        thr = max(within_m, relative * float(np.median(before))) if len(before) else within_m
        ok = err[k + 1:] < thr
        streak, found = 0, float("inf")
        for j, good in enumerate(ok):
            streak = streak + 1 if good else 0
            if streak >= run:
                found = float(t[k + 1 + j - run + 1] - t[k])
                break
        if np.isfinite(found) or t[-1] - t[k] >= min_left_s:  # not back, too little clip left: unjudged
            out.append(found)
    return out


def evaluate_motion(motion: Motion, loaded: LoadedDatabase, config: TrackerConfig, options: EvalOptions,
                    progress: Callable[[int, int], None] | None = None,
                    observe: Callable[[SceneFrame, TrackerState, FrameResult], None] | None = None) -> dict[str, Any]:
    """Track a motion rendered as synthetic video and measure the errors.

    Parameters
    ----------
    motion : Motion
    loaded : LoadedDatabase
    config : TrackerConfig
    options : EvalOptions
    progress : callable(done, total), optional
    observe : callable(frame, state, result), optional
        Called after every processed frame with the rendered frame (image and ground truth), the
        tracker's new state and its result (for diagnostics: ``bench/diag_tracker_support.py``).

    Returns
    -------
    dict
        The ``mocap-tracker eval`` JSON object.
    """
    travel = np.ptp(motion.poses[:, [0, 2]], axis=0).max() if motion.n_frames else 0.0
    scfg = SceneConfig(width=loaded.camera.width, height=loaded.camera.height, fps=options.fps,
                       empty_prefix=options.empty_prefix, in_place=bool(travel > options.in_place_travel_m))
    scene = SyntheticScene(motion, seed=options.seed, config=scfg)
    try:
        n = scene.n_frames if options.frames is None else min(scene.n_frames, options.empty_prefix + options.frames)
        cfg = replace(config, background_frames=options.empty_prefix)
        if options.subject_measurements:
            known = subject_measurements(scene.subject.spec)
            if unknown := set(options.subject_measurements) - set(known):
                raise ValueError(f"unknown measurement(s) {sorted(unknown)}; choose from {', '.join(known)}")
            given = {k: known[k] for k in ("height", *options.subject_measurements)}
            cfg = replace(cfg, body_candidates=(), body=given_body(given))
        state: TrackerState = new_state(loaded.body)
        errs, root_errs, errs2d, tracked = [], [], [], 0
        acc_i: list[int] = []  # frame number, estimated and true root-relative joints of steady frames
        acc_e: list[NDArray[np.float64]] = []
        acc_t: list[NDArray[np.float64]] = []
        present = 0
        digest = hashlib.sha256()  # the published pose stream, for regression checks
        t_pre, t_est, t_tot = [], [], []
        init_ms = 0.0
        evals: list[tuple[int, ...]] = []
        lost_at: float | None = None
        err_t: list[float] = []  # timestamps of the evaluated frames (errs)
        losses: list[int] = []  # index into errs of each forced loss
        next_loss = options.force_loss_every_s
        track_time = 0.0
        streak = 0
        for i in range(n):
            fr = scene.frame(i)
            was_tracking = state.phase == "tracking"  # the frame that ends initialisation scores the bodies
            state, res = process_frame(state, fr.image, loaded.db, loaded.body, loaded.camera, cfg, fr.timestamp)
            if observe is not None:
                observe(fr, state, res)
            if not fr.truth.present:
                continue
            present += 1
            if res.joints is None:
                continue
            tracked += 1
            jt, je = fr.truth.joints, res.joints
            digest.update(np.ascontiguousarray(je, dtype=np.float64).tobytes())
            e = float(np.linalg.norm((je - je[0]) - (jt - jt[0]), axis=1).mean())
            errs.append(e)
            if (was_tracking and res.phase == "tracking" and lost_at is None and not res.reinitialised
                    and not res.body_changed):  # jitter of steady tracking: no loss, recovery or new skeleton
                acc_i.append(i)
                acc_e.append(je - je[0])
                acc_t.append(jt - jt[0])
            root_errs.append(float(np.linalg.norm(je[0] - jt[0])))
            errs2d.append(float(np.linalg.norm(loaded.camera.project(je) - fr.truth.joints_2d, axis=1).mean()))
            if was_tracking and res.phase == "tracking":  # steady state; initialisation (body selection) apart
                t_pre.append(res.stage_ms.get("preprocess", 0.0) + res.stage_ms.get("background", 0.0))
                t_est.append(res.stage_ms.get("estimate", 0.0))
                t_tot.append(res.stage_ms.get("total", 0.0))
                evals.append(res.evaluations)
            else:
                init_ms += res.stage_ms.get("total", 0.0)
            t = fr.timestamp
            err_t.append(t)
            if lost_at is not None:
                streak = streak + 1 if e < 0.10 else 0
                if streak >= 3:  # the next loss waits for the track to be back within 10 cm
                    lost_at = None  # (the time is measured afterwards by reacquisition_times)
            elif res.phase == "tracking":
                track_time += 1.0 / options.fps
                if options.force_loss_every_s > 0 and track_time >= next_loss:
                    # forced loss: forget the pose, start from the wrong side of the body
                    wrong = initial_state(state.filter.placement)
                    state = replace(state, filter=wrong)
                    lost_at, streak = t, 0
                    losses.append(len(errs) - 1)
                    next_loss += options.force_loss_every_s
            if progress is not None:
                progress(i + 1, n)
    finally:
        scene.close()
    e_arr = np.asarray(errs)
    reacq = reacquisition_times(np.asarray(err_t), e_arr, losses, options.fps)
    lvl = np.asarray(evals, dtype=np.float64) if evals else np.zeros((0, 3))
    total_ms = float(np.mean(t_tot)) if t_tot else float("nan")
    accel = acceleration_error(np.asarray(acc_i, np.int64), np.asarray(acc_e), np.asarray(acc_t))
    return {
        "motion": motion.name,
        "frames": int(present),
        "tracked_frames": int(tracked),
        "mpjpe_cm": round(float(e_arr.mean() * 100), 2) if len(e_arr) else None,
        "root_error_cm": round(float(np.mean(root_errs) * 100), 2) if root_errs else None,
        "mpjpe_2d_px": round(float(np.mean(errs2d)), 2) if errs2d else None,
        "frames_within_10cm": round(float(np.mean(e_arr < 0.10)), 3) if len(e_arr) else 0.0,
        "accel_error_cm": round(accel * 100, 3) if np.isfinite(accel) else None,
        "reacquire_s_max": (None if not reacq else (round(max(reacq), 3) if np.isfinite(max(reacq)) else None)),
        "forced_losses": len(reacq),
        "reacquired": int(np.sum(np.isfinite(reacq))),
        "fps": round(1000.0 / total_ms, 1) if t_tot else None,
        "ms_per_frame": {"preprocess": _stats(t_pre), "estimate": _stats(t_est), "total": _stats(t_tot)},
        "initialisation_ms": round(init_ms, 1),
        "steady_frames": len(t_tot),
        "distance_evals_per_level": [round(float(x), 1) for x in lvl.mean(axis=0)] if len(lvl) else [],
        "templates": int(loaded.db.n_leaves),
        "tree_levels": [int(s) for s in loaded.db.tree.level_sizes],
        "estimator": "tree",
        "appearance_cue": bool(config.appearance is not None and config.filter.appearance_weight > 0),
        "distance": config.distance,
        "occlusion_dynamics": config.occlusion,
        "body_selected": state.body.name,
        "database_body": loaded.body.name,
        "subject_height_m": round(float(scene.subject.spec.height), 3),
        "reinitialisations": int(state.reinits),
        "poses_sha256": digest.hexdigest(),
    }
