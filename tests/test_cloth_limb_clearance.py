"""Sunk forearms and hands turned out of the trunk (``cloth_client.limb_clearance``): the kernel
against its numpy reference, the geometry it keeps, continuity, and a skirt under a sunk forearm."""

from __future__ import annotations

import numpy as np
import pytest
from test_cloth_driver import _dance

from cloth_client.avatar import avatar_capsules, capsule_endpoints
from cloth_client.cloth import structural_strain
from cloth_client.collision import penetration_np
from cloth_client.driver import ClothDriver, DriverConfig
from cloth_client.garment import make_skirt
from cloth_client.limb_clearance import ARMS, LIMB_CLEARANCE, LIMBS, MAX_PUSH, clear_limbs, limb_overlap
from protocol.skeleton import CAPSULE_INDEX, default_body, standing_pose

BODY = default_body()
R = BODY.capsule_radii
L_FORE, L_HAND = list(LIMBS).index(CAPSULE_INDEX["l_forearm"]), list(LIMBS).index(CAPSULE_INDEX["l_hand"])


def _swing(t0: float, t1: float, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Capsules of the synthetic motion whose left forearm swings through the hips at t = 0.5-1 s."""
    a, b = capsule_endpoints(BODY, _dance(np.arange(t0, t1, 1.0 / rate)))
    return a, b


def test_kernel_matches_the_numpy_reference() -> None:
    a, b = _swing(0.0, 1.5, 60.0)
    rng = np.random.default_rng(3)
    a = a + rng.normal(0.0, 0.01, a.shape)  # capsules no longer joined: the rule must not care
    b = b + rng.normal(0.0, 0.01, b.shape)
    an, bn = clear_limbs(a, b, R, backend="numba")
    ar, br = clear_limbs(a, b, R, backend="numpy")
    assert np.abs(an - a).max() > 0.05  # the motion does need clearing
    np.testing.assert_allclose(an, ar, atol=1e-9)
    np.testing.assert_allclose(bn, br, atol=1e-9)
    a1, b1 = clear_limbs(a[40], b[40], R)  # one pose (C, 3)
    np.testing.assert_allclose(a1, an[40], atol=1e-12)
    np.testing.assert_allclose(b1, bn[40], atol=1e-12)
    with pytest.raises(ValueError, match="backend"):
        clear_limbs(a, b, R, backend="cuda")


def test_a_sunk_limb_is_turned_out_with_every_length_kept() -> None:
    a, b = _swing(0.45, 1.1, 120.0)
    ac, bc = clear_limbs(a, b, R)
    before = np.array([limb_overlap(a[k], b[k], R) for k in range(len(a))])
    after = np.array([limb_overlap(ac[k], bc[k], R) for k in range(len(a))])
    # every limb whose whole correction stays well inside the push limit ends clear of the trunk
    easy = (before > -LIMB_CLEARANCE) & (before + LIMB_CLEARANCE < 0.5 * MAX_PUSH)
    easy &= (before[:, [L_FORE, L_FORE, L_FORE + 2, L_FORE + 2]] + LIMB_CLEARANCE <= MAX_PUSH)  # side not skipped
    assert easy[:, L_FORE].sum() >= 3 and easy[:, L_HAND].sum() >= 3
    assert np.all(after[easy] <= -LIMB_CLEARANCE + 1e-3)
    np.testing.assert_allclose(np.linalg.norm(bc - ac, axis=-1), np.linalg.norm(b - a, axis=-1), atol=1e-9)
    for up, fore, hand in ARMS:  # the chains stay joined, the shoulders stay put
        np.testing.assert_allclose(bc[:, up], ac[:, fore], atol=1e-12)
        np.testing.assert_allclose(bc[:, fore], ac[:, hand], atol=1e-12)
        np.testing.assert_array_equal(ac[:, up], a[:, up])
    others = np.setdiff1d(np.arange(a.shape[1]), ARMS.ravel())
    np.testing.assert_array_equal(ac[:, others], a[:, others])
    np.testing.assert_array_equal(bc[:, others], b[:, others])


def test_clear_limbs_and_limbs_too_deep_are_left_alone() -> None:
    a, b = capsule_endpoints(BODY, standing_pose(BODY))
    ac, bc = clear_limbs(a, b, R)
    np.testing.assert_array_equal(ac, a)
    np.testing.assert_array_equal(bc, b)
    a, b = _swing(0.65, 0.66, 100.0)  # the forearm 14 cm deep in the pelvis: no continuous way out
    assert limb_overlap(a[0], b[0], R)[L_FORE] + LIMB_CLEARANCE > MAX_PUSH
    ac, bc = clear_limbs(a, b, R)
    fore = CAPSULE_INDEX["l_forearm"]
    np.testing.assert_array_equal(ac[0, fore], a[0, fore])
    np.testing.assert_array_equal(bc[0, fore], b[0, fore])


def test_the_correction_grows_continuously_from_zero() -> None:
    """As the forearm sinks, the corrected arm moves no more than a few times the recorded one per
    step: no jump where the clearance starts acting."""
    a, b = _swing(0.46, 0.53, 2000.0)  # up to a 9 cm push, short of MAX_PUSH
    _, bc = clear_limbs(a, b, R)
    raw = np.abs(np.diff(b, axis=0)).max()
    fixed = np.abs(np.diff(bc, axis=0)).max()
    assert np.abs(bc - b).max() > 0.03 and fixed < 4.0 * raw


def test_skirt_under_a_forearm_held_in_the_hips() -> None:
    """A forearm held 6 cm deep in the pelvis for a second: the avatar's forearm is turned out and
    the skirt stays outside it and the hips, unstretched (without the rule the forearm is ghosted
    and the cloth left inside it)."""
    pose = _dance(np.array([0.54]))[0]
    assert limb_overlap(*capsule_endpoints(BODY, pose), R)[L_FORE] > 0.05
    t = np.arange(0.0, 1.0, 1.0 / 60.0)
    runs = {}
    for clearance in (LIMB_CLEARANCE, None):
        d = ClothDriver(BODY, make_skirt(BODY, 500), config=DriverConfig(dress_s=0.2, settle_s=0.2,
                                                                         limb_clearance=clearance))
        for ti in t:
            d.feed(pose, float(ti))
        runs[clearance] = d
    d = runs[LIMB_CLEARANCE]
    assert d.state is not None and not d._ghost.any()
    a, b = avatar_capsules(BODY, pose)
    depth = penetration_np(d.state.x, a, b, R, d.model.inv_mass > 0)
    assert depth.max() < 0.005
    assert structural_strain(d.model, d.state.x).max() < 0.10
    assert runs[None]._ghost.any()
