"""A body built from measurements the user gives (Okada & Stenger §3: the body model may be chosen
"according to body height, chest size and weight ... entered by hand").

The paper snaps hand-entered measurements to the nearest of the 30 models. Here the measurements
build the body itself (:func:`~tracker_service.body.family.build_body`, the family's proportions
and radii), so a user who gives their height and their arm and leg proportions gets exactly that
skeleton in the published joints and templates scaled to exactly that height; measurements left
out are taken from the nearest family model. Over the 51 held-out takes, the leg proportion is
what the automatic selection cannot supply (``docs/TRACKER.md``, "What the hard takes look
like"): for a 1.84 m man with legs 4.5 % longer than the family's, his height alone takes MPJPE
from 9.32 to 9.30 cm and all his measurements to 8.43 cm, nearly all of it the ``leg`` ratio (the
ankles and toes sit where the leg length puts them below the pelvis, and a silhouette in trousers
does not show it).

The text form, for the command line (``--measurements``), is comma-separated ``key=value`` pairs:

========== ====================================================== =========
key        meaning                                                unit
========== ====================================================== =========
height     standing height (required)                             m
group      ``men``, ``women`` or ``children``                     --
chest      chest (bust) girth                                     m
waist      waist girth                                            m
hip        hip girth                                              m
weight     body mass (only used to choose the nearest model)      kg
shoulder   distance between the two shoulder joints               m
arm        arm length over the family's proportion (1.0 = same)   --
leg        leg length over the family's proportion (1.0 = same)   --
========== ====================================================== =========
"""

from __future__ import annotations

import math
from typing import Any, Final, cast

from protocol.skeleton import Body
from tracker_service.body.family import GROUPS, Group, build_body, select_body_model

__all__ = ["MEASUREMENT_KEYS", "given_body", "parse_measurements"]

#: Accepted keys of the text form and their valid ranges (inclusive).
MEASUREMENT_KEYS: Final[dict[str, tuple[float, float]]] = {
    "height": (0.8, 2.3), "chest": (0.4, 1.6), "waist": (0.35, 1.6), "hip": (0.45, 1.7),
    "weight": (10.0, 250.0), "shoulder": (0.15, 0.6), "arm": (0.8, 1.2), "leg": (0.8, 1.2),
}


def parse_measurements(text: str) -> dict[str, Any]:
    """Parse ``"height=1.83,chest=1.08,leg=1.04,group=men"``.

    Parameters
    ----------
    text : str

    Returns
    -------
    dict
        Numbers as float (metres, kilograms, ratios) and ``group`` as str.

    Raises
    ------
    ValueError
        On an unknown or repeated key, a value that is not a finite number in its range, an unknown
        group, or no ``height``; the message names the offending item.
    """
    out: dict[str, Any] = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        key, sep, value = item.partition("=")
        key, value = key.strip().lower(), value.strip()
        if not sep or not value:
            raise ValueError(f"measurement {item!r} is not key=value")
        if key in out:
            raise ValueError(f"measurement {key!r} given twice")
        if key == "group":
            if value not in GROUPS:
                raise ValueError(f"unknown group {value!r}; choose from {', '.join(GROUPS)}")
            out[key] = value
            continue
        if key not in MEASUREMENT_KEYS:
            raise ValueError(f"unknown measurement {key!r}; known: group, {', '.join(MEASUREMENT_KEYS)}")
        try:
            x = float(value)
        except ValueError:
            raise ValueError(f"measurement {key}={value!r} is not a number") from None
        lo, hi = MEASUREMENT_KEYS[key]
        if not (math.isfinite(x) and lo <= x <= hi):
            raise ValueError(f"measurement {key}={value} outside {lo:g}-{hi:g}")
        out[key] = x
    if "height" not in out:
        raise ValueError("measurements need at least height=<metres>")
    return out


def given_body(measurements: dict[str, Any], name: str = "given") -> Body:
    """The body of the given measurements (keys as :func:`parse_measurements` returns them).

    The nearest family model (by height, chest and weight, within ``group`` if given) supplies the
    group and every girth not given; its girths are scaled by the height ratio so that the
    proportions stay the model's. ``shoulder`` is the joint spacing (``shoulder_width_m`` of the
    family's ``Body.measurements``).

    Parameters
    ----------
    measurements : dict
    name : str
        The body's name (published in ``BodyInfo``).

    Returns
    -------
    Body
        ``measurements`` of the result hold the height and the three girths actually used.
    """
    m = dict(measurements)
    h = float(m["height"])
    group = cast(Group | None, m.get("group"))
    near = select_body_model(h, m.get("chest"), m.get("weight"), group=group)
    k = h / near.body.height
    girth = {key: float(m[key]) if key in m else k * float(near.body.measurements[f"{key}_m"])
             for key in ("chest", "waist", "hip")}
    shoulder = float(m["shoulder"]) / h if "shoulder" in m else None
    return build_body(name, near.group, h, girth["chest"], girth["waist"], girth["hip"],
                      arm_ratio=float(m.get("arm", 1.0)), leg_ratio=float(m.get("leg", 1.0)),
                      shoulder_frac=shoulder)
