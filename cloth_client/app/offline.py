"""Offline runs: a garment simulated on a recorded or scripted motion, with quality and speed figures.

:func:`simulate_motion` feeds every frame of a :class:`protocol.motion.Motion` to a
:class:`~cloth_client.solver.driver.ClothDriver` (optionally rendering a video) and returns the summary
printed by ``mocap-cloth simulate --json``:

``steps_per_s``
    cloth substeps per wall-clock second (simulation only; rendering, loading and the one-off
    dressing on the first two poses excluded);
``realtime_factor``
    simulated seconds per wall-clock second, same exclusions (> 1: faster than real time);
``max_penetration_mm`` / ``mean_penetration_mm``
    deepest and mean depth of free particles inside the body capsules at the frame times (the mean
    is over penetrating particle-frames; 0 when none penetrates);
``max_strain``
    largest engineering strain of any structural spring at any frame (0.05 = 5 % longer than rest);
``energy_drift``
    largest rise of the cloth's mechanical energy during the static settle before the motion starts,
    in units of ``m g h`` of the whole garment (0: the integrator never created energy);
``nan``
    whether a non-finite value ever appeared (the driver then re-dresses the garment).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from cloth_client.solver.cloth import ClothParams
from cloth_client.solver.driver import ClothDriver, DriverConfig
from cloth_client.solver.garment import DEFAULT_PARTICLES, make_garment
from protocol.motion import Motion

__all__ = ["simulate_motion"]

log = logging.getLogger(__name__)


def simulate_motion(
    motion: Motion,
    garment: str = "cape",
    *,
    particles: int = DEFAULT_PARTICLES,
    params: ClothParams | None = None,
    config: DriverConfig | None = None,
    video: str | Path | None = None,
    video_fps: float = 30.0,
    size: tuple[int, int] = (480, 480),
    max_frames: int | None = None,
    progress: bool = False,
) -> dict[str, Any]:
    """Simulate ``garment`` on ``motion`` and summarise it (keys in the module docstring).

    Parameters
    ----------
    motion : Motion
        Poses on the shared skeleton; its ``body`` sizes the avatar and the garment.
    garment : {"cape", "skirt"}
    particles : int
        Approximate particle count.
    params, config : optional
        Solver parameters and driver timing.
    video : str or Path, optional
        ``*.mp4``, ``*.gif`` or a directory for PNG frames.
    video_fps : float
        Frame rate of the video (frames are taken at this rate from the simulation).
    size : (int, int)
        Video width and height in pixels.
    max_frames : int, optional
        Stop after this many frames of the motion.
    progress : bool
        Show a tqdm progress bar.

    Returns
    -------
    dict
        JSON-ready summary.
    """
    body = motion.body
    g = make_garment(garment, body, particles)
    driver = ClothDriver(body, g, params, config)
    poses, times = motion.poses, motion.times
    if max_frames is not None:
        poses, times = poses[:max_frames], times[:max_frames]
    # frames the loader flagged as artefacts (converter T-poses, glitches) are dropped frames here
    keep = np.asarray(motion.valid, dtype=bool)[: len(poses)]
    invalid = int((~keep).sum())
    poses, times = poses[keep], times[keep]
    if len(poses) == 0:
        raise ValueError(f"{motion.name or 'motion'} has no valid frame")
    renderer = writer = None
    if video is not None:
        from cloth_client.app.render import ClothRenderer, FrameWriter  # OpenGL only when a video is asked for

        renderer = ClothRenderer(body, g, *size, limb_clearance=driver.config.limb_clearance)
        writer = FrameWriter(video, video_fps)
    strains = np.zeros(len(poses))
    sim_wall = render_wall = 0.0
    next_render = times[0] if len(times) else 0.0
    bar: Any = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(poses), unit="frame", desc=f"{garment} on {motion.name or 'motion'}")
    dress_s = 0.0
    untimed_substeps = 0
    try:
        for i in range(len(poses)):
            t0 = time.perf_counter()
            stats = driver.feed(poses[i], float(times[i]))
            if i <= 1:  # the first two poses dress the avatar (one-off), see ClothDriver
                dress_s += time.perf_counter() - t0
            else:
                sim_wall += time.perf_counter() - t0
            if stats is not None:
                strains[i] = stats.max_strain
                untimed_substeps += stats.substeps if i <= 1 else 0
            if (renderer is not None and writer is not None and driver.state is not None
                    and times[i] + 1e-9 >= next_render):
                t0 = time.perf_counter()
                writer.write(renderer.render(poses[i], driver.state.x, driver.body_capsules))
                render_wall += time.perf_counter() - t0
                next_render += 1.0 / video_fps
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
        if writer is not None:
            writer.close()
        if renderer is not None:
            renderer.close()
    s = driver.summary()
    sim_time = float(s["sim_time_s"])
    timed = sim_time - (float(times[1] - times[0]) if len(times) > 1 else 0.0)  # excludes the dressing step
    out: dict[str, Any] = {
        "recording": motion.source or motion.name,
        "garment": garment,
        "particles": g.n_particles,
        "frames": int(s["frames"]),
        "input_fps": float(motion.fps),
        "sim_time_s": round(sim_time, 4),
        "wall_s": round(sim_wall, 4),
        "substeps": int(s["substeps"]),
        "steps_per_s": round((int(s["substeps"]) - untimed_substeps) / sim_wall, 1) if sim_wall > 0 else None,
        "realtime_factor": round(timed / sim_wall, 3) if sim_wall > 0 else None,
        "max_penetration_mm": round(1000.0 * float(s["max_penetration_m"]), 3),
        "mean_penetration_mm": round(1000.0 * float(s["mean_penetration_m"]), 3),
        "max_strain": round(float(s["max_strain"]), 4),
        "p99_strain": round(float(np.percentile(strains[1:], 99)), 4) if len(strains) > 1 else 0.0,
        "frames_over_10pct_strain": int((strains > 0.10).sum()),
        "energy_drift": round(float(s["energy_drift"]), 6),
        "settle_kinetic_j": round(float(s["settle_kinetic_j"]), 6),
        "resets": int(s["resets"]),
        "recoveries": int(s["recoveries"]),
        "skipped_frames": int(s["skipped"]) + invalid,
        "nan": bool(s["nan"]),
        "dress_s": round(dress_s, 3),
    }
    if video is not None:
        out["video"] = str(video)
        out["render_s"] = round(render_wall, 3)
    log.info("simulated %s on %s: %s", garment, out["recording"], out)
    return out
