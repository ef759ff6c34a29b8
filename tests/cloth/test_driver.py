"""Driving a garment with a pose stream: dressing, 15-120 Hz input, dropped frames, pose jumps and
the smooth teleport reset; and the garments themselves (sizing, topology, masses)."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest

from cloth_client.avatar.capsules import (
    Continuity,
    capsule_endpoints,
    interpolate_poses,
    interpolate_poses_reference,
    is_discontinuity,
    pose_keys,
    rigid_root_delta,
)
from cloth_client.contact.collision import penetration_reference, round_cone_reference
from cloth_client.solver.cloth import ClothParams, build_model, initial_state, step, structural_strain, tethers_held
from cloth_client.solver.driver import ClothDriver, DriverConfig
from cloth_client.solver.garment import DEFAULT_DENSITY, Garment, grid_topology, make_cape, make_garment, make_skirt
from protocol.kinematics import fk
from protocol.rotations import rotvec_to_matrix
from protocol.skeleton import (
    CAPSULE_INDEX,
    JOINT_INDEX,
    POSE_SIZE,
    ROT_JOINTS,
    body_from_measurements,
    default_body,
    standing_pose,
)
from protocol.wire.messages import body_from_body_info, body_info_from_body

BODY = default_body()
FAST = DriverConfig(dress_s=0.2, settle_s=0.2)


def _dance(t: np.ndarray, body=BODY) -> np.ndarray:  # type: ignore[no-untyped-def]
    """A synthetic motion: standing pose + sinusoids on the arms, hips and trunk, walking forward."""
    p = np.repeat(standing_pose(body)[None], len(t), axis=0)
    rot = p[:, 3:].reshape(len(t), -1, 3)
    w = 2 * np.pi * t
    rot[:, ROT_JOINTS.index("l_shoulder"), 2] += 0.9 * np.sin(w)
    rot[:, ROT_JOINTS.index("r_shoulder"), 0] += 0.8 * np.sin(1.3 * w)
    rot[:, ROT_JOINTS.index("l_hip"), 0] += 0.5 * np.sin(w)
    rot[:, ROT_JOINTS.index("r_hip"), 0] -= 0.5 * np.sin(w)
    rot[:, ROT_JOINTS.index("spine"), 1] += 0.4 * np.sin(0.5 * w)
    p[:, 2] += 0.8 * t  # walk forward at 0.8 m/s
    p[:, 4] += 0.6 * np.sin(0.5 * w)  # and turn
    return p


def _check(driver: ClothDriver, pose: np.ndarray, max_strain: float = 0.10) -> None:
    assert driver.state is not None
    assert np.all(np.isfinite(driver.state.x)) and np.all(np.isfinite(driver.state.v))
    a, b = capsule_endpoints(driver.body, pose)
    depth = penetration_reference(driver.state.x, a, b, driver.body.capsule_radii, driver.model.inv_mass > 0)
    assert depth.max() < 0.01
    assert structural_strain(driver.model, driver.state.x).max() < max_strain


@pytest.mark.parametrize("kind", ["cape", "skirt"])
@pytest.mark.parametrize("rate", [15.0, 120.0])
def test_synthetic_motion_at_low_and_high_rates(kind: str, rate: float) -> None:
    t = np.arange(0.0, 1.5, 1.0 / rate)
    poses = _dance(t)
    d = ClothDriver(BODY, make_garment(kind, BODY, 500), config=FAST)
    for p, ti in zip(poses, t, strict=True):
        d.feed(p, float(ti))
    _check(d, poses[-1])
    s = d.summary()
    assert s["frames"] == len(t) and s["resets"] == 0 and not s["nan"]
    assert s["energy_drift"] < 0.01
    assert s["sim_time_s"] == pytest.approx(t[-1] - t[0])


def test_dropped_frames_are_bridged_by_interpolation() -> None:
    t = np.arange(0.0, 1.5, 1 / 30)
    keep = np.ones(len(t), bool)
    keep[10:16] = False  # 0.2 s gap
    keep[30:33] = False
    poses = _dance(t)
    d = ClothDriver(BODY, make_cape(BODY, 500), config=FAST)
    for p, ti in zip(poses[keep], t[keep], strict=True):
        d.feed(p, float(ti))
    assert d.stats.resets == 0
    _check(d, poses[-1])


def test_stale_or_nonfinite_poses_are_skipped() -> None:
    d = ClothDriver(BODY, make_cape(BODY, 300), config=FAST)
    p = standing_pose(BODY)
    assert d.feed(p, 1.0) is None and d.state is None  # the first pose waits for the second
    assert d.feed(p, 1.05) is not None and d.state is not None  # dressed, then stepped
    assert d.feed(p, 1.05) is None  # not newer
    assert d.feed(p, 0.5) is None  # out of order
    bad = p.copy()
    bad[7] = np.nan
    assert d.feed(bad, 2.0) is None
    assert d.stats.skipped == 3
    assert d.feed(p, 1.1) is not None
    assert d.stats.frames == 3


def test_teleport_resets_the_cloth_smoothly() -> None:
    """The tracker re-initialises: the body jumps 4 m and turns 180 degrees in one frame. The cloth
    is carried along rigidly, keeps its drape relative to the body, and does not explode."""
    dt = 1 / 30
    d = ClothDriver(BODY, make_cape(BODY, 600), config=FAST)
    p = standing_pose(BODY)
    for k in range(20):
        d.feed(p, k * dt)
    assert d.state is not None
    before = d.state.x.copy()
    q = p.copy()
    q[0] += 3.0
    q[2] -= 2.6
    q[3:6] = [0.0, np.pi, 0.0]
    stats = d.feed(q, 20 * dt)
    assert stats is not None and stats.reset
    rot, shift = rigid_root_delta(p, q)
    np.testing.assert_allclose(rot, rotvec_to_matrix([0.0, np.pi, 0.0]), atol=1e-9)
    carried = before @ rot.T + shift
    assert np.abs(d.state.x - carried).max() < 0.05  # still draped the same way on the body
    speed = np.linalg.norm(d.state.v, axis=1)
    assert speed.max() < 2.0  # no explosion
    for k in range(21, 40):
        d.feed(q, k * dt)
    _check(d, q)
    assert np.linalg.norm(d.state.v, axis=1).max() < 0.5
    assert d.stats.resets == 1


def test_pose_jump_of_the_limbs_only_is_handled_as_a_reset() -> None:
    dt = 1 / 30
    d = ClothDriver(BODY, make_skirt(BODY, 500), config=FAST)
    p = standing_pose(BODY)
    for k in range(10):
        d.feed(p, k * dt)
    q = p.copy()
    q[3 + 3 * ROT_JOINTS.index("l_hip")] = -1.4  # the leg snaps up to a high kick
    assert is_discontinuity(BODY, p, q, dt)
    for k in range(10, 30):
        d.feed(q, k * dt)
    assert d.stats.resets == 1
    _check(d, q, max_strain=0.15)


def test_discontinuity_thresholds() -> None:
    p = standing_pose(BODY)
    q = p.copy()
    q[2] += 0.2  # 20 cm in a 30 Hz frame = 6 m/s: a run
    assert not is_discontinuity(BODY, p, q, 1 / 30)
    assert is_discontinuity(BODY, p, q, 1 / 120)  # 24 m/s
    assert is_discontinuity(BODY, p, p, 1.0)  # longer than the bridgeable gap
    assert is_discontinuity(BODY, p, p, 0.0)
    assert not is_discontinuity(BODY, p, q, 1 / 30, Continuity(max_root_speed=20.0))


def test_interpolated_poses_keep_bone_lengths_and_hit_the_ends() -> None:
    p0, p1 = _dance(np.array([0.1, 0.4]))
    s = np.linspace(0.0, 1.0, 7)
    mid = interpolate_poses(p0, p1, s)
    np.testing.assert_allclose(mid[0], p0, atol=1e-9)
    np.testing.assert_allclose(fk(mid[-1], BODY), fk(p1, BODY), atol=1e-9)
    j = fk(mid, BODY)
    hand = np.linalg.norm(j[:, JOINT_INDEX["l_wrist"]] - j[:, JOINT_INDEX["l_elbow"]], axis=1)
    np.testing.assert_allclose(hand, hand[0], rtol=1e-9)


@pytest.mark.parametrize("kind", ["cape", "skirt"])
def test_seam_spread_is_a_length_along_the_seam(kind: str) -> None:
    """``DriverConfig.seam_spread`` (metres) becomes whole pins of the garment's seam: 8 at the
    2,000-particle size the sweep measured, more on a finer garment; a negative length is refused."""
    body = default_body()
    coarse = ClothDriver(body, make_garment(kind, body, 2000))
    fine = ClothDriver(body, make_garment(kind, body, 5000))
    assert coarse._spread_pins == 8 and fine._spread_pins > coarse._spread_pins
    assert ClothDriver(body, make_garment(kind, body, 2000), config=DriverConfig(seam_spread=0.0))._spread_pins == 0
    with pytest.raises(ValueError, match="seam_spread"):
        ClothDriver(body, make_garment(kind, body, 2000), config=DriverConfig(seam_spread=-0.01))


# --- garments -------------------------------------------------------------------------------------

def test_grid_topology_counts() -> None:
    s, sh, b, t = grid_topology(4, 5, wrap=False)
    assert len(s) == 4 * 4 + 3 * 5 and len(sh) == 2 * 3 * 4 and len(b) == 4 * 3 + 2 * 5 and len(t) == 2 * 3 * 4
    s, sh, b, t = grid_topology(4, 5, wrap=True)
    assert len(s) == 4 * 5 + 3 * 5 and len(sh) == 2 * 3 * 5 and len(t) == 2 * 3 * 5
    with pytest.raises(ValueError):
        grid_topology(2, 5, wrap=False)


@pytest.mark.parametrize("kind", ["cape", "skirt"])
def test_garment_is_sized_to_the_body_and_clears_it(kind: str) -> None:
    small = body_from_measurements(1.45, name="small")
    tall = body_from_body_info(body_info_from_body(body_from_measurements(1.95, hip_m=1.15, name="tall"), "t"))
    sizes = []
    for body in (small, tall):
        g = make_garment(kind, body, 1500)
        assert abs(g.n_particles - 1500) < 200
        a, b = capsule_endpoints(body, g.pose)
        depth = penetration_reference(g.rest, a, b, body.capsule_radii, np.ones(g.n_particles, bool))
        assert depth.max() == 0.0
        area = 0.5 * np.linalg.norm(np.cross(g.rest[g.triangles[:, 1]] - g.rest[g.triangles[:, 0]],
                                             g.rest[g.triangles[:, 2]] - g.rest[g.triangles[:, 0]]), axis=1).sum()
        assert g.total_mass == pytest.approx(DEFAULT_DENSITY * area, rel=1e-9)
        sizes.append((np.ptp(g.rest[:, 0]), np.ptp(g.rest[:, 1])))
        # pins sit on the top row, rebuilt exactly by the avatar in the build pose
        assert np.all(g.pin_index < g.grid_shape[1])
    assert sizes[1][0] > 1.15 * sizes[0][0] and sizes[1][1] > 1.2 * sizes[0][1]


def test_strain_limit_batches_are_particle_disjoint_and_cover_all_springs() -> None:
    for g in (make_cape(BODY, 400), make_skirt(BODY, 400)):
        ptr = g.limit_batches
        assert ptr[0] == 0 and ptr[-1] == len(g.structural)
        for b0, b1 in itertools.pairwise(ptr):
            ids = g.limit_springs[b0:b1].ravel()
            assert len(np.unique(ids)) == len(ids)
        assert {tuple(sorted(s)) for s in g.limit_springs.tolist()} == {tuple(sorted(s)) for s in g.structural.tolist()}
        model = build_model(g)
        assert np.all(model.reach[g.pin_index] == 0.0) and np.all(model.reach >= 0)


def test_waistband_lets_go_where_an_arm_comes_near_but_not_round_the_trunk() -> None:
    """The skirt's seam counts a pin as covered when an arm comes within ``seam_reach`` of it (a
    forearm wedging under the waistband), but the trunk it is sewn round only within the margin."""
    d = ClothDriver(BODY, make_skirt(BODY, 500), config=FAST)
    reach = d._seam_margin
    margin, far = d.model.params.margin, d.config.seam_reach
    assert reach[CAPSULE_INDEX["abdomen"]] == margin and reach[CAPSULE_INDEX["pelvis"]] == margin
    assert reach[CAPSULE_INDEX["l_forearm"]] == far and reach[CAPSULE_INDEX["r_hand"]] == far
    g = d.garment
    pose = standing_pose(BODY)
    keys = pose_keys(BODY, np.stack([pose, pose]))
    pins = keys.pin_targets(g.pin_joint, g.pin_local, g.pin_axis, g.pin_axis_s, g.pin_axis_local)
    assert not keys.covered(pins, reach).any()  # standing: arms hang clear of the waistband
    # move one pin to 3 cm outside the left forearm's surface: within reach of an arm, not of the margin
    a, b = keys.track.a[0, CAPSULE_INDEX["l_forearm"]], keys.track.b[0, CAPSULE_INDEX["l_forearm"]]
    mid = 0.5 * (a + b)
    r = BODY.capsule_radii[CAPSULE_INDEX["l_forearm"]].mean()
    near = pins.copy()
    near[:, 0] = mid + np.array([r + 0.03, 0.0, 0.0])
    assert keys.covered(near, reach)[0] and not keys.covered(near, margin)[0]
    assert d._widen(keys.covered(near, reach)).sum() == 3  # the pin and its two neighbours go


def test_slide_under_arms_slides_the_waistband_under_a_forearm_and_releases_it_at_the_trunk() -> None:
    """With ``slide_under_arms`` (the default) a forearm or hand on the waistband slides the seam
    (nothing let go) while a thigh, the trunk or a limb sunk into it still releases the pins it
    covers; off, both release. A collar always slides; most of the seam covered slides either way."""
    g = make_skirt(BODY, 500)
    on = ClothDriver(BODY, g, config=FAST)
    off = ClothDriver(BODY, g, config=replace(FAST, slide_under_arms=False))
    assert DriverConfig().slide_under_arms and not off.config.slide_under_arms
    pose = standing_pose(BODY)
    keys = pose_keys(BODY, np.stack([pose, pose]))
    pins = keys.pin_targets(g.pin_joint, g.pin_local, g.pin_axis, g.pin_axis_s, g.pin_axis_local)
    arm, trunk = on._split_reach()
    for name in ("l_forearm", "l_hand", "r_forearm", "r_hand"):
        i = CAPSULE_INDEX[name]
        assert arm[i] == on._seam_margin[i] and trunk[i] == -np.inf
    for name in ("pelvis", "abdomen", "l_thigh", "l_upper_arm"):
        i = CAPSULE_INDEX[name]
        assert arm[i] == -np.inf and trunk[i] == on._seam_margin[i]
    on._ghost[:2] = True  # the left forearm and hand sunk into the trunk: they release, as when off
    arm, trunk = on._split_reach()
    assert np.all(arm[[CAPSULE_INDEX["l_forearm"], CAPSULE_INDEX["l_hand"]]] == -np.inf)
    assert arm[CAPSULE_INDEX["r_hand"]] == on._seam_margin[CAPSULE_INDEX["r_hand"]]
    np.testing.assert_array_equal(trunk[[CAPSULE_INDEX["l_forearm"], CAPSULE_INDEX["l_hand"]]],
                                  on._seam_margin[[CAPSULE_INDEX["l_forearm"], CAPSULE_INDEX["l_hand"]]])
    on._ghost[:] = False
    for d in (on, off):
        slide, released = d._seam_action(keys, pins)
        assert not slide and not released.any()  # standing: nothing near the waistband

    def near(capsule: str, gap: float = 0.01) -> np.ndarray:  # pin 0 moved to ``gap`` m off the surface
        a, b = keys.track.a[0, CAPSULE_INDEX[capsule]], keys.track.b[0, CAPSULE_INDEX[capsule]]
        r = BODY.capsule_radii[CAPSULE_INDEX[capsule]].mean()
        out = pins.copy()
        out[:, 0] = 0.5 * (a + b) + np.array([r + gap, 0.0, 0.0])
        return out

    slide, released = on._seam_action(keys, near("l_forearm"))
    assert slide and not released.any()
    slide, released = off._seam_action(keys, near("l_forearm"))
    assert not slide and released.sum() == 3
    for d in (on, off):
        slide, released = d._seam_action(keys, near("l_thigh", -0.01))
        assert not slide and released.sum() == 3
    most = pins.copy()
    most[:, :] = near("l_thigh", -0.01)[:, :1]  # every pin on the thigh: more than slide_fraction covered
    for d in (on, off):
        slide, released = d._seam_action(keys, most)
        assert slide and not released.any()
    cape = ClothDriver(BODY, make_cape(BODY, 500), config=FAST)
    cp = keys.pin_targets(cape.garment.pin_joint, cape.garment.pin_local, cape.garment.pin_axis,
                          cape.garment.pin_axis_s, cape.garment.pin_axis_local)
    slide, released = cape._seam_action(keys, cp)
    assert slide and not released.any()


def test_released_pins_hand_their_cloth_to_the_held_pins() -> None:
    """While part of the waistband is let go, every particle is tethered to its nearest *held* pin
    (never tighter than its own attachment), so the released stretch does not sag and stretch under
    the skirt's weight."""
    g = make_skirt(BODY, 500)
    model = build_model(g, ClothParams(extra_rounds=0))  # the attachments alone, without the extra rounds
    none = np.zeros(len(g.pin_index), dtype=bool)
    anchor, reach = tethers_held(model, none)
    np.testing.assert_array_equal(anchor, g.anchor)
    np.testing.assert_allclose(reach, model.reach)
    released = none.copy()
    released[: len(released) // 3] = True  # a third of the waistband
    anchor, reach = tethers_held(model, released)
    assert set(anchor.tolist()) <= set(g.pin_index[~released].tolist())
    assert np.all(reach >= model.reach - 1e-12) and np.all(reach[g.pin_index[released]] > 0.0)
    assert np.all(reach[g.pin_index[~released]] == 0.0)
    pose = standing_pose(BODY)
    keys = pose_keys(BODY, np.stack([pose, pose]))
    pins = keys.pin_targets(g.pin_joint, g.pin_local, g.pin_axis, g.pin_axis_s, g.pin_axis_local)
    worst = {}
    for name, tethers in (("own", None), ("held", (anchor, reach))):
        state = initial_state(model)
        worst[name] = 0.0
        for _ in range(60):  # 1 s
            state = step(state, model, keys.track, pins, 1 / 60, released=released, tethers=tethers)
            worst[name] = max(worst[name], float(structural_strain(model, state.x).max()))
    # without them the released stretch sags (10-11 % before the final strain passes became
    # contact-aware, 9.8 % since: cloth resting on the hips now slides instead of staying stretched;
    # the extra final rounds, off here, would also pull it back, at the cost of more rounds per substep)
    assert worst["held"] < 0.09 and worst["own"] > worst["held"] + 0.025


def test_waistband_stays_square_to_the_abdomen_when_the_back_bends() -> None:
    """The waistband's frame is the spine joint's, swung to keep the ring square to the pelvis-chest
    line: it moves rigidly and stays as far from the abdomen's axis as at rest, also in a deep bow,
    a side bend and a twist."""
    g = make_skirt(BODY, 500)
    pose = standing_pose(BODY)
    k = 3 + 3 * ROT_JOINTS.index("spine")
    bends = []
    for rv in ([0.6, 0.0, 0.0], [0.0, 0.0, 0.4], [0.3, 0.5, -0.2]):
        p = pose.copy()
        p[k:k + 3] = rv
        bends.append(p)
    keys = pose_keys(BODY, np.stack([pose, *bends]))
    t = keys.pin_targets(g.pin_joint, g.pin_local, g.pin_axis, g.pin_axis_s, g.pin_axis_local)
    plain = keys.pin_targets(g.pin_joint, g.pin_local, g.pin_axis, g.pin_axis_s)
    np.testing.assert_allclose(t[0], g.rest[g.pin_index], atol=1e-12)
    pelvis, chest = JOINT_INDEX["pelvis"], JOINT_INDEX["chest"]

    def axial(j: int) -> np.ndarray:  # distance of each pin from the pelvis-chest line, and along it from the anchor
        a, b = keys.joints[j, pelvis], keys.joints[j, chest]
        u = (b - a) / np.linalg.norm(b - a)
        s = g.pin_axis_s[:, None]
        d = t[j] - ((1.0 - s) * a + s * b)
        along = d @ u
        return np.concatenate([np.linalg.norm(d - along[:, None] * u, axis=1), along])

    for j in range(1, len(bends) + 1):
        d0 = np.linalg.norm(t[0][:, None] - t[0][None], axis=-1)
        np.testing.assert_allclose(np.linalg.norm(t[j][:, None] - t[j][None], axis=-1), d0, atol=1e-9)  # rigid
        np.testing.assert_allclose(axial(j), axial(0), atol=1e-9)  # square to the axis, same radii
        assert np.abs(t[j] - plain[j]).max() > 0.005  # the spine frame alone would tilt it


@pytest.mark.parametrize("kind", ["cape", "skirt"])
def test_driver_hands_the_seam_its_rest_lengths(kind: str) -> None:
    """The slide's length pass gets one rest length per seam segment (the skirt's ring closed),
    the pins' spacing in the garment; ``keep_seam_length=False`` keeps the slide without the length pass."""
    g = make_garment(kind, BODY, 500)
    d = ClothDriver(BODY, g, config=FAST)
    seam = g.rest[g.pin_index]
    ring = np.vstack([seam, seam[:1]]) if g.wrap else seam
    assert d._seam_rest.shape == (len(seam) if g.wrap else len(seam) - 1,)
    np.testing.assert_allclose(d._seam_rest, np.linalg.norm(np.diff(ring, axis=0), axis=1))
    assert np.all(d._seam_rest > 0.0) and (kind == "skirt") == g.wrap
    assert DriverConfig().keep_seam_length and not replace(FAST, keep_seam_length=False).keep_seam_length


def test_waistband_rolls_with_the_hips_against_the_chest() -> None:
    """A pelvis rolled against the chest (a salsa hip: the root rolled 0.2 rad, the spine rolled
    back) tilts the waistband with the hip line: rigidly, about the front-back direction only (the
    front and back pins stay where the square ring has them), the side pins along the hip line, and
    the high hip stays beyond the cloth margin of the ring, which the square ring lets it cross
    (its pins would be covered and released). Standing, the two rings are the same."""
    rolled, square = make_skirt(BODY, 500), make_skirt(BODY, 500, roll_with_hips=False)
    assert square.pin_roll is None and rolled.pin_roll is not None
    pose = standing_pose(BODY)
    hip = pose.copy()
    hip[3:6] = [0.0, 0.0, 0.2]
    k = 3 + 3 * ROT_JOINTS.index("spine")
    hip[k:k + 3] = [0.0, 0.0, -0.2]
    keys = pose_keys(BODY, np.stack([pose, hip]))

    def targets(g: Garment) -> np.ndarray:
        out: np.ndarray = keys.pin_targets(g.pin_joint, g.pin_local, g.pin_axis, g.pin_axis_s, g.pin_axis_local,
                                           g.pin_roll)
        return out

    t, flat = targets(rolled), targets(square)
    np.testing.assert_allclose(t[0], rolled.rest[rolled.pin_index], atol=1e-12)
    np.testing.assert_allclose(t[0], flat[0], atol=1e-12)
    d0 = np.linalg.norm(t[0][:, None] - t[0][None], axis=-1)
    np.testing.assert_allclose(np.linalg.norm(t[1][:, None] - t[1][None], axis=-1), d0, atol=1e-9)  # rigid
    cols = rolled.grid_shape[1]
    front, back = 0, cols // 2
    np.testing.assert_allclose(t[1][[front, back]], flat[1][[front, back]], atol=2e-3)  # no pitch, no twist
    j = keys.joints[1]
    s = rolled.pin_axis_s[0]
    anchor = (1.0 - s) * j[JOINT_INDEX["pelvis"]] + s * j[JOINT_INDEX["chest"]]
    line = j[JOINT_INDEX["r_hip"]] - j[JOINT_INDEX["l_hip"]]
    for side in (cols // 4, 3 * cols // 4):
        off = t[1][side] - anchor
        assert abs(off @ line) / (np.linalg.norm(off) * np.linalg.norm(line)) > 0.99
    c = CAPSULE_INDEX["pelvis"]

    def hip_gap(p: np.ndarray) -> float:
        d, _, _ = round_cone_reference(p, keys.track.a[1, c:c + 1], keys.track.b[1, c:c + 1],
                                       BODY.capsule_radii[c:c + 1, 0], BODY.capsule_radii[c:c + 1, 1])
        return float(d.min())

    margin = ClothParams().margin
    assert hip_gap(t[1]) > margin > hip_gap(flat[1])


def _swing_strains(rate: float, config: DriverConfig = FAST) -> tuple[list[float], bool]:
    """Max strain of every frame of the synthetic forearm swing through the hips at ``rate`` Hz, and
    whether the forearm was ever ghosted."""
    t = np.arange(0.0, 1.5, 1.0 / rate)
    d = ClothDriver(BODY, make_skirt(BODY, 500), config=config)
    strains, ghosted = [], False
    for p, ti in zip(_dance(t), t, strict=True):
        fs = d.feed(p, float(ti))
        ghosted |= bool(d._ghost.any())
        if fs is not None:
            strains.append(fs.max_strain)
    assert not d.stats.nan
    return strains, ghosted


@pytest.mark.parametrize("rate", [15.0, 30.0, 60.0, 120.0])
def test_skirt_strain_stays_low_while_a_forearm_swings_through_the_hips(rate: float) -> None:
    """The synthetic motion swings the left forearm 12-15 cm deep through the pelvis (t = 0.5-1 s,
    ``test_limb_overlap_of_a_forearm_swung_through_the_hips``). The avatar's forearm is turned out
    of the hips and kept on the side it came from from key to key, so it is never ghosted and the
    skirt stays within the 10 % target on every frame at every input rate (5-8 % measured). Without
    the correction carried, the forearm was ghosted past a 14 cm push and the
    frames where it left the hips reached 28-248 % at 15-60 Hz input."""
    strains, ghosted = _swing_strains(rate)
    assert not ghosted
    assert max(strains) < 0.10


@pytest.mark.parametrize("rate", [15.0, 30.0, 60.0])
def test_skirt_is_not_caught_by_a_ghosted_forearm(rate: float) -> None:
    """Without the avatar's correction (``limb_clearance=None``) the sunk forearm is ghosted: it
    stops pushing the cloth, and the skirt is not trapped round it (4-8 % measured)."""
    strains, ghosted = _swing_strains(rate, replace(FAST, limb_clearance=None))
    assert ghosted
    assert max(strains) < 0.12
    assert strains[-1] < 0.10


def test_limb_overlap_of_a_forearm_swung_through_the_hips() -> None:
    from cloth_client.avatar.capsules import LIMBS, limb_overlap

    radii = BODY.capsule_radii
    for ti in (0.0, 0.25):  # standing, then the arm out to the side
        assert np.all(limb_overlap(*capsule_endpoints(BODY, _dance(np.array([ti]))[0]), radii) < 0.0)
    depth = limb_overlap(*capsule_endpoints(BODY, _dance(np.array([0.6]))[0]), radii)  # through the pelvis
    i = list(LIMBS).index(CAPSULE_INDEX["l_forearm"])
    assert depth[i] > 0.10 and depth[list(LIMBS).index(CAPSULE_INDEX["r_forearm"])] < 0.0


def test_interpolation_kernel_matches_numpy() -> None:
    """The numba slerp of every joint equals the numpy reference (rotation vectors through
    matrices and quat_slerp), for small steps and turns of more than half a revolution."""
    rng = np.random.default_rng(8)
    s = np.linspace(0.0, 1.0, 6)
    for k in range(40):
        p0 = rng.normal(0.0, 1.2, POSE_SIZE)
        p1 = p0 + rng.normal(0.0, 0.05 if k % 2 else 2.0, POSE_SIZE)
        if k % 5 == 0:
            p1[3:12] = p0[3:12]  # unchanged joints: the linear branch
        np.testing.assert_allclose(interpolate_poses(p0, p1, s), interpolate_poses_reference(p0, p1, s),
                                   atol=1e-12, rtol=0)
    for interpolate in (interpolate_poses, interpolate_poses_reference):
        with pytest.raises(ValueError, match="shape"):
            interpolate(p0[:-3], p1, s)
