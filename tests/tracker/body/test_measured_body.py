"""A body from the user's measurements (``--measurements``): parsing, and the body it builds."""

import numpy as np
import pytest

from protocol.skeleton import JOINT_INDEX
from tracker_service.body.family import build_body, select_body_model
from tracker_service.body.measured import given_body, parse_measurements


@pytest.mark.parametrize(("text", "expected"), [
    ("height=1.83", {"height": 1.83}),
    (" height = 1.6 , group=women, chest=0.86 ,", {"height": 1.6, "group": "women", "chest": 0.86}),
    ("HEIGHT=1.7,arm=0.96,leg=1.04,shoulder=0.36,weight=70,waist=0.8,hip=0.95",
     {"height": 1.7, "arm": 0.96, "leg": 1.04, "shoulder": 0.36, "weight": 70.0, "waist": 0.8, "hip": 0.95}),
])
def test_parse(text: str, expected: dict[str, object]) -> None:
    assert parse_measurements(text) == expected


@pytest.mark.parametrize(("text", "match"), [
    ("", "at least height"),
    ("chest=1.0", "at least height"),
    ("height", "not key=value"),
    ("height=", "not key=value"),
    ("height=1.7,height=1.8", "twice"),
    ("height=1.7,inseam=0.8", "unknown measurement 'inseam'"),
    ("height=tall", "not a number"),
    ("height=nan", "outside"),
    ("height=3", "outside"),
    ("height=1.7,leg=1.5", "outside"),
    ("height=1.7,group=robots", "unknown group"),
])
def test_parse_rejects(text: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        parse_measurements(text)


def test_all_measurements_build_exactly_that_body() -> None:
    m = parse_measurements("height=1.83,group=men,chest=1.05,waist=0.9,hip=1.0,shoulder=0.375,arm=0.96,leg=1.045")
    b = given_body(m)
    ref = build_body("given", "men", 1.83, 1.05, 0.9, 1.0, arm_ratio=0.96, leg_ratio=1.045, shoulder_frac=0.375 / 1.83)
    np.testing.assert_allclose(b.offsets, ref.offsets)
    np.testing.assert_allclose(b.capsule_radii, ref.capsule_radii)
    assert b.name == "given" and b.height == pytest.approx(1.83)
    assert b.measurements["shoulder_width_m"] == pytest.approx(0.375)


def test_missing_measurements_come_from_the_nearest_model_and_proportions_change_the_limbs() -> None:
    b = given_body({"height": 1.72})
    near = select_body_model(1.72)
    k = 1.72 / near.body.height
    for key in ("chest_m", "waist_m", "hip_m"):
        assert b.measurements[key] == pytest.approx(k * near.body.measurements[key])
    assert b.height == pytest.approx(1.72)
    # a longer leg ratio: longer thigh and shin, the same stature
    long_legs = given_body({"height": 1.72, "leg": 1.05})
    knee, ankle = JOINT_INDEX["l_knee"], JOINT_INDEX["l_ankle"]
    for j in (knee, ankle):
        assert long_legs.bone_lengths[j] == pytest.approx(1.05 * b.bone_lengths[j])
    assert long_legs.height == pytest.approx(b.height)
    # the group limits the nearest model
    men = select_body_model(1.58, group="men")
    assert men.group == "men" and select_body_model(1.58).group != "men"
    assert given_body({"height": 1.58, "group": "men"}).measurements["chest_m"] == pytest.approx(
        1.58 / men.body.height * men.chest_m)
