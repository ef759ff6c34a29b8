"""Collision with body capsules: geometry of the tapered capsule, response against one capsule
(projection, inelastic normal, Coulomb friction), continuity under a fast swing, pinning."""

from __future__ import annotations

import numpy as np
import pytest

from cloth_client.avatar.capsules import AvatarKeys, capsule_endpoints, pose_keys
from cloth_client.contact import cone_kernels as C
from cloth_client.contact import response_kernels as K
from cloth_client.contact.collision import (
    CapsuleTrack,
    max_relative_travel,
    penetration_reference,
    round_cone_reference,
)
from cloth_client.contact.response import (
    PINCH_COS,
    PINCH_DEPTH,
    broad_phase_reference,
    collide_reference,
    pinch_margin_reference,
    release_straddles_reference,
)
from cloth_client.contact.seam import (
    check_seam_rest,
    covered_reference,
    keep_seam_length_reference,
    push_out_reference,
    slide_seam_reference,
)
from cloth_client.contact.seam_kernels import SEAM_LENGTH_SLACK
from cloth_client.solver.cloth import ClothParams, build_model, initial_state, step
from cloth_client.solver.garment import REST_CLEARANCE, make_cape, make_sheet, make_skirt
from cloth_client.solver.reference import touching_reference
from protocol.kinematics import fk
from protocol.rotations import rotvec_to_matrix
from protocol.skeleton import CAPSULE_INDEX, JOINT_INDEX, ROT_JOINTS, default_body, standing_pose

A = np.array([[0.0, 0.0, 0.0]])
B = np.array([[0.5, 0.0, 0.0]])


def _collide(backend: str, x: np.ndarray, v: np.ndarray, a0: np.ndarray, b0: np.ndarray, a1: np.ndarray,
             b1: np.ndarray, radii: np.ndarray, margin: float, friction: float, dt: float,
             floor: float | None = None, xprev: np.ndarray | None = None) -> np.ndarray:
    contact = np.zeros((len(x), 6))
    xp = x.copy() if xprev is None else xprev
    if backend == "numba":
        K.collide(x, v, np.ones(len(x)), a0, b0, a1, b1, radii, margin, friction, dt,
                  0.0 if floor is None else floor, floor is not None, contact,
                  np.full(len(x), K.ALL_CAPSULES), x.copy(), 0.0, xp)
    else:
        collide_reference(x, v, np.ones(len(x), bool), a0, b0, a1, b1, radii, margin, friction, dt, floor, contact,
                          xp)
    return contact


