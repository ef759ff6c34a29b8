"""``run`` and ``eval`` share one path from frame to published pose: on the same frames the daemon
publishes exactly the poses ``eval`` scores."""

from __future__ import annotations

import threading
from dataclasses import replace
from typing import Any

import numpy as np

from protocol.formats.load import load_motion
from protocol.net.session import build_config
from tracker_service.app import daemon
from tracker_service.app.evaluate import evaluate_motion
from tracker_service.app.options import EvalOptions, RunOptions
from tracker_service.paths import REPO_ROOT
from tracker_service.pipeline.config import TrackerConfig
from tracker_service.scene.synthetic import SceneConfig, SyntheticScene
from tracker_service.sources.frame_source import SyntheticSource
from tracker_service.templates.database import load_db

SCRIPT = REPO_ROOT / "game_client" / "scripts" / "strike.toml"
PREFIX, FRAMES, SEED = 12, 30, 3


def test_run_publishes_the_poses_eval_scores(small_db: Any) -> None:
    loaded = load_db(small_db[4], verify=False)
    cfg = TrackerConfig(distance="xor", init_frames=2, body_candidates=("mSA", "mMA"))
    motion = load_motion(SCRIPT, fps=30.0)

    scored: list[tuple[float, np.ndarray | None]] = []
    evaluate_motion(motion, loaded, cfg, EvalOptions(seed=SEED, empty_prefix=PREFIX, frames=FRAMES),
                    observe=lambda fr, st, res: scored.append((fr.timestamp, res.joints)))

    scene = SyntheticScene(motion, seed=SEED, config=SceneConfig(
        width=loaded.camera.width, height=loaded.camera.height, fps=30.0, empty_prefix=PREFIX))
    published: list[tuple[float, np.ndarray | None]] = []
    conf = build_config("publisher", mode="peer", listen=["tcp/127.0.0.1:0"])
    daemon.run_tracker(SyntheticSource(scene), loaded, replace(cfg), conf,
                       RunOptions(tracker_id="onepath", max_frames=PREFIX + FRAMES, realtime=False, warm_up=False),
                       threading.Event(), observe=lambda ts, frame, res: published.append(
                           (ts, None if res is None else res.joints)))

    assert len(published) == len(scored) == PREFIX + FRAMES
    poses = 0
    for (t_run, j_run), (t_eval, j_eval) in zip(published, scored, strict=True):
        assert t_run == t_eval
        assert (j_run is None) == (j_eval is None)
        if j_run is not None:
            np.testing.assert_array_equal(j_run, j_eval)
            poses += 1
    assert poses >= FRAMES // 2  # the person was tracked, not just waited for
