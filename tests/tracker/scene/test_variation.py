"""Domain randomisation of the synthetic scene: every axis varies what it says, a fixed seed gives
the same frames, and the default scene is untouched."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from protocol import fk
from protocol.skeleton import JOINT_INDEX, standing_pose
from tracker_service.body.family import body_model
from tracker_service.scene.subject import random_subject_spec
from tracker_service.scene.synthetic import SceneConfig, SyntheticScene, scene_subject, stooped
from tracker_service.scene.variation import (
    AXES,
    SceneVariation,
    backdrop_texture,
    degrade_frame,
    h264_roundtrip,
    parse_axes,
    vary_subject,
)

SCRIPT = Path(__file__).resolve().parents[3] / "protocol" / "scripts" / "crouch.toml"


def test_parse_axes() -> None:
    assert parse_axes("all") == AXES
    assert parse_axes("lights, body,lights") == ("lights", "body")
    assert parse_axes("") == ()
    with pytest.raises(ValueError, match="unknown variation axis hat"):
        parse_axes("body,hat")


def test_body_axis_draws_beyond_the_adult_family() -> None:
    kinds = set()
    for seed in range(40):
        base = random_subject_spec(np.random.default_rng([seed, 0]))
        spec = vary_subject(base, ("body",), np.random.default_rng([seed, 3, 0]))
        if spec.group == "children":
            kinds.add("child")
            assert 1.10 <= spec.height <= 1.45
        elif spec.height >= 1.92:
            kinds.add("tall")
        elif spec.stoop > 0:
            kinds.add("elderly")
            assert np.radians(10) <= spec.stoop <= np.radians(22)
        elif spec.chest > base.chest * 1.2:
            kinds.add("heavy")
        elif spec.chest < base.chest * 0.9:
            kinds.add("thin")
    assert kinds == {"child", "tall", "elderly", "heavy", "thin"}


def test_each_axis_changes_only_its_own_things() -> None:
    base, none = scene_subject(3)
    assert none == SceneVariation()
    for axis in AXES:
        spec, var = scene_subject(3, (axis,))
        assert scene_subject(3, (axis,)) == (spec, var)  # a fixed seed, the same draw
        person = axis in ("body", "clothing", "appearance")
        assert (spec != base) == person or axis == "body", axis  # an elderly draw may only stoop
        assert (var.lights != "default") == (axis == "lights")
        assert (var.noise_scale > 1) == (var.blur_px > 0) == (axis == "sensor")
        assert (var.codec != "none") == (axis == "compression")


def test_stoop_lowers_the_head() -> None:
    b = body_model("mMA").body
    pose = standing_pose(b)[None]
    head = JOINT_INDEX["head_top"]
    bent = stooped(pose, np.radians(20))
    assert fk(bent[0], b)[head, 1] < fk(pose[0], b)[head, 1] - 0.01
    assert np.array_equal(stooped(pose, 0.0), pose)


def test_backdrop_is_a_photograph_or_a_collage_and_reproducible() -> None:
    a = backdrop_texture(np.random.default_rng(4))
    assert a.shape == (384, 512, 3) and a.dtype == np.uint8
    assert np.array_equal(a, backdrop_texture(np.random.default_rng(4)))
    assert a.std() > 20  # texture, not a flat wall


def test_degradations_keep_the_picture() -> None:
    rng = np.random.default_rng(0)
    img = np.zeros((120, 160, 3), np.uint8)
    img[30:90, 50:110] = (40, 180, 220)
    img += rng.integers(0, 20, img.shape, dtype=np.uint8)
    h264 = h264_roundtrip(img, 30)
    assert h264.shape == img.shape and not np.array_equal(h264, img)
    assert np.abs(h264.astype(int) - img).mean() < 6
    blur = degrade_frame(img, SceneVariation(axes=("sensor",), blur_px=7.0), np.random.default_rng(1))
    assert np.abs(blur.astype(int) - img).max() > 50  # the edges smeared
    assert np.array_equal(blur, degrade_frame(img, SceneVariation(axes=("sensor",), blur_px=7.0),
                                              np.random.default_rng(1)))
    jpeg = degrade_frame(img, SceneVariation(axes=("compression",), codec="jpeg", quality=40), rng)
    assert np.abs(jpeg.astype(int) - img).mean() < 8


def test_varied_scene_frames_are_reproducible_and_differ_from_the_default() -> None:
    cfg = SceneConfig(variation=AXES)
    with SyntheticScene.from_file(SCRIPT, seed=2, config=cfg) as a:
        fa = a.frame(5)
    with SyntheticScene.from_file(SCRIPT, seed=2, config=cfg) as b:
        fb = b.frame(5)
    with SyntheticScene.from_file(SCRIPT, seed=2) as d:
        fd = d.frame(5)
    assert np.array_equal(fa.image, fb.image)
    assert np.array_equal(fa.truth.joints, fb.truth.joints)
    assert np.abs(fa.image.astype(int) - fd.image).mean() > 10
