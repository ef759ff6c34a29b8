"""The tracker's :class:`~tracker_service.pipeline.process.TrackerConfig` from the ``run`` / ``eval``
options (:class:`~tracker_service.app.options.TrackerOptions`)."""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import TYPE_CHECKING, TypeGuard

from tracker_service.app.options import TrackerOptions
from tracker_service.app.resources import ensure_appearance, requested_camera

if TYPE_CHECKING:
    from protocol.skeleton import Body
    from tracker_service.pipeline.process import TrackerConfig

__all__ = ["is_subject", "subject_keys", "tracker_config"]

log = logging.getLogger(__name__)

#: The keys of ``--measurements subject:KEY,...`` (eval: the synthetic person's own measurements).
SUBJECT_KEYS = ("height", "group", "chest", "waist", "hip", "shoulder", "arm", "leg")


def is_subject(spec: str | None) -> TypeGuard[str]:
    """Whether ``--measurements`` names the synthetic person's own (``subject`` or ``subject:KEYS``)."""
    return bool(spec) and (spec == "subject" or str(spec).startswith("subject:"))


def subject_keys(spec: str | None) -> tuple[str, ...]:
    """``subject`` -> every measurement of the scene's person; ``subject:height,leg`` -> those."""
    if not is_subject(spec):
        return ()
    _, _, keys = spec.partition(":")
    chosen = tuple(k.strip() for k in keys.split(",") if k.strip()) if keys else SUBJECT_KEYS
    if bad := sorted(set(chosen) - set(SUBJECT_KEYS)):
        raise ValueError(f"--measurements subject: unknown key(s) {bad}; choose from {', '.join(SUBJECT_KEYS)}")
    return chosen


def _body_choice(options: TrackerOptions) -> tuple[tuple[str, ...], Body | None]:
    """The body models the selection considers and the body given by the user's measurements."""
    from tracker_service.body.family import BODY_MODELS
    from tracker_service.body.measured import given_body, parse_measurements

    names = [m.name for m in BODY_MODELS]
    if options.body != "auto" and options.body not in names:
        raise ValueError(f"unknown body model {options.body!r}; choose auto or one of {', '.join(names)}")
    # auto: the family is scored on the first frames; NAME: that model (templates scaled to its height)
    cands = tuple(names) if options.body == "auto" else (options.body,)
    if not options.measurements:
        return cands, None
    if options.body != "auto":
        raise ValueError("give either --body NAME or --measurements, not both")
    if is_subject(options.measurements):  # eval's 'subject' is resolved with the scene
        if not options.subject_allowed:
            raise ValueError("--measurements subject is eval's (the synthetic person's own measurements); "
                             "give the user's as height=M,leg=RATIO,...")
        subject_keys(options.measurements)  # a bad key is an error now, not after the warm-up
        return (), None
    return (), given_body(parse_measurements(options.measurements))


def tracker_config(options: TrackerOptions) -> TrackerConfig:
    """The pipeline configuration the options ask for (loads the appearance network they name).

    Raises
    ------
    ValueError
        For an unknown body model, contradictory or bad measurements, or a heading out of range.
    tracker_service.cues.appearance.AppearanceError
        If a named appearance network cannot be read.
    """
    from tracker_service.estimators.tree_filter.filter import FilterParams
    from tracker_service.pipeline.process import TrackerConfig

    cands, given = _body_choice(options)
    max_heading = options.max_heading_deg
    if max_heading is not None and not 0.0 < max_heading <= 180.0:
        raise ValueError(f"--max-heading must be in (0, 180] degrees, got {max_heading}")
    cfg = TrackerConfig(distance=options.distance, occlusion=options.occlusion, body_candidates=cands, body=given,
                        estimator=options.estimator, min_confidence=options.min_confidence,
                        filter=FilterParams(max_heading=None if max_heading is None else math.radians(max_heading)))
    if not options.skin:
        cfg = replace(cfg, skin=None)
    if not options.shoes:
        cfg = replace(cfg, shoes=None)
    if not options.smoothing:
        cfg = replace(cfg, smoothing=None)
    elif cfg.smoothing is not None and (options.smooth_cutoff is not None or options.smooth_beta is not None):
        sm = cfg.smoothing
        if options.smooth_cutoff is not None:
            sm = replace(sm, min_cutoff_rot=options.smooth_cutoff, min_cutoff_root=options.smooth_cutoff)
        if options.smooth_beta is not None:
            sm = replace(sm, beta_rot=options.smooth_beta, beta_root=options.smooth_beta)
        cfg = replace(cfg, smoothing=sm)
    if options.pose == "map":
        cfg = replace(cfg, use_mean_pose=False)
    if not options.refine:
        cfg = replace(cfg, refine=None)
    if not options.floor:
        cfg = replace(cfg, floor=None)
    if not options.proportions:
        cfg = replace(cfg, proportions=None)
    if not options.reading_filter:
        cfg = replace(cfg, reading_filter=None)
    net = ensure_appearance(options.appearance, train_if_missing=False)
    if net is not None:
        from tracker_service.cues.appearance import appearance_unfit

        camera = requested_camera(options)
        why = appearance_unfit(camera) if camera is not None else None
        if why is not None and options.appearance is None:  # the shipped network, on a camera it never saw
            log.warning("appearance cue off: %s; the silhouettes alone track (name a network trained for this "
                        "camera with --appearance PATH)", why)
            net = None
        elif why is not None:
            log.warning("the appearance network %s reads this camera's frames although %s", options.appearance, why)
    if net is not None:
        cfg = replace(cfg, appearance=net)
    return cfg
