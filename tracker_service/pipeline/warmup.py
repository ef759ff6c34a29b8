"""Warm-up: run the whole pipeline once on a generated clip before the first real frame.

Every hot loop of the tracker is a numba kernel compiled on first call and cached on disk
(``@njit(cache=True)``). On a fresh install the first call of each compiles it, which stalls the
first real frames for tens of seconds (measured in ``docs/TRACKER.md``); later starts
load the cache in a fraction of a second. :func:`warm_up` drives :func:`~tracker_service.pipeline.process.
process_frame` through every phase (learning, waiting, initialising with the body selection,
tracking) on a clip made of an empty room and the database body standing at the reference spot (its most neutral leaf),
painted in skin and shoe colours so that the skin and shoe cues run too. The daemon calls it
before it announces itself, the evaluation before it starts the clock.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import JOINT_INDEX, Body
from tracker_service.body.kinematics import fk
from tracker_service.body.raster import render_silhouette
from tracker_service.camera import Camera
from tracker_service.estimators.tree_filter.filter import FilterDB
from tracker_service.pipeline.process import Phase, TrackerConfig, new_state, process_frame

__all__ = ["WarmUp", "warm_up", "warm_up_frames"]

log = logging.getLogger(__name__)

#: BGR colours of the generated person: a red shirt, skin at the skin locus' mean chromaticity
#: (head and hands only: a mostly skin-coloured silhouette switches the cue off), blue shoes.
_SHIRT = (40, 40, 200)
_SKIN = (60, 80, 112)
_SHOES = (200, 60, 40)
_SKIN_JOINTS = ("head", "l_hand_tip", "r_hand_tip")
_ROOM = 128


@dataclass(frozen=True)
class WarmUp:
    """What :func:`warm_up` did: ``seconds`` of wall-clock time, ``frames`` processed and the
    ``phase`` reached (``tracking`` when every stage ran)."""

    seconds: float
    frames: int
    phase: Phase


def warm_up_frames(db: FilterDB, db_body: Body, camera: Camera, config: TrackerConfig, tracking_frames: int = 3,
                   seed: int = 0) -> list[NDArray[np.uint8]]:
    """The generated clip: ``config.background_frames`` empty frames, then the person for the
    initialisation and ``tracking_frames`` more.

    Parameters
    ----------
    db : FilterDB
    db_body : Body
        The database's body (its leaf nearest the rest pose, at the reference spot, is the person).
    camera : Camera
    config : TrackerConfig
    tracking_frames : int
    seed : int
        Seed of the sensor noise.

    Returns
    -------
    list of (H, W, 3) uint8
        BGR frames.
    """
    rng = np.random.default_rng(seed)
    shape = (camera.height, camera.width, 3)

    def noisy(img: NDArray[np.float64]) -> NDArray[np.uint8]:
        return np.clip(img + rng.normal(0.0, 2.0, shape), 0, 255).astype(np.uint8)

    room = np.full(shape, float(_ROOM))
    frames = [noisy(room) for _ in range(max(config.background_frames, 2))]
    leaf = int(np.argmin(np.abs(db.leaf_poses[:, 3:]).sum(axis=1)))  # the most neutral pose: standing
    mask = render_silhouette(fk(db.leaf_poses[leaf].astype(np.float64), db_body), db_body.capsule_radii, camera)
    person = room.copy()
    person[mask] = _SHIRT
    if len(db.leaf_points):
        vv, uu = np.mgrid[: camera.height, : camera.width]
        for name in _SKIN_JOINTS:
            u, v = db.leaf_points[leaf, JOINT_INDEX[name]]
            person[mask & ((uu - u) ** 2 + (vv - v) ** 2 <= 36.0)] = _SKIN
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows):
        feet = mask.copy()
        feet[: max(int(rows[-1]) - 5, 0)] = False
        person[feet] = _SHOES
    frames += [noisy(person) for _ in range(config.init_frames + tracking_frames + 1)]
    return frames


def warm_up(db: FilterDB, db_body: Body, camera: Camera, config: TrackerConfig, tracking_frames: int = 3,
            should_stop: Callable[[], bool] | None = None) -> WarmUp:
    """Process :func:`warm_up_frames` and throw the result away (pure apart from the kernel cache).

    Parameters
    ----------
    db, db_body, camera, config
        As for :func:`~tracker_service.pipeline.process.process_frame`.
    tracking_frames : int
        Frames processed after the initialisation.
    should_stop : callable, optional
        Checked before each frame; True ends the warm-up early (a signal during start-up).

    Returns
    -------
    WarmUp
    """
    t0 = time.perf_counter()
    frames = warm_up_frames(db, db_body, camera, config, tracking_frames)
    state = new_state(db_body)
    phase: Phase = state.phase
    n = 0
    for i, frame in enumerate(frames):
        if should_stop is not None and should_stop():
            break
        n += 1
        state, res = process_frame(state, frame, db, db_body, camera, config, i / config.fps)
        phase = res.phase
    out = WarmUp(time.perf_counter() - t0, n, phase)
    if phase != "tracking" and n == len(frames):
        log.warning("warm-up ended in phase %r after %d frames: some kernels compile on the first real frames",
                    phase, len(frames))
    return out
