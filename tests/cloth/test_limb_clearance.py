"""Sunk forearms and hands turned out of the trunk (``cloth_client.avatar.limb_clearance``): the kernel
against its numpy reference, the geometry it keeps, continuity, and a skirt under a sunk forearm."""

from __future__ import annotations

import numpy as np
import pytest
from test_driver import _dance

from cloth_client.avatar.capsules import avatar_capsules, capsule_endpoints, rigid_root_delta
from cloth_client.avatar.limb_clearance import (
    ARMS,
    LIMB_CLEARANCE,
    LIMBS,
    MAX_PUSH,
    clear_limbs,
    clear_limbs_track,
    clear_limbs_track_reference,
    limb_overlap,
    limb_overlap_reference,
)
from cloth_client.contact.collision import penetration_reference
from cloth_client.solver.cloth import structural_strain
from cloth_client.solver.driver import ClothDriver, DriverConfig
from cloth_client.solver.garment import make_skirt
from protocol.skeleton import CAPSULE_INDEX, default_body, standing_pose

BODY = default_body()
R = BODY.capsule_radii
L_FORE, L_HAND = list(LIMBS).index(CAPSULE_INDEX["l_forearm"]), list(LIMBS).index(CAPSULE_INDEX["l_hand"])
#: The numba rule and its plain numpy reference, by the name tests are parametrised with.
TRACKS = {"numba": clear_limbs_track, "numpy": clear_limbs_track_reference}


