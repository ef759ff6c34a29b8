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
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from protocol.motion import Motion
from protocol.skeleton import N_JOINTS
from tracker_service.app.error_metrics import (
    acceleration_error,
    confidence_error_spearman,
    joint_jumps,
    reacquisition_times,
)
from tracker_service.app.options import EvalOptions
from tracker_service.body.measured import given_body
from tracker_service.camera import Camera
from tracker_service.pipeline.process import (
    FrameResult,
    TrackerConfig,
    TrackerState,
    force_loss,
    new_state,
    process_frame,
)
from tracker_service.scene.subject import SubjectSpec
from tracker_service.scene.synthetic import SceneConfig, SceneFrame, SyntheticScene
from tracker_service.scene.variation import h264_roundtrip
from tracker_service.sources.frame_source import fit_frame
from tracker_service.templates.database import LoadedDatabase

__all__ = ["EvalOptions", "acceleration_error", "confidence_error_spearman", "evaluate_motion", "joint_jumps",
           "reacquisition_times", "subject_measurements"]

log = logging.getLogger(__name__)


def subject_measurements(spec: SubjectSpec) -> dict[str, Any]:
    """The synthetic person's measurements in the form of :func:`~tracker_service.body.measured.parse_measurements`."""
    return {"height": spec.height, "group": spec.group, "chest": spec.chest, "waist": spec.waist, "hip": spec.hip,
            "shoulder": spec.shoulder_frac * spec.height, "arm": spec.arm_ratio, "leg": spec.leg_ratio}


def _stats(v: list[float]) -> dict[str, float]:
    a = np.asarray(v, dtype=np.float64)
    if a.size == 0:
        return {"min": float("nan"), "avg": float("nan"), "p99": float("nan"), "max": float("nan")}
    return {"min": round(float(a.min()), 3), "avg": round(float(a.mean()), 3),
            "p99": round(float(np.percentile(a, 99)), 3), "max": round(float(a.max()), 3)}


@dataclass
class _Tally:
    """What :func:`evaluate_motion` gathers over the frames where the person is in view."""

    present: int = 0
    tracked: int = 0
    errs: list[float] = field(default_factory=list)  # root-relative mean joint error of each tracked frame
    confs: list[float] = field(default_factory=list)  # the published confidence of each tracked frame
    err_t: list[float] = field(default_factory=list)  # their timestamps
    root_errs: list[float] = field(default_factory=list)
    errs2d: list[float] = field(default_factory=list)
    acc_i: list[int] = field(default_factory=list)  # frame number, estimated and true joints in the world
    acc_e: list[NDArray[np.float64]] = field(default_factory=list)  # of the steady frames (jitter, jumps)
    acc_t: list[NDArray[np.float64]] = field(default_factory=list)
    digest: Any = field(default_factory=hashlib.sha256)  # the published pose stream, for regression checks
    t_pre: list[float] = field(default_factory=list)
    t_est: list[float] = field(default_factory=list)
    t_tot: list[float] = field(default_factory=list)
    init_ms: float = 0.0
    evals: list[tuple[int, ...]] = field(default_factory=list)
    withheld: dict[str, int] = field(default_factory=dict)  # frames whose pose was withheld, by reason

    def add(self, i: int, fr: SceneFrame, res: FrameResult, loaded: LoadedDatabase, was_tracking: bool,
            in_loss: bool) -> float:
        """Score tracked frame ``i`` (``was_tracking``: the tracker was tracking before it; ``in_loss``:
        a forced loss is not yet recovered); returns its root-relative mean joint error."""
        assert res.joints is not None
        self.tracked += 1
        jt, je = fr.truth.joints, res.joints
        self.digest.update(np.ascontiguousarray(je, dtype=np.float64).tobytes())
        e = float(np.linalg.norm((je - je[0]) - (jt - jt[0]), axis=1).mean())
        self.errs.append(e)
        self.confs.append(float(res.confidence))
        steady = was_tracking and res.phase == "tracking"  # initialisation (body selection) apart
        if steady and not in_loss and not res.reinitialised and not res.body_changed:
            # jitter of steady tracking: no loss, recovery or new skeleton
            self.acc_i.append(i)
            self.acc_e.append(np.asarray(je, np.float64))
            self.acc_t.append(np.asarray(jt, np.float64))
        self.root_errs.append(float(np.linalg.norm(je[0] - jt[0])))
        self.errs2d.append(float(np.linalg.norm(fr.truth.camera.project(je) - fr.truth.joints_2d, axis=1).mean()))
        if steady:
            self.t_pre.append(res.stage_ms.get("preprocess", 0.0) + res.stage_ms.get("background", 0.0))
            self.t_est.append(res.stage_ms.get("estimate", 0.0))
            self.t_tot.append(res.stage_ms.get("total", 0.0))
            self.evals.append(res.evaluations)
        else:
            self.init_ms += res.stage_ms.get("total", 0.0)
        self.err_t.append(fr.timestamp)
        return e


