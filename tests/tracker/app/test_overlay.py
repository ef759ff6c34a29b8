"""tracker_service.viz.overlay: the silhouette tint, the projected skeleton, the HUD, and the overlay
video the daemon's and the evaluation's per-frame hooks write."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from protocol.formats.video import video_info
from protocol.kinematics import fk
from protocol.skeleton import JOINT_INDEX, default_body, standing_pose
from tracker_service.camera import Camera, default_camera
from tracker_service.viz.overlay import LEFT_BGR, OverlayVideo, draw_overlay, hud_lines


def _scene() -> tuple[np.ndarray, np.ndarray, Camera]:
    cam = default_camera(320, 240)
    joints = fk(standing_pose(default_body()), default_body())
    return np.full((240, 320, 3), 60, np.uint8), joints, cam


def test_overlay_draws_skeleton_at_the_projected_joints_and_tints_the_silhouette() -> None:
    image, joints, cam = _scene()
    sil = np.zeros((120, 160), bool)  # half resolution: resized to the frame
    sil[40:100, 60:100] = True
    out = draw_overlay(image, cam, joints=joints, silhouette=sil, hud=hud_lines("tracking", 29.97, 0.8))
    assert out.shape == image.shape and np.array_equal(image, np.full_like(image, 60))  # input untouched
    uv = cam.project(joints)
    u, v = np.round(uv[JOINT_INDEX["l_elbow"]]).astype(int)
    assert np.abs(out[v - 1: v + 2, u - 1: u + 2].astype(int) - LEFT_BGR).sum(axis=2).min() < 60
    assert (out[150:190, 170:190] != 60).any()  # tinted silhouette region (rows 80-200, cols 120-200)
    assert (out[5:15, 5:60] != 60).any()  # the HUD box
    bare = draw_overlay(image, cam)
    assert (bare[100:, 100:] == 60).all()  # no joints, no silhouette: only the (empty) HUD


def test_overlay_video_writes_every_frame(tmp_path: Path) -> None:
    image, joints, cam = _scene()
    path = tmp_path / "overlay.mp4"
    with OverlayVideo(path, cam, fps=30.0) as video:
        for k in range(6):
            res = SimpleNamespace(phase="tracking" if k else "initialising", silhouette=None,
                                  joints=joints if k else None, confidence=0.7, stage_ms={"total": 20.0})
            video(image, res)
        video(image, None)  # a frame the pipeline could not use
    info = video_info(path)
    assert (info.codec, info.frames, info.width, info.height) == ("h264", 7, 320, 240)
