"""The synthetic scene: determinism, ground truth consistency, empty prefix, the person's body."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from protocol.formats.load import load_motion
from protocol.formats.mocap_data import mocap_root
from protocol.kinematics import fk
from protocol.motion import Motion
from protocol.rotations import rotvec_to_matrix
from protocol.skeleton import N_PARTS
from tracker_service.body.family import BODY_MODELS
from tracker_service.scene.subject import build_subject, random_subject_spec
from tracker_service.scene.synthetic import SceneConfig, SyntheticScene, place_motion

KICK = "bandai/dataset-1_kick_normal_001.bvh"


@pytest.fixture(scope="module")
def kick() -> Motion:
    m = load_motion(mocap_root() / KICK)
    return Motion(poses=m.poses[60:130:2], fps=m.fps / 2, name="kick", body=m.body)


@pytest.fixture(scope="module")
def scene(kick: Motion) -> Iterator[SyntheticScene]:
    with SyntheticScene(kick, seed=3, config=SceneConfig(empty_prefix=2)) as s:
        yield s


def test_same_seed_same_frames_in_any_order(scene: SyntheticScene, kick: Motion) -> None:
    first = [scene.frame(i) for i in (0, 5, 20)]
    with SyntheticScene(kick, seed=3, config=SceneConfig(empty_prefix=2)) as twin:
        again = [twin.frame(i) for i in (20, 5, 0)][::-1]
    for a, b in zip(first, again, strict=True):
        assert a.timestamp == b.timestamp
        assert np.array_equal(a.image, b.image)
        assert np.array_equal(a.truth.silhouette, b.truth.silhouette)
        np.testing.assert_array_equal(a.truth.joints_2d, b.truth.joints_2d)
    with SyntheticScene(kick, seed=4, config=SceneConfig(empty_prefix=2)) as other:
        assert not np.array_equal(other.frame(20).image, first[2].image)
        assert other.subject.spec != scene.subject.spec


def test_a_prerendered_source_gives_the_same_frames(kick: Motion) -> None:
    """``run --prerender``: every frame rendered when the source is made, the same as rendered on
    demand, with each frame's truth kept for ``last_truth``."""
    from tracker_service.sources.frame_source import SyntheticSource

    short = Motion(poses=kick.poses[:6], fps=kick.fps, name="kick", body=kick.body)
    with SyntheticScene(short, seed=3, config=SceneConfig(empty_prefix=2)) as a, \
            SyntheticScene(short, seed=3, config=SceneConfig(empty_prefix=2)) as b:
        live, pre = SyntheticSource(a), SyntheticSource(b, prerender=True)
        assert pre._frames is not None and len(pre._frames) == b.n_frames == 8
        for (t0, im0), (t1, im1) in zip(live, pre, strict=True):
            assert t0 == t1 and np.array_equal(im0, im1)
            np.testing.assert_array_equal(live.last_truth.joints_2d, pre.last_truth.joints_2d)
        assert pre.counters["frames"] == 8


def test_frames_and_ground_truth_are_consistent(scene: SyntheticScene) -> None:
    assert scene.n_frames == len(scene) == 2 + len(scene.poses)
    for i in range(2, scene.n_frames, 4):
        ts, image, truth = scene.frame(i)
        assert image.shape == (240, 320, 3) and image.dtype == np.uint8
        assert ts == pytest.approx(i / scene.fps)
        assert truth.present and truth.index == i
        np.testing.assert_allclose(truth.pose, scene.poses[i - 2])
        np.testing.assert_allclose(truth.joints, fk(truth.pose, scene.subject.body), atol=1e-9)
        np.testing.assert_allclose(truth.joints_2d, truth.camera.project(truth.joints))
        assert np.array_equal(truth.silhouette, truth.part_labels >= 0)
        assert truth.part_pixels.shape == (N_PARTS,) and truth.part_pixels.sum() == truth.silhouette.sum()
        assert np.all((truth.visibility >= 0) & (truth.visibility <= 1))
        assert 1500 < truth.silhouette.sum() < 15000
        assert truth.part_pixels[[1, 2]].min() > 0  # torso and head are seen


def test_projected_joints_lie_inside_the_true_silhouette(scene: SyntheticScene) -> None:
    for i in range(2, scene.n_frames, 3):
        truth = scene.frame(i).truth
        sil = cv2.dilate(truth.silhouette.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        uv = np.round(truth.joints_2d).astype(int)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < 320) & (uv[:, 1] >= 0) & (uv[:, 1] < 240)
        assert inside.all()
        assert sil[uv[:, 1], uv[:, 0]].all(), f"frame {i}: joints {np.nonzero(~sil[uv[:, 1], uv[:, 0]])[0]} outside"