@dataclass
class _ForcedLosses:
    """Forces a tracking loss every ``every_s`` seconds of tracking, the next one only once the
    track is back within 10 cm (three frames in a row); the time it took is measured afterwards by
    :func:`reacquisition_times`."""

    every_s: float
    fps: float
    next_loss: float = 0.0
    lost_at: float | None = None
    streak: int = 0
    track_time: float = 0.0
    at: list[int] = field(default_factory=list)  # index into the errors of each forced loss

    def __post_init__(self) -> None:
        self.next_loss = self.every_s

    def after(self, t: float, e: float, index: int, res: FrameResult, state: TrackerState,
              reset: Callable[[TrackerState], TrackerState]) -> TrackerState:
        """Follow tracked frame ``index`` (time ``t``, error ``e``); the state, with a loss forced by
        ``reset`` (the estimator restarted)."""
        if self.lost_at is not None:
            self.streak = self.streak + 1 if e < 0.10 else 0
            if self.streak >= 3:
                self.lost_at = None
        elif res.phase == "tracking":
            self.track_time += 1.0 / self.fps
            if self.every_s > 0 and self.track_time >= self.next_loss:
                # forced loss: forget the pose, start from the wrong side of the body
                state = reset(state)
                self.lost_at, self.streak = t, 0
                self.at.append(index)
                self.next_loss += self.every_s
        return state


def _scene(motion: Motion, loaded: LoadedDatabase, options: EvalOptions) -> SyntheticScene:
    travel = np.ptp(motion.poses[:, [0, 2]], axis=0).max() if motion.n_frames else 0.0
    scfg = SceneConfig(width=loaded.camera.width, height=loaded.camera.height, fps=options.fps,
                       empty_prefix=options.empty_prefix, in_place=bool(travel > options.in_place_travel_m),
                       variation=options.variation,
                       camera=_scene_camera(loaded.camera, options))
    return SyntheticScene(motion, seed=options.seed, config=scfg)


def _eval_config(config: TrackerConfig, options: EvalOptions, scene: SyntheticScene) -> TrackerConfig:
    """``config`` with the scene's background frames and, if asked, the person's own measurements."""
    # the background learned from the empty-room prefix, at most as many frames as `run` learns it from;
    # with no prefix from the first frames, the person in them, as `run` does when started in view
    cfg = config if options.empty_prefix == 0 else replace(
        config, background_frames=min(config.background_frames, options.empty_prefix))
    if options.subject_measurements:
        known = subject_measurements(scene.subject.spec)
        if unknown := set(options.subject_measurements) - set(known):
            raise ValueError(f"unknown measurement(s) {sorted(unknown)}; choose from {', '.join(known)}")
        given = {k: known[k] for k in ("height", *options.subject_measurements)}
        cfg = replace(cfg, body_candidates=(), body=given_body(given))
    return cfg


def _scene_camera(working: Camera, options: EvalOptions) -> Camera | None:
    """The camera filming the scene: the one the tracker was told about (``--camera`` and the
    shorthands), at ``input_size`` if given; None: the working camera."""
    base = options.camera if options.camera is not None else working
    if options.input_size is not None:
        return widened(base.fitted(working.size), options.input_size)
    return options.camera


