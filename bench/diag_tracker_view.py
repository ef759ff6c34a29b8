"""Look at the tracker's error: camera view and side view of the truth against the published pose.

For chosen frames of a held-out take rendered as synthetic video, writes one PNG with a tile per
frame: the camera image (2x) with the true skeleton (green) and the published one (red, its root
put on the true root), and beside it a side view (depth horizontal, the camera to the right, height
up) of both, root-relative, with the frame's mean joint error. The side view shows what the camera
cannot: on the hard takes (bye-tired, byebye-old, guides) the two skeletons coincide in
the image while the true one leans towards the camera and the estimate stands upright.

Usage::

    .venv/bin/python bench/diag_tracker_view.py --take-index 17 --frames 40,70,100 --out out/view.png
        [--seed S]

A diagnostic, not a test. Frame numbers count from the first frame of the scene (the empty-room
prefix included).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from protocol.formats.load import load_motion
from protocol.formats.mocap_data import index_entries, mocap_root
from protocol.skeleton import PARENTS
from tracker_service.app.evaluate import EvalOptions, evaluate_motion
from tracker_service.app.resources import ensure_db
from tracker_service.body.family import BODY_MODELS
from tracker_service.build.database import is_held_out
from tracker_service.pipeline.process import FrameResult, TrackerConfig, TrackerState
from tracker_service.scene.synthetic import SceneFrame


def _draw(img: NDArray[np.uint8], pts: NDArray[np.float64], colour: tuple[int, int, int]) -> None:
    for j, p in enumerate(PARENTS):
        if p >= 0 and np.all(np.isfinite(pts[[p, j]])):
            cv2.line(img, tuple(int(v) for v in pts[p]), tuple(int(v) for v in pts[j]), colour, 1, cv2.LINE_AA)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--take-index", type=int, required=True, help="held-out take (0-50)")
    ap.add_argument("--frames", required=True, help="comma-separated frame numbers")
    ap.add_argument("--seed", type=int, default=7, help="scene seed (the subject)")
    ap.add_argument("--out", required=True, help="image to write (.png, or .jpg for a smaller file)")
    args = ap.parse_args()
    held = [e for i, e in enumerate(index_entries()) if is_held_out(i)]
    if not 0 <= args.take_index < len(held):
        raise SystemExit(f"--take-index: 0..{len(held) - 1}")
    try:
        wanted = sorted({int(x) for x in args.frames.split(",")})
    except ValueError:
        raise SystemExit(f"--frames {args.frames!r}: comma-separated integers") from None
    loaded = ensure_db(None)
    cfg = TrackerConfig(distance="xor", body_candidates=tuple(m.name for m in BODY_MODELS))
    tiles: list[NDArray[np.uint8]] = []

    def observe(fr: SceneFrame, st: TrackerState, res: FrameResult, *_: Any) -> None:
        if fr.truth.index not in wanted or res.joints is None or not fr.truth.present:
            return
        truth = fr.truth.joints
        est = res.joints - res.joints[0] + truth[0]
        img: NDArray[np.uint8] = np.asarray(cv2.resize(fr.image, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST),
                                            np.uint8)
        _draw(img, 2 * fr.truth.camera.project(truth), (0, 255, 0))
        _draw(img, 2 * fr.truth.camera.project(est), (0, 0, 255))
        side = np.full((img.shape[0], img.shape[0] // 2, 3), 255, np.uint8)
        h, w = side.shape[:2]
        scale = 0.3 * h
        for joints, colour in ((truth, (0, 160, 0)), (est, (0, 0, 255))):
            rel = joints - truth[0]
            _draw(side, np.stack([w / 2 + scale * rel[:, 2], 0.62 * h - scale * rel[:, 1]], axis=1), colour)
        err = np.linalg.norm((res.joints - res.joints[0]) - (truth - truth[0]), axis=1).mean()
        cv2.putText(side, f"frame {fr.truth.index}: {100 * err:.1f} cm", (5, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (0, 0, 0), 1, cv2.LINE_AA)
        # the person's half of the camera view, then the side view
        cols = np.flatnonzero(res.silhouette.any(axis=0)) if res.silhouette is not None else np.array([160])
        c = int(np.clip(2 * cols.mean(), h // 2, img.shape[1] - h // 2)) if len(cols) else img.shape[1] // 2
        tiles.append(np.concatenate([img[:, c - h // 2: c + h // 2], side], axis=1))

    evaluate_motion(load_motion(mocap_root() / held[args.take_index].path, fps=30.0), loaded, cfg,
                    EvalOptions(frames=max(wanted) + 1, seed=args.seed), observe=observe)
    if not tiles:
        raise SystemExit("none of the frames was tracked (try later frames: the first ones learn the background)")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(args.out, np.concatenate(tiles, axis=1), [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(f"wrote {len(tiles)} frame(s) of {held[args.take_index].path} to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
