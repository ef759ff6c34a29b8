"""MediaPipe Pose (BlazePose, 0.10.21) on a folder of frames: the peer of ``bench/bench_peers.py``.

Runs in its own environment (``.venv-peers``: ``mediapipe==0.10.21`` needs ``numpy<2``,
``opencv-python-headless<4.12`` and ``protobuf<5``, which the product's environment does not have;
``make bench-peers`` creates it). Reads ``frame_*.png`` from FOLDER in name order as one video
(tracking mode, landmark smoothing on: how a user runs it on a webcam) and writes FOLDER/mediapipe.json:
per frame the 33 world landmarks (metres, origin between the hips, x right, y down, z away from
the camera) or null where no person was found, their visibilities, and the milliseconds each frame
took.

Usage::

    .venv-peers/bin/python bench/peers/mediapipe_pose.py FOLDER [--complexity 0|1|2]
"""

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import mediapipe as mp


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder")
    ap.add_argument("--complexity", type=int, default=1, choices=(0, 1, 2),
                    help="BlazePose model: 0 lite, 1 full (default), 2 heavy")
    args = ap.parse_args()
    folder = Path(args.folder)
    frames = sorted(folder.glob("frame_*.png"))
    if not frames:
        print(f"no frame_*.png in {folder}", file=sys.stderr)
        return 2
    out = {"model": f"mediapipe {mp.__version__} pose complexity {args.complexity}", "frames": []}
    with mp.solutions.pose.Pose(static_image_mode=False, model_complexity=args.complexity,
                                smooth_landmarks=True, min_detection_confidence=0.5,
                                min_tracking_confidence=0.5) as pose:
        for path in frames:
            bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
            t0 = time.perf_counter()
            res = pose.process(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
            ms = (time.perf_counter() - t0) * 1e3
            world = res.pose_world_landmarks
            out["frames"].append({
                "ms": ms,
                "world": None if world is None else [[p.x, p.y, p.z] for p in world.landmark],
                "visibility": None if world is None else [p.visibility for p in world.landmark],
            })
    (folder / "mediapipe.json").write_text(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