def _swing(t0: float, t1: float, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Capsules of the synthetic motion whose left forearm swings through the hips at t = 0.5-1 s."""
    a, b = capsule_endpoints(BODY, _dance(np.arange(t0, t1, 1.0 / rate)))
    return a, b


def test_kernel_matches_the_numpy_reference() -> None:
    a, b = _swing(0.0, 1.5, 60.0)
    rng = np.random.default_rng(3)
    a = a + rng.normal(0.0, 0.01, a.shape)  # capsules no longer joined: the rule must not care
    b = b + rng.normal(0.0, 0.01, b.shape)
    an, bn = clear_limbs(a, b, R)
    ar, br, _ = clear_limbs_track_reference(a, b, R)
    bn_all = bn
    assert np.abs(an - a).max() > 0.05  # the motion does need clearing
    np.testing.assert_allclose(an, ar, atol=1e-9)
    np.testing.assert_allclose(bn, br, atol=1e-9)
    _, _, memory = clear_limbs_track(a[:40], b[:40], R)  # carried over: one pose (C, 3) continues the run
    a1, b1, _ = clear_limbs_track(a[40], b[40], R, memory)
    np.testing.assert_allclose(a1, an[40], atol=1e-12)
    np.testing.assert_allclose(b1, bn[40], atol=1e-12)
    for backend in ("numba", "numpy"):  # the memory out of the kernel and out of the reference agree
        _, _, m = TRACKS[backend](a[:40], b[:40], R)
        np.testing.assert_allclose(m, memory, atol=1e-9)
    # a run continued from its memory (its first key given), and a lower push limit that skips a
    # side while it carries a correction: both backends alike
    runs = {backend: [track(a[39:], b[39:], R, memory, first_given=True), track(a, b, R, max_push=0.10)]
            for backend, track in TRACKS.items()}
    for (an, bn, mn), (ar, br, mr) in zip(runs["numba"], runs["numpy"], strict=True):
        np.testing.assert_allclose(an, ar, atol=1e-9)
        np.testing.assert_allclose(bn, br, atol=1e-9)
        np.testing.assert_allclose(mn, mr, atol=1e-9)
    np.testing.assert_allclose(runs["numba"][0][1][1:], bn_all[40:], atol=1e-12)
    for track in TRACKS.values():
        with pytest.raises(ValueError, match="shape"):
            track(a, b, R, np.zeros((6, 3)))


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
    a, b = _swing(0.65, 0.66, 100.0)  # the forearm 14 cm deep in the pelvis
    push = limb_overlap(a[0], b[0], R)[L_FORE] + LIMB_CLEARANCE
    assert 0.10 < push < MAX_PUSH  # turned out with the default limit
    fore = CAPSULE_INDEX["l_forearm"]
    assert np.abs(clear_limbs(a, b, R)[1][0, fore] - b[0, fore]).max() > 0.05
    ac, bc = clear_limbs(a, b, R, max_push=0.10)  # beyond a lower one: left as recorded
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


def test_a_corrected_limb_moves_as_smoothly_as_the_recorded_one() -> None:
    """The forearm swinging through the hips, keys at the driver's 240 Hz: wherever the corrected
    arm is clear of the trunk on two consecutive keys, its forearm and hand move at most a little
    more than the recorded ones, and the hand never turns back where the recorded one does not.
    Started afresh at every key, the rule put the arm on whichever side the nearest surface (or the
    last of alternate pushes out of hip and thigh) pointed to: jumps of 18 cm between keys."""
    a, b = _swing(0.4, 1.2, 240.0)
    ac, bc = clear_limbs(a, b, R)
    after = np.array([limb_overlap(ac[k], bc[k], R) for k in range(len(a))])
    clear = (after[:, [L_FORE, L_HAND]] <= 0.0).all(axis=1)
    both = clear[1:] & clear[:-1]
    limbs = LIMBS[[L_FORE, L_HAND]]
    raw = np.linalg.norm(np.diff(b[:, limbs], axis=0), axis=-1).max(axis=1)
    fixed = np.linalg.norm(np.diff(bc[:, limbs], axis=0), axis=-1).max(axis=1)
    corrected = np.abs(bc - b).max(axis=(1, 2)) > 0.01
    assert (corrected[1:] & both).sum() >= 80  # the swing is corrected and clear over many keys
    assert (fixed - raw)[both].max() < 0.02
    v, rv = np.diff(bc[:, limbs[1]], axis=0), np.diff(b[:, limbs[1]], axis=0)  # hand tip steps
    turns = ((v[1:] * v[:-1]).sum(axis=1) < 0.0) & (np.linalg.norm(v[1:], axis=1) > 0.005)
    assert not (turns & ((rv[1:] * rv[:-1]).sum(axis=1) > 0.0)).any()
    # keys passed one call at a time, with the memory, give the same avatar as one call
    memory = None
    for k in range(len(a)):
        _, b1, memory = clear_limbs_track(a[k], b[k], R, memory)
        np.testing.assert_allclose(b1, bc[k], atol=1e-12)
    # as the cloth driver calls it: steps of keys, each starting at the previous step's last key
    _, b0, memory = clear_limbs_track(a[:8], b[:8], R)
    parts = [b0]
    for k0 in range(7, len(a) - 1, 7):
        _, b1, memory = clear_limbs_track(a[k0:k0 + 8], b[k0:k0 + 8], R, memory, first_given=True)
        np.testing.assert_allclose(b1[0], parts[-1][-1], atol=1e-12)  # the shared key is not corrected twice
        parts.append(b1[1:])
    np.testing.assert_allclose(np.concatenate(parts), bc[:sum(len(p) for p in parts)], atol=1e-12)


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
    depth = penetration_reference(d.state.x, a, b, R, d.model.inv_mass > 0)
    assert depth.max() < 0.005
    assert structural_strain(d.model, d.state.x).max() < 0.10
    assert runs[None]._ghost.any()


def test_the_driver_carries_the_correction_and_draws_it() -> None:
    """The cloth driver keeps the sunk-limb correction from step to step (the avatar it simulates
    is the one the renderer gets), and a reset moves the carried correction with the root."""
    d = ClothDriver(BODY, make_skirt(BODY, 300), config=DriverConfig(dress_s=0.1, settle_s=0.1))
    fore = CAPSULE_INDEX["l_forearm"]
    for ti in np.arange(0.45, 0.62, 1.0 / 60.0):
        pose = _dance(np.array([ti]))[0]
        d.feed(pose, float(ti))
    assert d.body_capsules is not None and d._limb_memory is not None
    a_raw, b_raw = capsule_endpoints(BODY, pose)
    assert limb_overlap(a_raw, b_raw, R)[L_FORE] > 0.05  # recorded: the forearm deep in the hips
    a, b = d.body_capsules
    assert limb_overlap(a, b, R)[L_FORE] < 0.0  # simulated and drawn: turned out
    assert np.abs(b[fore] - b_raw[fore]).max() > 0.05
    memory = d._limb_memory.copy()
    assert np.abs(memory[0]).max() > 0.05 and not memory[1].any()  # the left arm carries a correction
    jump = pose.copy()  # the tracker re-initialises: 3 m away, turned 180 degrees
    jump[0] += 3.0
    jump[3:6] = [0.0, np.pi, 0.0]
    rot, _ = rigid_root_delta(pose, jump)
    d._advance = lambda *args, **kwargs: None  # type: ignore[method-assign]  # only the reset's own bookkeeping
    d._reset(jump, 0.7)
    np.testing.assert_allclose(d._limb_memory, memory @ rot.T, atol=1e-12)


def test_a_carried_correction_lets_go_once_the_recorded_arm_is_clear() -> None:
    """An arm swung from the front to the back through the side of the hips and held there, clear
    of the body: the correction carried through the swing (on the side the arm came from) must not
    hold the arm away from the recording once the way back would cross the trunk."""
    a0, b0 = capsule_endpoints(BODY, standing_pose(BODY))
    chain = ARMS[0]
    shoulder = a0[chain[0]].copy()
    rate = 240.0
    swing = np.linspace(np.radians(60.0), np.radians(-40.0), int(rate))
    flex = np.concatenate([swing, np.full(int(rate), swing[-1])])
    c, s = np.cos(np.radians(-25.0)), np.sin(np.radians(-25.0))
    adduct = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    a, b = np.repeat(a0[None], len(flex), 0), np.repeat(b0[None], len(flex), 0)
    for k, f in enumerate(flex):
        cf, sf = np.cos(f), np.sin(f)
        turn = np.array([[1.0, 0.0, 0.0], [0.0, cf, -sf], [0.0, sf, cf]]) @ adduct
        for cap in chain:
            a[k, cap] = shoulder + (a0[cap] - shoulder) @ turn.T
            b[k, cap] = shoulder + (b0[cap] - shoulder) @ turn.T
    _, bc = clear_limbs(a, b, R)
    raw_overlap = np.array([limb_overlap(a[k], b[k], R)[[L_FORE, L_HAND]].max() for k in range(len(a))])
    assert raw_overlap.max() > 0.05 and raw_overlap[-int(rate):].max() < -0.03  # through the hips, then clear
    moved = np.abs(bc[:, chain] - b[:, chain]).max(axis=(1, 2))
    assert moved.max() > 0.05  # corrected during the swing
    np.testing.assert_array_equal(bc[-int(rate // 2):], b[-int(rate // 2):])  # as recorded once clear


def test_limb_overlap_kernel_matches_numpy() -> None:
    """The numba overlap of the limbs with the trunk equals the numpy reference, for limbs clear
    of the trunk and swung through it."""
    rng = np.random.default_rng(4)
    pose = standing_pose(BODY)
    depths = []
    for _ in range(60):
        p = pose + rng.normal(0.0, 0.7, pose.shape)
        p[:3] = pose[:3]
        a, b = capsule_endpoints(BODY, p)
        got, ref = limb_overlap(a, b, R), limb_overlap_reference(a, b, R)
        np.testing.assert_allclose(got, ref, atol=1e-12, rtol=0)
        depths.append(ref)
    assert (np.array(depths) > 0).any() and (np.array(depths) < 0).any()
    with pytest.raises(ValueError, match="limb_overlap"):  # what the kernel (no bounds checks) would misread
        limb_overlap(a[:3], b[:3], R)
    with pytest.raises(ValueError, match="out of range"):
        limb_overlap(a[:3], b[:3], R[:3])
    for overlap in (limb_overlap, limb_overlap_reference):
        with pytest.raises(ValueError, match="samples"):
            overlap(a, b, R, samples=0)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_an_upper_arm_pressed_into_the_side_turns_out_about_the_shoulder(backend: str) -> None:
    """An arm pressed against the ribs (the elbow moved 10 cm in from the standing pose): the elbow turns
    about the fixed shoulder until the upper arm is at least ``LIMB_CLEARANCE`` off the trunk (room for the
    cape caught under it); forearm and hand ride along, every length kept."""
    a, b = capsule_endpoints(BODY, standing_pose(BODY))
    up, fore, hand = ARMS[0]
    uarm = np.array([up])
    shoulder, elbow = a[up].copy(), b[up].copy()
    length = np.linalg.norm(elbow - shoulder)
    target = elbow + np.array([-0.10, 0.0, 0.0])
    new_elbow = shoulder + length * (target - shoulder) / np.linalg.norm(target - shoulder)
    a2, b2 = a.copy(), b.copy()
    b2[up] = new_elbow
    for cap in (fore, hand):  # the rest of the arm carried with the elbow
        a2[cap] += new_elbow - elbow
        b2[cap] += new_elbow - elbow
    assert limb_overlap(a2, b2, R, uarm)[0] > 0.0  # sunk into the trunk
    ac, bc, _ = TRACKS[backend](a2, b2, R)
    # clear of the trunk; a little further where the sunk forearm's own push turned the elbow too
    assert -0.04 < limb_overlap(ac, bc, R, uarm)[0] <= -LIMB_CLEARANCE + 1e-3
    np.testing.assert_array_equal(ac[up], shoulder)
    np.testing.assert_allclose(np.linalg.norm(bc - ac, axis=-1), np.linalg.norm(b2 - a2, axis=-1), atol=1e-9)
    np.testing.assert_allclose(bc[up], ac[fore], atol=1e-12)
    np.testing.assert_allclose(bc[fore], ac[hand], atol=1e-12)
    assert bc[up, 0] > new_elbow[0] + 0.01  # the elbow went out, away from the ribs
    assert np.linalg.norm(bc[up] - elbow) < 0.10  # not past the standing pose
    ar, br, _ = TRACKS[backend](a, b, R)  # the standing arm (4 cm off) is left alone
    np.testing.assert_array_equal(ar, a)
    np.testing.assert_array_equal(br, b)