def widened(camera: Camera, size: tuple[int, int]) -> Camera:
    """A camera of ``size`` = ``(width, height)`` pixels whose frames, once brought to the working
    size (:func:`~tracker_service.sources.frame_source.fit_frame`: the centre of the working aspect
    cropped, then scaled), are ``camera``'s: the same pose, the same vertical field of view when the frame is
    wider than 4:3 (the horizontal one when it is taller), square pixels, the principal point at
    the centre (640x480: the same camera at twice the resolution; 1280x720: a wider lens)."""
    w, h = int(size[0]), int(size[1])
    s = min(w / camera.width, h / camera.height)
    return replace(camera, width=w, height=h, fx=camera.fx * s, fy=camera.fy * s, cx=(w - 1) / 2.0,
                   cy=(h - 1) / 2.0)


def jpeg_roundtrip(image: NDArray[np.uint8], quality: int) -> NDArray[np.uint8]:
    """``image`` (H, W, 3) uint8 BGR encoded as JPEG at ``quality`` and decoded again."""
    import cv2

    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return np.asarray(cv2.imdecode(buf, cv2.IMREAD_COLOR), np.uint8)


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
    scene = _scene(motion, loaded, options)
    tally = _Tally()
    losses = _ForcedLosses(options.force_loss_every_s, options.fps)
    try:
        n = scene.n_frames if options.frames is None else min(scene.n_frames, options.empty_prefix + options.frames)
        cfg = _eval_config(config, options, scene)
        state: TrackerState = new_state(loaded.body)

        def lose(st: TrackerState) -> TrackerState:
            return force_loss(st, loaded.db, loaded.body, loaded.camera, cfg)

        for i in range(n):
            fr = scene.frame(i)
            was_tracking = state.phase == "tracking"  # the frame that ends initialisation scores the bodies
            image = fr.image if options.jpeg_quality is None else jpeg_roundtrip(fr.image, options.jpeg_quality)
            if options.h264_crf is not None:
                image = h264_roundtrip(image, options.h264_crf)
            if image.shape[:2] != (loaded.camera.height, loaded.camera.width):  # as `run` does (one path)
                image = fit_frame(image, loaded.camera.size)
            state, res = process_frame(state, image, loaded.db, loaded.body, loaded.camera, cfg, fr.timestamp)
            if observe is not None:
                observe(fr, state, res)
            if not fr.truth.present:
                continue
            tally.present += 1
            if res.rejected is not None:
                tally.withheld[res.rejected] = tally.withheld.get(res.rejected, 0) + 1
            if res.joints is None:
                continue
            e = tally.add(i, fr, res, loaded, was_tracking, in_loss=losses.lost_at is not None)
            state = losses.after(fr.timestamp, e, len(tally.errs) - 1, res, state, lose)
            if progress is not None:
                progress(i + 1, n)
    finally:
        scene.close()
    return _result(motion, loaded, config, options, tally, losses.at, state, scene)


def _after(errs: NDArray[np.float64], t: NDArray[np.float64], t0: float) -> float | None:
    """Mean of ``errs`` (metres) at times ``t >= t0``, in cm; None when no frame is that late."""
    late = errs[t >= t0 - 1e-9] if len(errs) else errs
    return round(float(late.mean() * 100), 2) if len(late) else None