def test_round_cone_distance_matches_support_points() -> None:
    """For any direction w, the hull of the two spheres has its support point c + r w (c, r the
    sphere maximising c.w + r) on the surface with outward normal w; points h along w are at
    signed distance h."""
    rng = np.random.default_rng(3)
    a, b = np.array([[0.1, 0.2, -0.1]]), np.array([[0.3, 0.6, 0.2]])
    ra, rb = np.array([0.09]), np.array([0.04])
    w = rng.normal(size=(500, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    use_a = (w @ a[0] + ra[0]) >= (w @ b[0] + rb[0])
    support = np.where(use_a[:, None], a[0] + ra[0] * w, b[0] + rb[0] * w)
    for h in (0.03, 0.0, -0.01):
        d, n, _ = round_cone_reference(support + h * w, a, b, ra, rb)
        np.testing.assert_allclose(d[:, 0], h, atol=1e-9)
        np.testing.assert_allclose(n[:, 0], w, atol=1e-7)
        for k in range(0, 500, 50):  # the numba scalar version agrees
            dk, nx, ny, nz, _ = C.round_cone(*(support[k] + h * w[k]), a[0], b[0], ra[0], rb[0])
            assert dk == pytest.approx(d[k, 0], abs=1e-12)
            np.testing.assert_allclose([nx, ny, nz], n[k, 0], atol=1e-9)


def test_round_cone_degenerate_cases() -> None:
    # one sphere swallows the other: just the big sphere
    d, n, t = round_cone_reference(np.array([[0.0, 0.5, 0.0]]), A, np.array([[0.05, 0.0, 0.0]]), np.array([0.2]),
                                   np.array([0.05]))
    assert d[0, 0] == pytest.approx(0.3) and t[0, 0] == 0.0
    np.testing.assert_allclose(n[0, 0], [0, 1, 0], atol=1e-12)
    # a point on the axis inside gets a unit normal
    d, n, _ = round_cone_reference(np.array([[0.25, 0.0, 0.0]]), A, B, np.array([0.1]), np.array([0.1]))
    assert d[0, 0] == pytest.approx(-0.1) and np.linalg.norm(n[0, 0]) == pytest.approx(1.0)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_particle_inside_capsule_is_projected_out_with_friction(backend: str) -> None:
    r, margin, mu, dt = np.array([[0.1, 0.1]]), 0.005, 0.4, 0.01
    x = np.array([[0.25, 0.05, 0.0], [0.25, 0.3, 0.0]])  # inside, and far outside
    v = np.array([[1.0, -2.0, 0.0], [0.0, -1.0, 0.0]])  # sliding along the axis, moving into it
    contact = _collide(backend, x, v, A, B, A, B, r, margin, mu, dt)
    np.testing.assert_allclose(x[0], [0.25, 0.1 + margin, 0.0], atol=1e-12)
    # normal velocity (-2 into the surface) cancelled; tangential 1 m/s reduced by mu * 2 = 0.8
    np.testing.assert_allclose(v[0], [0.2, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(contact[0], [0, 1, 0, 0, 0, 0], atol=1e-12)
    np.testing.assert_array_equal(x[1], [0.25, 0.3, 0.0])  # untouched
    np.testing.assert_array_equal(v[1], [0.0, -1.0, 0.0])
    assert not contact[1].any()


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_moving_capsule_carries_particle_and_static_friction_sticks(backend: str) -> None:
    r, dt = np.array([[0.1, 0.1]]), 0.01
    a0, b0 = A - [0.0, 0.02, 0.0], B - [0.0, 0.02, 0.0]  # the capsule rose 2 cm during the substep
    x = np.array([[0.25, 0.09, 0.0]])
    v = np.array([[0.05, 0.0, 0.0]])
    _collide(backend, x, v, a0, b0, A, B, r, 0.0, 1.0, dt)
    np.testing.assert_allclose(x[0, 1], 0.1, atol=1e-12)
    # surface moves up at 2 m/s: the particle leaves with it; the small slip is stopped by friction
    np.testing.assert_allclose(v[0], [0.0, 2.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_floor_and_pinch_between_two_surfaces(backend: str) -> None:
    # a capsule lying 2 cm deep in the floor; one particle in the crease between them, one on the floor
    a, b, r = np.array([[0.0, 0.03, 0.0]]), np.array([[0.5, 0.03, 0.0]]), np.array([[0.05, 0.05]])
    x = np.array([[0.25, -0.003, 0.035], [1.0, -0.02, 0.0]])
    v = np.array([[0.3, -1.0, 0.0], [0.3, -1.0, 0.0]])
    contact = _collide(backend, x, v, a, b, a, b, r, 0.0, 0.5, 0.01, floor=0.0)
    assert x[1, 1] == pytest.approx(0.0) and v[1, 1] == 0.0 and v[1, 0] < 0.3  # floor with friction
    np.testing.assert_allclose(contact[1], [0, 1, 0, 0, 0, 0], atol=1e-12)
    d, _, _ = round_cone_reference(x[:1], a, b, r[:, 0], r[:, 1])
    assert d[0, 0] >= -1e-3 and x[0, 1] >= -1e-9  # worked out of both (to within a millimetre)
    assert np.linalg.norm(contact[0, :3]) > 0.5 and np.linalg.norm(contact[0, 3:]) > 0.5  # two surfaces
    np.testing.assert_allclose(v[0], 0.0, atol=1e-12)  # pinched: held by the (still) capsule, no sliding


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_cloth_in_a_narrow_gap_fits_and_stays_with_the_stouter_part(backend: str) -> None:
    """Two parallel capsules 8 mm apart (a hand against the hip) with a 6 mm margin: the particle
    between them settles half-way (4 mm from each, outside both) instead of being pushed into one.
    Where they overlap by 5 mm (a forearm pressed on the hip) it settles half-way through the
    overlap, 2.5 mm inside each (the gap's middle, y = 0.0975), instead of being squeezed out to
    one side; in both cases it takes the velocity of the thicker capsule (at rest), not that of the
    thin one sliding over it."""
    margin, dt = 0.006, 0.01
    radii = np.array([[0.10, 0.10], [0.03, 0.03]])
    for top, start, gap_d in ((0.138, 0.103, 0.004), (0.125, 0.102, -0.0025)):
        a1 = np.array([[-0.3, 0.0, 0.0], [-0.3, top, 0.0]])
        b1 = np.array([[0.3, 0.0, 0.0], [0.3, top, 0.0]])
        a0 = a1 - [[0.0, 0.0, 0.0], [0.02, 0.0, 0.0]]  # the thin capsule slides along +X at 2 m/s
        b0 = b1 - [[0.0, 0.0, 0.0], [0.02, 0.0, 0.0]]
        x = np.array([[0.05, start, 0.0]])
        v = np.array([[1.0, 0.5, 0.0]])
        _collide(backend, x, v, a0, b0, a1, b1, radii, margin, 0.3, dt)
        d, _, _ = round_cone_reference(x, a1, b1, radii[:, 0], radii[:, 1])
        np.testing.assert_allclose(d[0], [gap_d, gap_d], atol=1e-9)
        np.testing.assert_allclose(x[0], [0.05, gap_d + 0.10, 0.0], atol=1e-9)
        np.testing.assert_allclose(v[0], 0.0, atol=1e-12)
    # the numba and numpy clearances agree, round a posed body and in the gap above
    body = default_body()
    keys = pose_keys(body, standing_pose(body)[None].repeat(2, 0))
    rng = np.random.default_rng(5)
    for a, b, r, lo, hi in ((keys.track.a[0], keys.track.b[0], body.capsule_radii, [-0.4, 0.5, -0.3], [0.4, 1.5, 0.3]),
                            (a1, b1, radii, [-0.3, 0.09, -0.04], [0.3, 0.13, 0.04])):
        pts = rng.uniform(lo, hi, size=(3000, 3))
        geo = np.empty((len(a), 13))
        C.capsule_geometry(a, b, r, margin, geo)
        got = np.array([K.pinch_margin(*p, geo, 0.5 * (a + b), margin) for p in pts])
        ref = pinch_margin_reference(pts, a, b, r, margin)
        np.testing.assert_allclose(got, ref, atol=1e-12)
    assert (ref < margin).sum() > 100 and (ref == margin).sum() > 100


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_pinch_clearance_is_half_the_gap_down_to_the_pinch_depth(backend: str) -> None:
    """Clearance in a crease between a thick (r = 10 cm, axis y = 0) and a thin (r = 3 cm, axis
    y = top) parallel capsule, hand-computed from the two surface distances d1 = y - 0.10 and
    d2 = top - y - 0.03 of a particle at height y: (d1 + d2) / 2, at most the margin and at least
    -PINCH_DEPTH (a 20 mm overlap leaves no room at 10 mm inside each); the full margin outside a
    crease (the thin capsule beside the thick one: normals 90 degrees apart)."""
    margin = 0.006
    assert K.PINCH_DEPTH == PINCH_DEPTH and PINCH_DEPTH < 0.01  # numba = numpy, within the 1 cm target
    radii = np.array([[0.10, 0.10], [0.03, 0.03]])
    cases = (  # (top, y, expected clearance)
        (0.138, 0.103, 0.004),  # 8 mm gap: d1 = 3, d2 = 5 mm
        (0.125, 0.102, -0.0025),  # 5 mm overlap: d1 = 2, d2 = -7 mm
        (0.110, 0.095, -K.PINCH_DEPTH),  # 20 mm overlap: d1 = -5, d2 = -15 mm, mean -10 mm
        (0.150, 0.100, margin),  # d2 = 20 mm: only one surface within the margin
    )
    for top, y, expected in cases:
        a = np.array([[-0.3, 0.0, 0.0], [-0.3, top, 0.0]])
        b = np.array([[0.3, 0.0, 0.0], [0.3, top, 0.0]])
        p = np.array([[0.05, y, 0.0]])
        if backend == "numba":
            geo = np.empty((2, 13))
            C.capsule_geometry(a, b, radii, margin, geo)
            got = K.pinch_margin(*p[0], geo, 0.5 * (a + b), margin)
        else:
            got = float(pinch_margin_reference(p, a, b, radii, margin)[0])
        assert got == pytest.approx(expected, abs=1e-12)
    # the thin capsule sunk sideways into the thick one (axis at z = 0.1): near where the surfaces
    # cross, both are within the margin but their normals are 76 degrees apart: no crease (a crease
    # is two normals more than 90 degrees apart)
    a = np.array([[-0.3, 0.0, 0.0], [-0.3, 0.0, 0.1]])
    b = a + np.array([0.6, 0.0, 0.0])
    p = np.array([[0.0, 0.033, 0.097]])
    d, nrm, _ = round_cone_reference(p, a, b, radii[:, 0], radii[:, 1])
    assert np.all(d[0] < margin) and nrm[0, 0] @ nrm[0, 1] > PINCH_COS
    assert pinch_margin_reference(p, a, b, radii, margin)[0] == margin
    # a V: the thin capsule beside the thick one, their surfaces crossing at 100 degrees (normals
    # cos -0.17); a particle 2 mm outside the crossing gets half the gap, one 2 mm inside gets 0
    # (never a clearance inside the body in a V, only in a crease beyond PINCH_COS)
    dist = np.sqrt(0.10**2 + 0.03**2 + 2 * 0.10 * 0.03 * 0.17)
    a = np.array([[-0.3, 0.0, 0.0], [-0.3, dist, 0.0]])
    b = a + np.array([0.6, 0.0, 0.0])
    yc = (0.10**2 - 0.03**2 + dist**2) / (2 * dist)
    cross = np.array([0.0, yc, np.sqrt(0.10**2 - yc**2)])
    bis = cross / 0.10 + (cross - (a[1] + b[1]) / 2) / 0.03
    bis /= np.linalg.norm(bis)
    for sign, floor in ((1.0, None), (-1.0, 0.0)):
        p = (cross + sign * 0.002 * bis)[None]
        d, nrm, _ = round_cone_reference(p, a, b, radii[:, 0], radii[:, 1])
        cos = nrm[0, 0] @ nrm[0, 1]
        assert PINCH_COS < cos < K.CREASE_COS and np.all(d[0] < margin), (cos, d)
        expected = 0.5 * (d[0, 0] + d[0, 1]) if floor is None else floor
        assert 0.0 <= expected < margin
        geo = np.empty((2, 13))
        C.capsule_geometry(a, b, radii, margin, geo)
        assert K.pinch_margin(*p[0], geo, 0.5 * (a + b), margin) == pytest.approx(expected, abs=1e-12)
        assert pinch_margin_reference(p, a, b, radii, margin)[0] == pytest.approx(expected, abs=1e-12)


def test_penetration_depth_kernel_matches_numpy(rng: np.random.Generator) -> None:
    body = default_body()
    keys = pose_keys(body, standing_pose(body)[None].repeat(2, 0))
    a, b = keys.track.a[0], keys.track.b[0]
    x = rng.uniform([-0.4, 0.0, -0.3], [0.4, 1.8, 0.3], size=(2000, 3))
    free = rng.random(2000) > 0.1
    out = np.empty(2000)
    C.penetration(x, a, b, body.capsule_radii, free.astype(float), out)
    ref = penetration_reference(x, a, b, body.capsule_radii, free)
    np.testing.assert_allclose(out, ref, atol=1e-12)
    assert (ref > 0).sum() > 50 and np.all(ref[~free] == 0)


def test_fast_swing_does_not_tunnel_through_cloth() -> None:
    """A forearm-sized capsule (r = 4 cm) crosses a hanging sheet at 12 m/s within one 30 Hz frame.
    With the substeps planned from its travel it pushes the cloth ahead; forcing one substep lets it
    pass straight through."""
    g = make_sheet(12, 12, 0.03, height=1.5)
    model = build_model(g, ClothParams(floor=None))
    # hang the sheet vertically in the plane z = 0: rows go down
    x0 = g.rest.copy()
    x0[:, 1] = 1.5 + x0[:, 2]
    x0[:, 2] = 0.0
    state = initial_state(model, x0)
    r = np.array([[0.04, 0.04]])
    a = np.array([[[0.17, 1.05, -0.2]], [[0.17, 1.05, 0.2]]])
    b = a + np.array([0.0, 0.25, 0.0])  # a vertical bar 25 cm tall, moving from z = -0.2 to z = +0.2
    track = CapsuleTrack(a, b, r)
    assert max_relative_travel(track) == pytest.approx(10.0)
    pins = np.repeat(x0[g.pin_index][None], 2, axis=0)
    good = step(state, model, track, pins, 1 / 30)
    bad = step(state, model, track, pins, 1 / 30, n_substeps=1)
    assert good.substeps >= 20
    near = (np.abs(x0[:, 0] - 0.17) < 0.025) & (x0[:, 1] > 1.06) & (x0[:, 1] < 1.29)
    assert near.sum() >= 4
    assert np.all(good.x[near, 2] > 0.2 - 0.04)  # carried along: ahead of or beside the bar, not behind
    d, _, _ = round_cone_reference(good.x, a[-1], b[-1], r[:, 0], r[:, 1])
    assert d.min() > 0.0
    assert np.all(bad.x[near, 2] < 0.1)  # left behind: the bar jumped over them


def test_pins_follow_their_joint() -> None:
    body = default_body()
    g = make_skirt(body, 400)
    model = build_model(g)
    p0 = standing_pose(body)
    p1 = p0.copy()
    p1[3:6] = [0.0, np.pi / 2, 0.0]  # turn the whole body 90 degrees about +Y
    p1[0] += 0.3
    keys = pose_keys(body, np.stack([p0, p1]))
    targets = keys.pin_targets(g.pin_joint, g.pin_local, g.pin_axis, g.pin_axis_s, g.pin_axis_local)
    np.testing.assert_allclose(targets[0], g.rest[g.pin_index], atol=1e-12)
    rel0 = g.rest[g.pin_index] - p0[:3]
    np.testing.assert_allclose(targets[1] - p1[:3], rel0 @ rotvec_to_matrix(p1[3:6]).T, atol=1e-9)
    assert np.allclose((targets[1] - p1[:3])[:, 0], rel0[:, 2], atol=1e-9)  # +Z turned onto +X
    out = step(initial_state(model), model, keys.track, targets, 1 / 30)
    np.testing.assert_allclose(out.x[g.pin_index], targets[-1], atol=1e-12)


def test_covered_pins_are_released_and_collide() -> None:
    body = default_body()
    g = make_cape(body, 400)
    pose = standing_pose(body)
    keys = pose_keys(body, np.stack([pose, pose]))
    targets = keys.pin_targets(g.pin_joint, g.pin_local)
    assert not keys.covered(targets, 0.006).any()  # the collar clears the body at rest
    # bury two collar pins at the chest joint, inside the thorax: they are reported as covered
    buried = targets.copy()
    buried[:, :2] = fk(pose, body)[JOINT_INDEX["chest"]]
    covered = keys.covered(buried, 0.006)
    assert covered[:2].all() and not covered[2:].any()
    model = build_model(g)
    out = step(initial_state(model), model, keys.track, buried, 1 / 30, released=covered)
    d, _, _ = round_cone_reference(out.x[g.pin_index[:2]], keys.track.a[-1], keys.track.b[-1], body.capsule_radii[:, 0],
                                   body.capsule_radii[:, 1])
    assert d.min() > 0.0  # released pins are free particles: pushed out, not held inside
    np.testing.assert_allclose(out.x[g.pin_index[2:]], buried[-1, 2:], atol=1e-12)
    pushed = keys.push_out(buried, 0.006)
    d, _, _ = round_cone_reference(pushed[0], keys.track.a[0], keys.track.b[0], body.capsule_radii[:, 0],
                                   body.capsule_radii[:, 1])
    assert d.min() >= 0.006 - 1e-9


def test_skirt_waistband_clears_kicks_and_bends_and_hangs_inside_the_arms() -> None:
    body = default_body()
    g = make_skirt(body, 600)
    pose = standing_pose(body)
    a, b = capsule_endpoints(body, pose)
    d, _, _ = round_cone_reference(g.rest, a, b, body.capsule_radii[:, 0], body.capsule_radii[:, 1])
    assert d.min() > 0.006  # the rest shape clears every capsule, arms included: hands swing outside
    hips = [CAPSULE_INDEX[n] for n in ("pelvis", "l_thigh", "r_thigh")]
    assert d[g.pin_index][:, hips].min() >= REST_CLEARANCE  # in 3D: the hip spheres reach the waist's height
    spine_y = fk(pose, body)[JOINT_INDEX["spine"], 1]
    assert spine_y <= g.rest[g.pin_index, 1].min() <= spine_y + 0.01  # raised no more than that takes
    tip = fk(pose, body)[JOINT_INDEX["l_hand_tip"]]
    side = (np.abs(g.rest[:, 0]) > 2 * np.abs(g.rest[:, 2])) & (g.rest[:, 1] > tip[1])
    assert side.sum() > 10 and np.all(np.abs(g.rest[side, 0]) < tip[0])  # inside the hanging arms
    kick, bow = pose.copy(), pose.copy()
    hip, spine = 3 + 3 * ROT_JOINTS.index("l_hip"), 3 + 3 * ROT_JOINTS.index("spine")
    kick[hip:hip + 3] = [-np.pi / 2, 0.0, 0.0]  # thigh horizontal, forwards
    bow[spine:spine + 3] = [0.3, 0.0, 0.0]  # trunk bent forwards ~17 degrees (deeper: the front is released)
    for p1 in (kick, bow):
        keys = pose_keys(body, np.stack([pose, p1]))
        t = keys.pin_targets(g.pin_joint, g.pin_local, g.pin_axis, g.pin_axis_s, g.pin_axis_local)
        np.testing.assert_allclose(t[0], g.rest[g.pin_index], atol=1e-12)
        assert not keys.covered(t, 0.006).any()  # no thigh through the waistband, no trunk over it
    knee = fk(kick, body)[JOINT_INDEX["l_knee"]]
    assert knee[2] > 0.3  # the kick really lifts the thigh forwards


def test_collar_moves_with_the_chest() -> None:
    body = default_body()
    g = make_cape(body, 300)
    assert set(g.pin_joint.tolist()) == {JOINT_INDEX["chest"]}
    pose = standing_pose(body)
    bent = pose.copy()
    k = 3 + 3 * ROT_JOINTS.index("spine")
    bent[k] = 0.5  # lean forward
    keys = pose_keys(body, np.stack([pose, bent]))
    t = keys.pin_targets(g.pin_joint, g.pin_local)
    assert np.all(t[1, :, 2] > t[0, :, 2] + 0.05)  # the collar went forward with the torso


def test_broad_phase_kernel_matches_numpy_and_never_hides_a_contact() -> None:
    """The candidate masks agree with the reference, and collision restricted to the candidates
    gives exactly the full result, also for particles that moved past the slack since the masks
    were gathered (they fall back to every capsule)."""
    body = default_body()
    pose = standing_pose(body)
    keys = pose_keys(body, np.stack([pose, pose]))
    a, b, r = keys.track.a[0], keys.track.b[0], body.capsule_radii
    rng = np.random.default_rng(11)
    x = rng.uniform([-0.4, -0.05, -0.3], [0.4, 1.8, 0.3], size=(4000, 3))
    free = rng.random(len(x)) > 0.1
    margin, slack = 0.006, 0.02
    cand, xb = np.empty(len(x), np.int64), np.empty_like(x)
    K.broad_phase(x, free.astype(float), a, b, r, margin + slack, cand, xb)
    np.testing.assert_array_equal(cand, broad_phase_reference(x, free, a, b, r, margin + slack))
    np.testing.assert_array_equal(xb, x)
    assert 0 < (cand != 0).sum() < len(x) and (cand & (cand - 1) != 0).sum() > 50  # several capsules at joints
    # then the particles move (half of them further than the slack) and the body moves a little
    x1 = x + rng.normal(0.0, 0.012, x.shape)
    lift = np.array([0.0, 0.003, 0.0])
    a1, b1 = a + lift, b + lift
    v = rng.normal(0.0, 0.5, x.shape)
    outs = []
    for mask, ref in ((np.full(len(x), K.ALL_CAPSULES), xb), (cand, xb)):
        xx, vv, contact = x1.copy(), v.copy(), np.zeros((len(x), 6))
        touch = np.ones(len(x), dtype=bool)
        K.collide(xx, vv, free.astype(float), a, b, a1, b1, r, margin, 0.3, 0.004, 0.0, True, contact,
                  mask, ref, slack - 0.003, x, touch)  # the capsules moved 3 mm: the particles may move the rest
        np.testing.assert_array_equal(touch, touching_reference(contact))  # the flags written on the way
        outs.append((xx, vv, contact))
    xn, vn, cn = x1.copy(), v.copy(), np.zeros((len(x), 6))
    collide_reference(xn, vn, free, a, b, a1, b1, r, margin, 0.3, 0.004, 0.0, cn, x)
    for xx, vv, contact in outs:
        np.testing.assert_allclose(xx, xn, atol=1e-12)
        np.testing.assert_allclose(vv, vn, atol=1e-9)
        np.testing.assert_allclose(contact, cn, atol=1e-12)
    assert np.abs(xn - x1).max() > 0.01  # contacts did happen


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_particle_pushed_through_a_thin_capsule_goes_back_to_its_side(backend: str) -> None:
    """A forearm (r = 3 cm) moving down 1 cm onto cloth that the strain limit dragged 4 cm down
    inside it: projected to the nearest surface the cloth would come out below the arm (through
    it); it is put back above, where it was relative to the arm at the start of the substep."""
    r, dt, margin = np.array([[0.03, 0.03]]), 0.004, 0.006
    a0, b0 = np.array([[0.0, 0.01, 0.0]]), np.array([[0.3, 0.01, 0.0]])
    a1, b1 = a0 - [0.0, 0.01, 0.0], b0 - [0.0, 0.01, 0.0]
    xprev = np.array([[0.15, 0.045, 0.0], [0.15, 0.045, 0.0]])  # 5 mm above the arm
    x = np.array([[0.15, 0.005, 0.0], [0.15, -0.012, 0.0]])  # above / past the axis
    v = np.array([[0.0, -3.0, 0.0], [0.0, -3.0, 0.0]])
    _collide(backend, x, v, a0, b0, a1, b1, r, margin, 0.0, dt, xprev=xprev)
    np.testing.assert_allclose(x[0], [0.15, 0.03 + margin, 0.0], atol=1e-12)  # nearest surface: above anyway
    np.testing.assert_allclose(x[1], [0.15, 0.03 + margin, 0.0], atol=1e-12)  # not below the arm
    np.testing.assert_allclose(v[:, 1], -2.5, atol=1e-9)  # no faster than the arm (-2.5 m/s) into it
    x = np.array([[0.15, -0.012, 0.0]])
    _collide(backend, x, v[:1].copy(), a0, b0, a1, b1, r, margin, 0.0, dt)  # no memory: nearest surface
    np.testing.assert_allclose(x[0], [0.15, -0.03 - margin, 0.0], atol=1e-12)


def _bent_keys_and_points(seed: int, n: int):  # type: ignore[no-untyped-def]
    """Three keys (standing, left elbow bent, standing) and ``(3, n, 3)`` random points round the body."""
    body = default_body()
    pose = standing_pose(body)
    bent = pose.copy()
    elbow = 3 + 3 * ROT_JOINTS.index("l_elbow")
    bent[elbow:elbow + 3] = [0.0, 0.0, 1.2]
    keys = pose_keys(body, np.stack([pose, bent, pose]))
    pts = np.random.default_rng(seed).uniform([-0.4, 0.6, -0.3], [0.4, 1.5, 0.3], size=(3, n, 3))
    return body, keys, pts


def _segments(p: np.ndarray, wrap: bool) -> np.ndarray:
    """Segment lengths ``(K + 1, S)`` of seams ``p (K + 1, P, 3)``, closed round when ``wrap``."""
    ring = np.concatenate([p, p[:, :1]], axis=1) if wrap else p
    out: np.ndarray = np.linalg.norm(np.diff(ring, axis=1), axis=-1)
    return out


@pytest.mark.parametrize(("spread", "wrap", "keep"), [(0, False, False), (6, False, False), (6, True, False),
                                                      (0, False, True), (6, True, True)])
def test_slide_seam_kernel_matches_numpy(spread: int, wrap: bool, keep: bool) -> None:
    """The numba seam slide equals its numpy reference, leaves its input alone and clears the body;
    with the seam's rest lengths (here shorter than the random seam's) also the length pass."""
    _body, keys, pts = _bent_keys_and_points(9, 300)
    rest = 0.8 * _segments(pts, wrap)[0] if keep else None
    before = pts.copy()
    got = keys.slide_seam(pts, 0.006, spread, wrap, rest)
    ref = slide_seam_reference(keys.track, pts, 0.006, spread, wrap, check_seam_rest(pts.shape[1], rest, wrap))
    np.testing.assert_array_equal(pts, before)
    assert (np.linalg.norm(ref - pts, axis=-1) > 1e-9).sum() > 40
    np.testing.assert_allclose(got, ref, atol=1e-9, rtol=0)
    if keep:
        plain = slide_seam_reference(keys.track, pts, 0.006, spread, wrap, np.zeros(0))
        assert np.abs(ref - plain).max() > 0.01  # the length pass moved the pins
    with pytest.raises(ValueError, match="spread"):
        keys.slide_seam(pts, 0.006, -1)
    with pytest.raises(ValueError, match="rest"):
        keys.slide_seam(pts, 0.006, spread, wrap, np.ones(pts.shape[1] - 2))


@pytest.mark.parametrize("wrap", [False, True])
def test_keep_seam_length_kernel_matches_numpy(wrap: bool) -> None:
    """The length pass's kernel equals its numpy reference on random seams round a bent arm whose
    rest lengths are 70-100 % of their segments, leaves its input alone, and a seam already within
    its rest lengths comes back unchanged."""
    _body, keys, pts = _bent_keys_and_points(4, 200)
    seg = _segments(pts, wrap)[0]
    rest = seg * np.random.default_rng(5).uniform(0.7, 1.0, len(seg))
    before = pts.copy()
    got = keys.keep_seam_length(pts, 0.006, rest)
    ref = keep_seam_length_reference(keys.track, pts, 0.006, rest)
    np.testing.assert_array_equal(pts, before)
    np.testing.assert_allclose(got, ref, atol=1e-9, rtol=0)
    assert np.abs(ref - pts).max() > 0.01
    assert (_segments(ref, wrap) / rest).max() < (_segments(pts, wrap) / rest).max()
    np.testing.assert_array_equal(keys.keep_seam_length(pts, 0.006, 1.1 * _segments(pts, wrap).max(axis=0)), pts)
    with pytest.raises(ValueError, match="rest"):
        keys.keep_seam_length(pts, 0.006, rest[:-3])


def _seam_under_a_ball(depth: float) -> tuple[AvatarKeys, np.ndarray]:
    """A straight seam of 41 pins 1 cm apart along x, and a ball of radius 5 cm (a head thrown back)
    sunk ``depth`` metres into its middle from above."""
    centre = np.array([0.0, 0.05 - depth, 0.0])
    a = np.repeat(centre[None, None], 2, axis=0)
    track = CapsuleTrack(a, a.copy(), np.array([[0.05, 0.05]]))
    keys = AvatarKeys(track, np.zeros((2, 1, 3)), np.repeat(np.eye(3)[None, None], 2, axis=0))
    x = np.linspace(-0.2, 0.2, 41)
    seam = np.stack([x, np.zeros_like(x), np.zeros_like(x)], axis=1)
    return keys, np.repeat(seam[None], 2, axis=0)


def test_slid_seam_keeps_its_length_under_a_body_part() -> None:
    """Pushing each covered pin along its own normal spreads a seam round the ball that covers it
    (the cape's collar under the skull); sliding it carries the covered pins together and spreads
    the step over their neighbours, so the pins' spacing stays near its rest length."""
    keys, seam = _seam_under_a_ball(0.02)
    r = keys.track.radii[0, 0]

    def worst_strain(p: np.ndarray) -> float:
        return float((np.linalg.norm(np.diff(p[0], axis=0), axis=1) / 0.01 - 1.0).max())

    def clearance(p: np.ndarray) -> float:
        return float(np.linalg.norm(p[0] - keys.track.a[0, 0], axis=1).min() - r)

    radial = keys.push_out(seam, 0.006)
    assert clearance(radial) >= 0.006 - 1e-9 and worst_strain(radial) > 0.4
    def slide(backend: str, spread: int, rest: np.ndarray | None = None) -> np.ndarray:
        if backend == "numba":
            return keys.slide_seam(seam, 0.006, spread, rest=rest)
        return slide_seam_reference(keys.track, seam, 0.006, spread, False, np.zeros(0) if rest is None else rest)

    for backend in ("numba", "numpy"):
        slid = slide(backend, 8)
        assert clearance(slid) >= 0.006 - 1e-9
        assert worst_strain(slid) < 0.1, backend
        assert worst_strain(slide(backend, 0)) > 0.1  # the spread matters
        # the length pass (given the rest lengths) shortens what the slide left stretched: the spread
        # slide's 3.5 % to within its slack, the unspread slide's step (over 10 %) by half
        for spread, bound in ((8, SEAM_LENGTH_SLACK + 0.005), (0, 0.6 * worst_strain(keys.slide_seam(seam, 0.006, 0)))):
            kept = slide(backend, spread, np.full(40, 0.01))
            assert clearance(kept) >= 0.006 - 1e-9
            plain = worst_strain(keys.slide_seam(seam, 0.006, spread))
            assert worst_strain(kept) < min(bound, plain), (backend, spread)
    free, _ = _seam_under_a_ball(-0.01)  # the ball 1 cm clear of the seam: nothing moves
    np.testing.assert_allclose(free.slide_seam(seam, 0.006, 8), seam, atol=0)
    np.testing.assert_allclose(free.slide_seam(seam, 0.006, 8, rest=np.full(40, 0.01)), seam, atol=0)


def test_covered_kernel_matches_numpy() -> None:
    body, keys, pts = _bent_keys_and_points(2, 500)
    reach = np.full(len(body.capsule_radii), 0.006)
    reach[::3] = 0.04
    for m in (0.006, reach):
        got, ref = keys.covered(pts, m), covered_reference(keys.track, pts, m)
        np.testing.assert_array_equal(got, ref)
        assert 20 < got.sum() < 480


def test_push_out_kernel_matches_numpy() -> None:
    """The numba push-out of pin targets equals the numpy reference, and its result clears the body."""
    body, keys, pts = _bent_keys_and_points(5, 400)
    before = pts.copy()
    got, ref = keys.push_out(pts, 0.006), push_out_reference(keys.track, pts, 0.006)
    np.testing.assert_array_equal(pts, before)  # the input is not modified
    moved = np.linalg.norm(ref - pts, axis=-1) > 1e-9
    assert 40 < moved.sum() < 1100  # many points started inside the body, many outside
    np.testing.assert_allclose(got, ref, atol=1e-9, rtol=0)
    with pytest.raises(ValueError, match="shape"):
        keys.push_out(pts[:2], 0.006)  # a key count other than the track's
    clear = [round_cone_reference(got[k], keys.track.a[k], keys.track.b[k], body.capsule_radii[:, 0],
                                  body.capsule_radii[:, 1])[0].min(axis=1) >= 0.006 - 1e-9 for k in range(3)]
    assert np.mean(clear) > 0.97  # two passes clear nearly all (a point deep in a joint may need more)


def test_skirt_hip_ease_widens_the_hips_but_stays_inside_the_arms() -> None:
    body = default_body()
    g0, g1 = make_skirt(body, 600), make_skirt(body, 600, hip_ease=0.02)
    assert g0.grid_shape == g1.grid_shape
    centre = g0.rest[g0.pin_index].mean(axis=0)
    r0 = np.hypot(*(g0.rest - centre)[:, [0, 2]].T)
    r1 = np.hypot(*(g1.rest - centre)[:, [0, 2]].T)
    assert np.all(r1 >= r0 - 1e-12) and np.all(r1 <= r0 + 0.02 + 1e-9)
    assert (r1 - r0).max() > 0.015  # some of the yoke gets the whole ease
    np.testing.assert_array_equal(g1.rest[g1.pin_index], g0.rest[g0.pin_index])  # the waistband is the same
    a, b = capsule_endpoints(body, standing_pose(body))
    d, _, _ = round_cone_reference(g1.rest, a, b, body.capsule_radii[:, 0], body.capsule_radii[:, 1])
    assert d.min() > 0.006  # the hands still hang outside the cloth


def _straddle_scene(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    """``n`` stretched springs, each across one of two capsules (a limb between its two particles),
    besides slack springs and stretched springs clear of the body."""
    a = np.array([[0.0, 0.0, 0.0], [0.0, 0.5, 0.0]])
    b = np.array([[0.0, 0.4, 0.0], [0.4, 0.5, 0.0]])
    radii = np.array([[0.05, 0.04], [0.04, 0.04]])
    pts, springs, hi = [], [], []
    for k in range(n):
        kind = k % 4
        c = k % 2
        t = rng.uniform(0.2, 0.8)
        axis_pt = a[c] + t * (b[c] - a[c])
        u = (b[c] - a[c]) / np.linalg.norm(b[c] - a[c])
        side = np.cross(u, [0.0, 0.0, 1.0])
        side /= np.linalg.norm(side)
        off = rng.uniform(-0.02, 0.02) * np.array([0.0, 0.0, 1.0])  # the chord passes off the axis
        if kind == 3:  # a stretched spring beside the limb, clear of it
            off = np.array([0.0, 0.0, 0.09])
        p0, p1 = axis_pt - 0.052 * side + off, axis_pt + 0.052 * side + off
        length = np.linalg.norm(p1 - p0)
        pts += [p0, p1]
        springs.append([2 * k, 2 * k + 1])
        hi.append(length / (1.5 if kind != 2 else 0.9))  # kind 2: slack, never tested
    x = np.array(pts)
    inv_mass = np.ones(len(x))
    inv_mass[0] = 0.0  # a pinned end does not move: its partner takes the whole lift
    return x, inv_mass, np.array(springs, np.int64), np.array(hi), a, b, radii


OPPOSED = ClothParams().straddle_opposed


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_cloth_draped_round_a_limb_is_not_lifted(rng: np.random.Generator, backend: str) -> None:
    """A stretched spring whose chord cuts into a limb with both ends on the same side of it (cloth
    lying over an arm, ends 80 degrees apart round the axis) is left to collision and the strain
    limit; with the side test off (``opposed`` > 1) it would be lifted (and pumped along the limb)."""
    a, b = np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.4, 0.0]])
    radii = np.array([[0.04, 0.04]])
    pts = []
    for _ in range(6):
        y = rng.uniform(0.1, 0.3)
        base = rng.uniform(0.0, 2.0 * np.pi)
        for ang in (base - np.radians(40.0), base + np.radians(40.0)):
            pts.append([0.0405 * np.cos(ang), y, 0.0405 * np.sin(ang)])
    x = np.array(pts)
    springs = np.arange(len(x), dtype=np.int64).reshape(-1, 2)
    hi = np.linalg.norm(x[1::2] - x[::2], axis=1) / 1.3
    inv_mass = np.ones(len(x))
    fn = K.release_straddles if backend == "numba" else release_straddles_reference
    xb = x.copy()
    assert fn(xb, inv_mass, springs, hi, 1.0, a, b, radii, 0.006, OPPOSED) == 0
    np.testing.assert_array_equal(xb, x)
    assert fn(xb, inv_mass, springs, hi, 1.0, a, b, radii, 0.006, 1.5) == len(springs)  # the chords are inside


def test_straddled_spring_is_lifted_off_the_limb(rng: np.random.Generator) -> None:
    """A stretched spring with a limb between its particles is moved to one side of the limb (both
    backends agree), so its chord clears the capsule by the margin; slack springs, springs clear of
    the body and pins are left alone."""
    x, inv_mass, springs, hi, a, b, radii = _straddle_scene(rng, 24)
    margin = 0.006
    out = {}
    for backend in ("numba", "numpy"):
        xb = x.copy()
        fn = K.release_straddles if backend == "numba" else release_straddles_reference
        out[backend] = (fn(xb, inv_mass, springs, hi, 1.0, a, b, radii, margin, OPPOSED), xb)
    (n, got), (n_ref, ref) = out["numba"], out["numpy"]
    assert n == n_ref == 12  # kinds 0 and 1 of 24
    np.testing.assert_allclose(got, ref, atol=1e-12, rtol=0)
    assert got[0].tolist() == x[0].tolist()  # the pin
    ts = np.linspace(0.0, 1.0, 41)[:, None]
    for k, (i, j) in enumerate(springs):
        moved = not np.allclose(got[[i, j]], x[[i, j]])
        assert moved == (k % 4 in (0, 1)), k
        if moved:
            depth = [round_cone_reference(c[i] * (1 - ts) + c[j] * ts, a, b, radii[:, 0], radii[:, 1])[0].min()
                     for c in (x, got)]
            if k == 0:  # one end pinned: the chord turns about it, lifted at the deepest sample only
                assert depth[0] < -0.02 and depth[1] > 0.2 * depth[0]
            else:  # a symmetric straddle: the chord is carried clear, to the margin
                assert depth[0] < -0.01 and abs(depth[1] - margin) < 1e-3

