"""The subject's bone proportions from the appearance cue's readings: bone lengths of a reading,
ratios (median, symmetric, clipped, only the adapted bones), the adapted body, and the pipeline
switching the published skeleton once."""

from __future__ import annotations

import numpy as np
import pytest

from protocol import fk
from protocol.skeleton import JOINT_INDEX, N_JOINTS, default_body, standing_pose
from tracker_service.body.proportions import (
    ADAPTED_BONES,
    ProportionParams,
    adapt_body,
    bone_lengths_read,
    proportion_ratios,
)


def _reading(body, pose=None) -> np.ndarray:  # type: ignore[no-untyped-def]
    j = fk(standing_pose(body) if pose is None else pose, body)
    return (j - j[0]) / body.height


def test_bone_lengths_of_a_reading_are_the_bodys() -> None:
    body = default_body()
    got = bone_lengths_read(_reading(body), body.height)
    assert got[0] == 0.0
    assert np.allclose(got, body.bone_lengths)


def test_ratios_are_median_symmetric_clipped_and_only_for_adapted_bones(rng: np.random.Generator) -> None:
    body = default_body()
    j = JOINT_INDEX
    true = np.ones(N_JOINTS)
    true[[j["spine"], j["chest"], j["neck"]]] = 0.95  # a shorter torso
    true[[j["l_knee"], j["r_knee"]]] = 1.04  # longer thighs
    true[j["l_elbow"]], true[j["r_elbow"]] = 1.02, 1.06  # asymmetric readings: their mean
    true[j["l_ankle"]] = true[j["r_ankle"]] = 1.5  # beyond max_change: clipped
    true[j["l_wrist"]] = 0.8  # not an adapted bone: kept
    frames = body.bone_lengths * true * (1.0 + rng.normal(0, 0.01, (41, N_JOINTS)))
    frames[3] = frames[3] * 3.0  # one wild frame: the median ignores it
    frames[5, 4] = np.nan  # a non-finite reading is dropped
    r = proportion_ratios(frames, body, ProportionParams(max_change=0.15))
    assert np.allclose(r[[j["spine"], j["chest"], j["neck"]]], 0.95, atol=0.01)
    assert np.allclose(r[[j["l_knee"], j["r_knee"]]], 1.04, atol=0.01)
    assert r[j["l_elbow"]] == r[j["r_elbow"]] and abs(r[j["l_elbow"]] - 1.04) < 0.01
    assert r[j["l_ankle"]] == r[j["r_ankle"]] == pytest.approx(1.15)
    kept = [k for k in range(N_JOINTS) if k not in [j[n] for n in ADAPTED_BONES]]
    assert np.array_equal(r[kept], np.ones(len(kept)))
    assert np.array_equal(proportion_ratios(np.full((3, N_JOINTS), np.nan), body, ProportionParams()),
                          np.ones(N_JOINTS))


def test_adapted_body_keeps_stature_and_scales_bones() -> None:
    body = default_body()
    r = np.ones(N_JOINTS)
    r[JOINT_INDEX["spine"]] = 0.9
    new = adapt_body(body, r)
    assert new.name == body.name and new.height == pytest.approx(body.height)
    assert new.bone_lengths[JOINT_INDEX["spine"]] == pytest.approx(0.9 * body.bone_lengths[JOINT_INDEX["spine"]])
    spine = JOINT_INDEX["spine"]
    assert np.array_equal(np.delete(new.offsets, spine, 0), np.delete(body.offsets, spine, 0))
    for bad in (np.ones(3), np.zeros(N_JOINTS), np.full(N_JOINTS, np.nan)):
        with pytest.raises(ValueError):
            adapt_body(body, bad)
    with pytest.raises(ValueError):
        ProportionParams(frames=0)
    with pytest.raises(ValueError):
        ProportionParams(max_change=1.0)


def test_the_pipeline_publishes_the_read_proportions_once(small_db, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    """A network that reads a body with a 10 % shorter spine and 8 % longer shins: after
    ``frames`` frames of tracking the published skeleton has them (``body_changed`` on that frame
    only); without the cue, or with ``proportions=None``, the model's skeleton stays."""
    from conftest import constant_reading_net

    from protocol.motion import ground
    from tracker_service.body.raster import render_silhouette
    from tracker_service.pipeline.process import TrackerConfig, new_state, process_frame
    from tracker_service.templates.database import load_db

    _, _, motions, _, path = small_db
    loaded = load_db(path)
    db, cam = loaded.db, loaded.camera
    truth = fk(ground(motions[0].poses, loaded.body), loaded.body)
    want = np.ones(N_JOINTS)
    want[[JOINT_INDEX["spine"], JOINT_INDEX["chest"]]] = 0.9
    want[[JOINT_INDEX["l_ankle"], JOINT_INDEX["r_ankle"]]] = 1.08
    subject = adapt_body(loaded.body, want)
    net = constant_reading_net(_reading(subject), log_var=-7.0)
    room = np.full((cam.height, cam.width, 3), (170, 175, 160), np.float32)
    masks = [render_silhouette(truth[f], loaded.body.capsule_radii, cam) for f in range(0, 40, 2)]

    def frame(mask: np.ndarray | None) -> np.ndarray:
        img = room.copy()
        if mask is not None:
            img[mask] = (40, 60, 200)
        return np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)

    frames = [frame(None) for _ in range(6)] + [frame(m) for m in masks]

    def run(cfg: TrackerConfig, clip: list[np.ndarray] = frames):  # type: ignore[no-untyped-def]
        st = new_state(loaded.body)
        changed = []
        for i, img in enumerate(clip):
            st, res = process_frame(st, img, db, loaded.body, cam, cfg, i / 30)
            changed.append(res.body_changed)
        return st, changed

    base = TrackerConfig(background_frames=6, init_frames=3, appearance=net,
                         proportions=ProportionParams(frames=5))
    st, changed = run(base)
    assert sum(changed) == 1 and st.proportions_set
    adapted = [JOINT_INDEX[n] for n in ADAPTED_BONES]
    got = st.body.bone_lengths[adapted] / loaded.body.bone_lengths[adapted]
    assert np.allclose(got, want[adapted], atol=0.02)
    assert st.body.height == pytest.approx(loaded.body.height)
    for cfg in (TrackerConfig(background_frames=6, init_frames=3, proportions=ProportionParams(frames=5)),
                TrackerConfig(background_frames=6, init_frames=3, appearance=net, proportions=None)):
        st, changed = run(cfg)
        assert not any(changed) and np.array_equal(st.body.offsets, loaded.body.offsets)
    # the person leaves and comes back: read again, relative to the model (not compounded)
    st, changed = run(base, frames + [frame(None) for _ in range(3)] + [frame(m) for m in masks])
    assert sum(changed) == 2 and st.proportions_set
    got = st.body.bone_lengths[adapted] / loaded.body.bone_lengths[adapted]
    assert np.allclose(got, want[adapted], atol=0.02)