def _result(motion: Motion, loaded: LoadedDatabase, config: TrackerConfig, options: EvalOptions, tally: _Tally,
            losses: list[int], state: TrackerState, scene: SyntheticScene) -> dict[str, Any]:
    """The ``mocap-tracker eval`` JSON object."""
    e_arr = np.asarray(tally.errs)
    reacq = reacquisition_times(np.asarray(tally.err_t), e_arr, losses, options.fps)
    lvl = np.asarray(tally.evals, dtype=np.float64) if tally.evals else np.zeros((0, 3))
    t_tot = tally.t_tot
    total_ms = float(np.mean(t_tot)) if t_tot else float("nan")
    steady_i = np.asarray(tally.acc_i, np.int64)
    world_e = np.asarray(tally.acc_e).reshape(len(steady_i), N_JOINTS, 3)
    world_t = np.asarray(tally.acc_t).reshape(len(steady_i), N_JOINTS, 3)
    accel = acceleration_error(steady_i, world_e - world_e[:, :1], world_t - world_t[:, :1])  # root-relative
    jumps, worst_jump = joint_jumps(steady_i, world_e, world_t)
    return {
        "motion": motion.name,
        "frames": int(tally.present),
        "tracked_frames": int(tally.tracked),
        "mpjpe_cm": round(float(e_arr.mean() * 100), 2) if len(e_arr) else None,
        "root_error_cm": round(float(np.mean(tally.root_errs) * 100), 2) if tally.root_errs else None,
        "root_error_max_cm": round(float(np.max(tally.root_errs) * 100), 2) if tally.root_errs else None,
        "mpjpe_2d_px": round(float(np.mean(tally.errs2d)), 2) if tally.errs2d else None,
        # from 3 s after the person appears: a start with them in view is judged on it
        "mpjpe_after_3s_cm": _after(e_arr, np.asarray(tally.err_t), options.empty_prefix / options.fps + 3.0),
        "frames_within_10cm": round(float(np.mean(e_arr < 0.10)), 3) if len(e_arr) else 0.0,
        "accel_error_cm": round(accel * 100, 3) if np.isfinite(accel) else None,
        "joint_jumps_15cm": jumps,
        "worst_joint_jump_cm": round(worst_jump * 100, 2),
        "confidence_error_spearman": confidence_error_spearman(tally.confs, tally.errs),
        "reacquire_s_max": (None if not reacq else (round(max(reacq), 3) if np.isfinite(max(reacq)) else None)),
        "forced_losses": len(reacq),
        "reacquired": int(np.sum(np.isfinite(reacq))),
        "fps": round(1000.0 / total_ms, 1) if t_tot else None,
        "ms_per_frame": {"preprocess": _stats(tally.t_pre), "estimate": _stats(tally.t_est), "total": _stats(t_tot)},
        "initialisation_ms": round(tally.init_ms, 1),
        "steady_frames": len(t_tot),
        "distance_evals_per_level": [round(float(x), 1) for x in lvl.mean(axis=0)] if len(lvl) else [],
        "templates": int(loaded.db.n_leaves),
        "tree_levels": [int(s) for s in loaded.db.tree.level_sizes],
        "estimator": config.estimator,
        "appearance_cue": bool(config.appearance is not None and config.filter.appearance_weight > 0),
        "distance": config.distance,
        "occlusion_dynamics": config.occlusion,
        "body_selected": state.body.name,
        "database_body": loaded.body.name,
        "subject_height_m": round(float(scene.subject.spec.height), 3),
        "body_height_m": round(float(state.body.height), 3),
        "stature_measured_m": round(float(np.median(state.statures)), 3) if state.statures else None,
        "reinitialisations": int(state.reinits),
        "withheld": dict(sorted(tally.withheld.items())),
        "background_relearns": int(state.relearns),
        "camera_estimate": state.camera_estimate.as_dict() if state.camera_estimate is not None else {},
        "empty_prefix": options.empty_prefix,
        "poses_sha256": tally.digest.hexdigest(),
        "jpeg_quality": options.jpeg_quality,
        "h264_crf": options.h264_crf,
        "input_size": list(options.input_size) if options.input_size else None,
        "camera": scene.camera.summary(),
        "variation": list(options.variation),
        "subject": {"group": scene.subject.spec.group, "chest_m": round(float(scene.subject.spec.chest), 3),
                    "stoop_deg": round(float(np.degrees(scene.subject.spec.stoop)), 1)},
        "scene": {"lights": scene.variation.lights, "codec": scene.variation.codec,
                  "quality": scene.variation.quality, "blur_px": round(scene.variation.blur_px, 1),
                  "noise_scale": round(scene.variation.noise_scale, 2)},
    }