def test_empty_prefix_shows_the_room_with_noise_only(scene: SyntheticScene) -> None:
    e0, e1, full = scene.frame(0), scene.frame(1), scene.frame(2)
    assert not e0.truth.present and not e0.truth.silhouette.any() and np.isnan(e0.truth.pose).all()
    d = np.abs(e0.image.astype(int) - e1.image.astype(int))
    assert 0.3 < d.mean() < 4.0  # sensor noise and exposure drift, no content change
    diff = np.abs(full.image.astype(int) - e0.image.astype(int)).sum(axis=2) > 40
    person = cv2.dilate(full.truth.silhouette.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    assert diff[person].mean() > 0.5  # the person stands out from the background ...
    assert diff[~person].mean() < 0.02  # ... and little else changed (a soft shadow at most)


def test_the_person_is_not_one_of_the_models() -> None:
    for seed in range(12):
        spec = random_subject_spec(np.random.default_rng(seed))
        assert 1.5 <= spec.height <= 1.95
        for m in BODY_MODELS:
            me = m.body.measurements
            assert max(abs(spec.height - me["height_m"]), abs(spec.chest - me["chest_m"]),
                       abs(spec.waist - me["waist_m"]), abs(spec.hip - me["hip_m"])) > 0.02
    subject = build_subject(random_subject_spec(np.random.default_rng(1)))
    assert len(subject.surface.faces) > 3000 and np.allclose(subject.weight.sum(axis=1), 1.0)
    verts, normals, _ = subject.pose_mesh(np.r_[0.0, 1.0, 0.0, np.zeros(57)])
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-9)
    assert verts[:, 1].max() == pytest.approx(subject.spec.height - subject.body.standing_root_height() + 1.0,
                                              abs=0.03)


def test_place_motion_faces_the_camera_and_centres(kick: Motion) -> None:
    placed = place_motion(kick.poses)
    fwd = rotvec_to_matrix(placed[0, 3:6])[:, 2]
    assert abs(fwd[0]) < 1e-9 and fwd[2] > 0  # heading towards the camera (tilt kept)
    lo, hi = placed[:, [0, 2]].min(axis=0), placed[:, [0, 2]].max(axis=0)
    np.testing.assert_allclose(lo + hi, 0.0, atol=1e-9)
    assert np.all(place_motion(kick.poses, in_place=True)[:, [0, 2]] == 0.0)


def test_jitter_and_distortion_keep_truth_aligned(kick: Motion) -> None:
    cfg = SceneConfig(camera_jitter_px=1.0, distortion=(-0.15, 0.02), noise=False)
    short = Motion(poses=kick.poses[:6], fps=kick.fps, name="short", body=kick.body)
    with SyntheticScene(short, seed=9, config=cfg) as s:
        shifts = [s.frame_camera(i).cx - s.camera.cx for i in range(6)]
        assert max(abs(x) for x in shifts) <= 1.0 and np.ptp(shifts) > 0
        for i in (0, 5):
            truth = s.frame(i).truth
            sil = cv2.dilate(truth.silhouette.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
            uv = np.round(truth.joints_2d).astype(int)
            assert sil[uv[:, 1], uv[:, 0]].mean() > 0.95


_HASH_SCRIPT = """
import hashlib
from protocol.formats.mocap_data import mocap_root
from tracker_service.scene.synthetic import SceneConfig, SyntheticScene
with SyntheticScene.from_file(mocap_root() / {kick!r}, seed=3, config=SceneConfig(empty_prefix=1)) as s:
    h = hashlib.sha256()
    for i in (0, 7, 40):
        f = s.frame(i)
        h.update(f.image.tobytes())
        h.update(f.truth.part_labels.tobytes())
print(h.hexdigest())
"""


def test_same_seed_same_frames_in_another_process() -> None:
    """Two processes (one with single-threaded rasterisation) render bit-identical frames and labels."""
    script = _HASH_SCRIPT.format(kick=KICK)
    root = Path(__file__).resolve().parents[3]
    here = subprocess.run([sys.executable, "-c", script], cwd=root, capture_output=True, text=True, check=True)
    there = subprocess.run([sys.executable, "-c", script], cwd=root, capture_output=True, text=True, check=True,
                           env={**os.environ, "LP_NUM_THREADS": "1"})
    assert len(here.stdout.strip()) == 64 and here.stdout == there.stdout
