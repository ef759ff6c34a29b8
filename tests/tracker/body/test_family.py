"""The 30-model body family: counts, names, size ordering, selection by measurements, BodyInfo."""

from __future__ import annotations

import re

import numpy as np
import pytest

from protocol.kinematics import fk
from protocol.skeleton import CAPSULES, JOINT_INDEX, standing_pose
from protocol.wire.codec import decode, encode
from protocol.wire.messages import BodyInfo, body_from_body_info
from tracker_service.body.family import (
    BODY_MODELS,
    body_model,
    build_body,
    ellipse_axes,
    estimate_weight,
    markdown_table,
    model_body_info,
    select_body_model,
)
from tracker_service.body.mesh import BodyMesh

HEIGHT_ORDER = "PSMLT"
CHEST_ORDER = "YABE"
_CAP = [c[0] for c in CAPSULES]


def test_family_has_the_papers_counts_and_names() -> None:
    groups = [m.group for m in BODY_MODELS]
    assert (groups.count("men"), groups.count("women"), groups.count("children")) == (10, 14, 6)
    names = [m.name for m in BODY_MODELS]
    assert len(set(names)) == 30
    for m in BODY_MODELS:
        assert re.fullmatch(r"[mwc][PSMLT][YABE]", m.name), m.name
        assert m.name[0] == {"men": "m", "women": "w", "children": "c"}[m.group]
        assert m.body.name == m.name
    for name in ("mMA", "mMB", "mLY"):  # the models named in the paper's Fig. 6
        assert body_model(name).group == "men"
    with pytest.raises(KeyError, match="known"):
        body_model("xXX")


@pytest.mark.parametrize("group", ["men", "women", "children"])
def test_taller_and_larger_classes_really_are(group: str) -> None:
    ms = [m for m in BODY_MODELS if m.group == group]
    for a in ms:
        for b in ms:
            ha, hb = HEIGHT_ORDER.index(a.height_class), HEIGHT_ORDER.index(b.height_class)
            ca, cb = CHEST_ORDER.index(a.chest_class), CHEST_ORDER.index(b.chest_class)
            if ha < hb:  # taller class: taller, longer legs and arms
                assert a.height_m < b.height_m
                assert a.body.leg_length < b.body.leg_length
                assert a.body.bone_lengths[JOINT_INDEX["l_elbow"]] < b.body.bone_lengths[JOINT_INDEX["l_elbow"]]
            if ha == hb and ca < cb:  # larger chest class at the same height: larger and heavier
                assert a.chest_m < b.chest_m
                assert a.weight_kg < b.weight_kg
                assert a.body.capsule_radii[_CAP.index("thorax"), 0] < b.body.capsule_radii[_CAP.index("thorax"), 0]
                assert a.body.capsule_radii[_CAP.index("l_thigh"), 0] <= b.body.capsule_radii[_CAP.index("l_thigh"), 0]


def test_groups_differ_as_people_do() -> None:
    men = [m for m in BODY_MODELS if m.group == "men"]
    women = [m for m in BODY_MODELS if m.group == "women"]
    kids = [m for m in BODY_MODELS if m.group == "children"]
    assert max(k.height_m for k in kids) < min(m.height_m for m in men)
    assert np.mean([m.height_m for m in men]) > np.mean([w.height_m for w in women])
    # children have relatively larger heads
    skull = _CAP.index("skull")
    ratio = [m.body.capsule_radii[skull, 1] / m.height_m for m in BODY_MODELS]
    assert min(r for r, m in zip(ratio, BODY_MODELS, strict=True) if m.group == "children") > \
        max(r for r, m in zip(ratio, BODY_MODELS, strict=True) if m.group != "children")
    for m in men + women:  # plausible adult weights
        bmi = m.weight_kg / m.height_m**2
        assert 18.5 < bmi < 27.0, (m.name, bmi)


def test_crown_of_every_model_is_at_its_height() -> None:
    for m in BODY_MODELS:
        joints = fk(standing_pose(m.body), m.body)
        verts, _ = BodyMesh(m.body).vertices(joints)
        assert abs(verts[:, 1].max() - m.height_m) < 0.01, m.name
        assert abs(verts[:, 1].min()) < 0.01, m.name  # feet on the floor


def test_selection_from_measurements() -> None:
    assert select_body_model(1.70, 0.92, 64.5).name == "mMA"
    assert select_body_model(1.75, 0.90).name == "mLY"
    assert select_body_model(1.58, 0.83, group="women").name == "wMA"
    assert select_body_model(1.21, 0.61).name == "cSA"
    assert select_body_model(1.80).name == "mTA"
    # a heavier man of the same height and chest gets the bigger model
    assert select_body_model(1.70, 0.95, 75.0).name == "mMB"
    with pytest.raises(ValueError):
        select_body_model(3.0)
    with pytest.raises(ValueError):
        select_body_model(1.7, group="robots")  # type: ignore[arg-type]


def test_every_model_selects_itself() -> None:
    for m in BODY_MODELS:
        assert select_body_model(m.height_m, m.chest_m, m.weight_kg, group=m.group).name == m.name


def test_body_info_rebuilds_the_avatar() -> None:
    m = body_model("wTB")
    info = model_body_info(m, "cam0")
    assert isinstance(info, BodyInfo)
    assert info.body_model == "wTB"
    assert decode(encode(info), BodyInfo) == info
    back = body_from_body_info(info)
    pose = standing_pose(m.body)
    np.testing.assert_allclose(fk(pose, back), fk(pose, m.body), atol=1e-5)
    np.testing.assert_allclose(info.capsule_radii, m.body.capsule_radii, atol=1e-7)
    assert info.measurements["weight_kg"] == pytest.approx(m.weight_kg)


def test_helpers() -> None:
    a, b = ellipse_axes(0.9, 1.3)
    assert a / b == pytest.approx(1.3)
    circ = np.pi * (3 * (a + b) - np.sqrt((3 * a + b) * (a + 3 * b)))
    assert circ == pytest.approx(0.9)
    assert estimate_weight(1.70, 0.92, 0.80, 0.92) == pytest.approx(64.5, abs=0.2)
    body = build_body("x", "women", 1.64, 0.86, 0.68, 0.95, arm_ratio=1.05)
    ref = build_body("y", "women", 1.64, 0.86, 0.68, 0.95)
    assert body.bone_lengths[JOINT_INDEX["l_elbow"]] > ref.bone_lengths[JOINT_INDEX["l_elbow"]]
    table = markdown_table()
    assert table.count("\n") == 32 and "| mMA | men | A4 | 170 |" in table
