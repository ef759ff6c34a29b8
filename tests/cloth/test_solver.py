"""Cloth solver: spring forces and integration against hand-computed cases, energy of a hanging
cloth, strain limiting, and the numba kernels against their numpy references."""

from __future__ import annotations

import numpy as np
import pytest

from cloth_client.contact.collision import CapsuleTrack
from cloth_client.solver import force_kernels as F
from cloth_client.solver import strain_kernels as S
from cloth_client.solver.cloth import (
    ClothParams,
    build_model,
    energy,
    initial_state,
    step,
    step_reference,
    structural_strain,
    tethers_held,
)
from cloth_client.solver.garment import make_cape, make_sheet, make_skirt
from cloth_client.solver.reference import (
    drag_forces_reference,
    integrate_reference,
    line_limit_reference,
    long_range_attach_reference,
    ring_limit_reference,
    spring_forces_reference,
    spring_strain_reference,
    strain_limit_reference,
    touching_reference,
    worst_stretch2_reference,
)
from protocol.skeleton import default_body

EMPTY = CapsuleTrack(np.zeros((2, 0, 3)), np.zeros((2, 0, 3)), np.zeros((0, 2)))
FREE = dict(floor=None, air_density=0.0)  # no floor, no drag
#: The numba step and its plain numpy reference, by the name tests are parametrised with.
STEPS = {"numba": step, "numpy": step_reference}


def _pins(g, n_keys: int = 2) -> np.ndarray:  # type: ignore[no-untyped-def]
    return np.repeat(g.rest[g.pin_index][None], n_keys, axis=0)


# --- hand-computed cases ----------------------------------------------------------------------------

@pytest.mark.parametrize("fn", ["numba", "numpy"])
def test_spring_force_hand_computed(fn: str) -> None:
    x = np.array([[0.0, 0.0, 0.0], [1.5, 0.0, 0.0], [1.5, 2.0, 0.0]])
    v = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    springs = np.array([[0, 1], [1, 2]])
    rest, k, kd = np.array([1.0, 2.0]), np.array([10.0, 3.0]), np.array([0.5, 0.0])
    if fn == "numba":
        f = np.zeros_like(x)
        F.spring_forces(x, v, springs, rest, k, kd, f)
    else:
        f = spring_forces_reference(x, v, springs, rest, k, kd)
    # spring 0: stretched by 0.5 -> 5 N, separating at 2 m/s along the axis -> +1 N damping = 6 N
    # spring 1: exactly at rest (length 2) but v1 - v2 = (2, 0, 0) is perpendicular -> no force
    np.testing.assert_allclose(f, [[6.0, 0, 0], [-6.0, 0, 0], [0, 0, 0]], atol=1e-12)


def test_compressed_spring_pushes_apart() -> None:
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.6, 0.0]])
    f = spring_forces_reference(x, np.zeros_like(x), np.array([[0, 1]]), np.array([1.0]), np.array([2.0]),
                                np.array([0.0]))
    # 0.4 m short at 2 N/m: 0.8 N pushing particle 0 (below) down and particle 1 up
    np.testing.assert_allclose(f, [[0, -0.8, 0], [0, 0.8, 0]], atol=1e-12)


def test_semi_implicit_euler_hand_computed() -> None:
    x = np.array([[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])
    v = np.array([[0.5, 0.0, -1.0], [1.0, 1.0, 1.0]])
    f = np.array([[0.2, 0.0, 0.0], [5.0, 5.0, 5.0]])
    inv_mass = np.array([2.0, 0.0])  # particle 1 is pinned
    g, dt, damp = np.array([0.0, -9.81, 0.0]), 0.01, 1.0 / (1.0 + 0.5 * 0.01)
    xp = np.empty_like(x)
    F.integrate(x, v, f, inv_mass, g, damp, dt, xp)
    v_expected = (np.array([0.5, 0.0, -1.0]) + dt * (np.array([0.4, 0.0, 0.0]) + g)) * damp
    np.testing.assert_allclose(v[0], v_expected, rtol=1e-13)
    np.testing.assert_allclose(x[0], [1.0, 2.0, 3.0] + dt * v_expected, rtol=1e-13)
    np.testing.assert_array_equal(x[1], [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(v[1], [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(xp, [[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]])


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_free_fall_matches_discrete_formula(backend: str) -> None:
    """All pins released, springs at rest, no damping/drag/floor: every particle follows the
    semi-implicit Euler recursion v_n = n g h, x_n = x_0 + g h^2 n (n + 1) / 2 exactly."""
    g = make_sheet(4, 5, 0.05)
    model = build_model(g, ClothParams(damping_ratio=0.0, mass_damping=0.0, **FREE))
    state = initial_state(model)
    n, dt = 7, 0.021
    out = STEPS[backend](state, model, EMPTY, _pins(g), dt, released=np.ones(len(g.pin_index), bool), n_substeps=n)
    h = dt / n
    np.testing.assert_allclose(out.v[:, 1], -9.81 * h * n, rtol=1e-9)
    np.testing.assert_allclose(out.x[:, 1], g.rest[:, 1] - 9.81 * h * h * n * (n + 1) / 2, rtol=1e-9)
    np.testing.assert_allclose(out.x[:, [0, 2]], g.rest[:, [0, 2]], atol=1e-12)
    assert out.substeps == n and out.t == pytest.approx(dt)


# --- energy of a hanging cloth ----------------------------------------------------------------------

def _swing(params: ClothParams, seconds: float, fps: float = 60.0) -> tuple[np.ndarray, object, object]:
    g = make_sheet(10, 10, 0.05)  # horizontal, pinned along its first row: it swings down
    model = build_model(g, params)
    state = initial_state(model)
    e = [energy(model, state)["total"]]
    for _ in range(round(seconds * fps)):
        state = step(state, model, EMPTY, _pins(g), 1.0 / fps)
        e.append(energy(model, state)["total"])
    return np.array(e), model, state


def test_undamped_hanging_cloth_conserves_energy() -> None:
    """Conservative springs + symplectic Euler: the total energy oscillates but does not drift."""
    p = ClothParams(damping_ratio=0.0, mass_damping=0.0, limit_iterations=0, final_sweeps=0, tethers=False,
                    **FREE)
    e, model, state = _swing(p, 2.0)
    scale = model.garment.total_mass * 9.81 * 0.45  # m g L of the sheet
    assert np.all(np.isfinite(e))
    assert np.abs(e - e[0]).max() < 0.05 * scale
    assert energy(model, state)["kinetic"] > 0.05 * scale  # still swinging


def test_damped_hanging_cloth_loses_energy_and_comes_to_rest() -> None:
    e, model, state = _swing(ClothParams(floor=None), 4.0)
    scale = model.garment.total_mass * 9.81 * 0.45
    assert np.all(np.diff(e) < 1e-3 * scale)  # never gains energy (to rounding of the projections)
    assert e[-1] < e[0] - 0.3 * scale  # it fell and dissipated
    assert energy(model, state)["kinetic"] < 1e-3 * scale
    hem = state.x.reshape(10, 10, 3)[-1]
    drop = model.garment.rest[0, 1] - hem[:, 1]
    assert np.all(drop > 0.45 * 0.95) and np.all(drop < 0.45 * (1 + model.params.max_stretch) + 1e-3)
    assert structural_strain(model, state.x).max() <= model.params.max_stretch + 0.01


def test_strain_limiting_keeps_a_heavy_cloth_short() -> None:
    """Soft springs alone would let a 1 m column sag by tens of percent; the limiter holds it."""
    g = make_sheet(40, 6, 0.025)
    loose = build_model(g, ClothParams(limit_iterations=0, final_sweeps=0, tethers=False, **FREE))
    tight = build_model(g, ClothParams(**FREE))
    results = []
    for model in (loose, tight):
        state = initial_state(model)
        for _ in range(120):
            state = step(state, model, EMPTY, _pins(g), 1 / 60)
        results.append(structural_strain(model, state.x).max())
    assert results[0] > 0.2
    assert results[1] <= tight.params.max_stretch + 0.01


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_extra_rounds_run_while_a_spring_is_stretched_beyond_the_trigger(backend: str) -> None:
    """A hanging sheet whose pinned edge is jerked 30-50 cm along itself in one 60 Hz step of one or
    two substeps: the fixed final rounds leave springs over ``extra_above`` (8 %); the extra rounds
    run until every structural spring is within it, and are skipped when none is over."""
    g = make_sheet(20, 12, 0.025)
    worst, calm = [], []
    for extra in (0, 4):
        model = build_model(g, ClothParams(extra_rounds=extra, air_density=0.0))
        state = initial_state(model)
        for _ in range(60):
            state = STEPS[backend](state, model, EMPTY, _pins(g), 1 / 60)
        calm.append(STEPS[backend](state, model, EMPTY, _pins(g), 1 / 60, n_substeps=2).x)
        strains = []
        for shift in (0.3, 0.4, 0.5):
            for n_sub in (1, 2):
                jerk = _pins(g)
                jerk[1] += [shift, 0.0, 0.0]
                jerked = STEPS[backend](state, model, EMPTY, jerk, 1 / 60, n_substeps=n_sub)
                strains.append(structural_strain(model, jerked.x).max())
        worst.append(max(strains))
    assert worst[0] > 0.085  # over the 8 % trigger without them
    assert worst[1] <= 0.08 + 1e-12
    np.testing.assert_array_equal(calm[0], calm[1])  # nothing over the trigger: no extra round ran


# --- numba kernels against the numpy references -----------------------------------------------------

@pytest.fixture(scope="module", params=["cape", "skirt"])
def model(request: pytest.FixtureRequest):  # type: ignore[no-untyped-def]
    body = default_body()
    g = (make_cape if request.param == "cape" else make_skirt)(body, 400)
    return build_model(g)


def _perturbed(model, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    x = model.garment.rest + rng.normal(0.0, 0.006, model.garment.rest.shape)
    v = rng.normal(0.0, 0.5, x.shape)
    contact = np.zeros((len(x), 6))
    contact[::5, 1] = 1.0
    contact[::7, 3:6] = [0.6, 0.0, 0.8]
    return x, v, contact


def test_force_kernels_match_numpy(model, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    x, v, _ = _perturbed(model, rng)
    f = np.zeros_like(x)
    F.spring_forces(x, v, model.springs, model.rest, model.k, model.kd, f)
    ref = spring_forces_reference(x, v, model.springs, model.rest, model.k, model.kd)
    np.testing.assert_allclose(f, ref, atol=1e-12)
    f[:] = 0.0
    wind = np.array([1.0, 0.0, -2.0])
    F.drag_forces(x, v, model.garment.triangles, 0.6, wind, np.empty_like(x), f)
    np.testing.assert_allclose(f, drag_forces_reference(x, v, model.garment.triangles, 0.6, wind), atol=1e-12)


def test_integrate_kernel_matches_numpy(model, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    """Semi-implicit Euler of the free particles: the kernel (damping as a factor) and the reference
    (damping as a division) agree to rounding; pinned particles stay, and both return the old positions."""
    x, v, _ = _perturbed(model, rng)
    f = rng.normal(0.0, 0.01, x.shape)
    gravity, c, dt = np.array([0.0, -9.81, 0.0]), 0.3, 1 / 240
    xk, vk, xp = x.copy(), v.copy(), np.empty_like(x)
    F.integrate(xk, vk, f, model.inv_mass, gravity, 1.0 / (1.0 + c * dt), dt, xp)
    xr, vr = x.copy(), v.copy()
    xp_ref = integrate_reference(xr, vr, f, model.inv_mass, gravity, c, dt)
    np.testing.assert_allclose(xk, xr, atol=1e-14, rtol=0)
    np.testing.assert_allclose(vk, vr, atol=1e-12, rtol=0)
    np.testing.assert_array_equal(xp, x)
    np.testing.assert_array_equal(xp_ref, x)
    pinned = model.inv_mass == 0
    assert pinned.any() and np.array_equal(xk[pinned], x[pinned]) and np.array_equal(vk[pinned], v[pinned])
    assert np.abs(xk - x).max() > 1e-4  # the free particles did move


def test_constraint_kernels_match_numpy(model, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    x, _, contact = _perturbed(model, rng)
    g, p = model.garment, model.params
    a, b = x.copy(), x.copy()
    S.long_range_attach(a, model.inv_mass, g.anchor, model.reach * 0.97)
    long_range_attach_reference(b, model.inv_mass, g.anchor, model.reach * 0.97)
    np.testing.assert_allclose(a, b, atol=1e-12)
    # each kernel from identical inputs: chained, rounding could flip which constraints are active
    for lines, rest in ((model.lines_v, model.rest_v), (model.lines_h, model.rest_h)):
        b = a.copy()
        S.line_limit(a, model.inv_mass, lines, rest, p.max_stretch, p.max_compression, contact)
        line_limit_reference(b, model.inv_mass, lines, rest, p.max_stretch, p.max_compression, contact)
        np.testing.assert_allclose(a, b, atol=1e-12)
    rings = (model.lines_s, model.rest_s)
    before = a.copy()
    if model.garment.wrap:  # the rings of the perturbed cloth, before the row solves brought them in
        before[:] = x
    a, b = before.copy(), before.copy()
    S.ring_limit(a, model.inv_mass, *rings, p.max_stretch, p.max_compression, contact)
    ring_limit_reference(b, model.inv_mass, *rings, p.max_stretch, p.max_compression, contact)
    np.testing.assert_allclose(a, b, atol=1e-12)
    assert (np.abs(a - before).max() > 1e-3) == model.garment.wrap  # rings solved (a cape has none)
    b = a.copy()
    S.strain_limit(a, model.inv_mass, model.lim_springs, model.lim_lo, model.lim_hi, 3, contact)
    strain_limit_reference(b, model.inv_mass, model.lim_springs, model.lim_lo, model.lim_hi, g.limit_batches, 3,
                           contact)
    np.testing.assert_allclose(a, b, atol=1e-12)
    assert np.abs(a - x).max() > 1e-3  # the test did exercise the constraints
    worst = S.worst_stretch2(x, model.lim_springs, model.lim_hi, model.inv_mass)
    assert worst > 1.0
    np.testing.assert_allclose(worst, worst_stretch2_reference(x, model.lim_springs, model.lim_hi, model.inv_mass),
                               rtol=1e-12)
    # springs between two pins are left out of the trigger (no round can shorten them)
    pinned = np.zeros_like(model.inv_mass)
    assert S.worst_stretch2(x, model.lim_springs, model.lim_hi, pinned) == 0.0
    assert worst_stretch2_reference(x, model.lim_springs, model.lim_hi, pinned) == 0.0
    ends = model.lim_springs[np.argmax(np.linalg.norm(x[model.lim_springs[:, 1]] - x[model.lim_springs[:, 0]], axis=1)
                                       / model.lim_hi)]
    held = model.inv_mass.copy()
    held[ends] = 0.0  # the worst spring's two ends pinned: the next worst counts
    got = S.worst_stretch2(x, model.lim_springs, model.lim_hi, held)
    free = held[model.lim_springs].sum(axis=1) > 0
    ratio = (np.linalg.norm(x[model.lim_springs[:, 1]] - x[model.lim_springs[:, 0]], axis=1) / model.lim_hi) ** 2
    assert not free.all() and got <= worst
    np.testing.assert_allclose(got, ratio[free].max(), rtol=1e-12)
    np.testing.assert_allclose(got, worst_stretch2_reference(x, model.lim_springs, model.lim_hi, held), rtol=1e-12)


def test_touch_flags_match_numpy_and_leave_the_strain_passes_unchanged(model, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    """The :func:`touching` flags equal the reference, and each strain pass gives bit for bit the same
    positions with the flags handed in (as the substep kernel does) as when it derives them itself."""
    x, _, contact = _perturbed(model, rng)
    touch = np.empty(len(x), dtype=bool)
    S.touching(contact, touch)
    np.testing.assert_array_equal(touch, touching_reference(contact))
    assert 0 < touch.sum() < len(x)
    p = model.params
    limits = (p.max_stretch, p.max_compression, contact)
    passes = [(S.line_limit, (model.lines_v, model.rest_v, *limits)),
              (S.line_limit, (model.lines_h, model.rest_h, *limits)),
              (S.ring_limit, (model.lines_s, model.rest_s, *limits)),
              (S.strain_limit, (model.lim_springs, model.lim_lo, model.lim_hi, 2, contact))]
    for kernel, args in passes:
        a, b = x.copy(), x.copy()
        kernel(a, model.inv_mass, *args)
        kernel(b, model.inv_mass, *args, touch)
        assert np.array_equal(a, b)
    assert np.abs(a - x).max() > 1e-4


def test_contact_aware_moves_never_go_into_the_surface(model, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    x, _, _ = _perturbed(model, rng)
    contact = np.zeros((len(x), 6))
    contact[:, 1] = 1.0  # every particle rests on a floor below it
    y0 = x[:, 1].copy()
    S.strain_limit(x, model.inv_mass, model.lim_springs, model.lim_lo, model.lim_hi, 4, contact)
    assert np.all(x[:, 1] >= y0 - 1e-12)


@pytest.mark.parametrize("fn", ["numba", "numpy"])
def test_line_solve_slides_a_particle_held_by_a_surface_in_one_pass(fn: str) -> None:
    """Sliding projection: a stretched spring whose free end rests under a surface (the move
    towards the pinned end points into it) is solved in one pass by sliding that end along the
    surface (the correction divided by ``w (1 - (u . n)^2)``), not only the tangential share of it."""
    x = np.array([[0.0, 0.0, 0.0], [0.09, -0.08, 0.0]])
    inv_mass = np.array([0.0, 1.0])
    lines, rest = np.array([[0, 1]]), np.array([[0.1]])
    contact = np.zeros((2, 6))
    contact[1, 1] = -1.0  # the surface lies above particle 1: it may not move up
    (S.line_limit if fn == "numba" else line_limit_reference)(x, inv_mass, lines, rest, 0.03, 0.1, contact)
    assert x[1, 1] == pytest.approx(-0.08, abs=1e-12)  # nothing into the surface
    assert np.linalg.norm(x[1]) == pytest.approx(0.103, abs=0.002)  # without it: 0.111 (8 % over)


@pytest.mark.parametrize("fn", ["numba", "numpy"])
def test_ring_solve_cuts_each_ring_at_its_slackest_spring(fn: str) -> None:
    """Closed rings of 12 free particles, every spring 6 % over its rest length except one slack
    spring (a different one in each ring): each ring is solved as the open chain that starts after
    its slack spring, so every stretched spring comes back to the 3 % limit and the stretch the
    chain's contraction leaves goes to the slack spring (a fixed cut puts it into a stretched one)."""
    m = 12
    theta = np.linspace(0.0, 2.0 * np.pi, m, endpoint=False)
    circle = np.stack([0.2 * np.cos(theta), np.zeros(m), 0.2 * np.sin(theta)], axis=1)
    length = np.linalg.norm(np.roll(circle, -1, axis=0) - circle, axis=1)
    # three rings solved together (particles 0-11, 12-23, 24-35), the slack spring elsewhere in each
    slack_at = np.array([0, 5, 11])
    x = np.concatenate([circle + np.array([0.0, 0.3 * r, 0.0]) for r in range(3)])
    rings = np.arange(3 * m).reshape(3, m)
    rest = np.tile(length / 1.06, (3, 1))
    rest[np.arange(3), slack_at] = length[slack_at] / 0.90  # 10 % slack
    (S.ring_limit if fn == "numba" else ring_limit_reference)(x, np.ones(3 * m), rings, rest, 0.03, 0.2,
                                                             np.zeros((3 * m, 6)))
    for r in range(3):
        ring = x[rings[r]]
        strain = np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1) / rest[r] - 1.0
        assert np.all(np.delete(strain, slack_at[r]) < 0.031), strain  # 3 % to first order
        assert strain[slack_at[r]] < 0.0  # the chain's ends pulled apart into the slack, not past it
    # the same ring cut at a stretched spring (a fixed cut): that spring takes the contraction
    x = circle.copy()
    rest = length / 1.06
    rest[5] = length[5] / 0.90
    order = (8 + 1 + np.arange(m)) % m  # the chain that starts after spring 8 (particles 8 -> 9)
    (S.line_limit if fn == "numba" else line_limit_reference)(x, np.ones(m), order[None], rest[order[:-1]][None],
                                                             0.03, 0.2, np.zeros((m, 6)))
    assert np.linalg.norm(x[9] - x[8]) / rest[8] - 1.0 > 0.10


def test_whole_step_matches_numpy_reference() -> None:
    """The fused numba substep loop runs the same sequence as the numpy reference. (Once constraints
    are active, a rounding-level difference can flip which ones are, so the kernels are compared
    one by one above; here the limits are wide enough to stay inactive while every code path runs.)"""
    g = make_cape(default_body(), 300)
    model = build_model(g, ClothParams(floor=None, max_stretch=0.5, max_compression=0.5, extra_above=0.5))
    rng = np.random.default_rng(7)
    state = initial_state(model, g.rest + rng.normal(0, 0.004, g.rest.shape))
    state.v[:] = rng.normal(0, 0.3, state.v.shape)
    pins = _pins(g, 3) + np.array([0.0, 0.01, 0.02])[:, None, None] * np.array([1.0, 0.0, 0.0])
    a = step(state, model, EMPTY, pins, 1 / 60, n_substeps=4)
    b = step_reference(state, model, EMPTY, pins, 1 / 60, n_substeps=4)
    np.testing.assert_allclose(a.x, b.x, atol=1e-10)
    np.testing.assert_allclose(a.v, b.v, atol=1e-7)
    # with pins let go and the attachments moved to the held ones (every particle is tethered)
    released = np.zeros(len(g.pin_index), dtype=bool)
    released[:3] = True
    tight = build_model(g, ClothParams(floor=None, max_stretch=0.5, max_compression=0.5, extra_above=0.5))
    tethers = tethers_held(tight, released)
    a = step(state, tight, EMPTY, pins, 1 / 60, released=released, tethers=tethers, n_substeps=4)
    b = step_reference(state, tight, EMPTY, pins, 1 / 60, released=released, tethers=tethers, n_substeps=4)
    np.testing.assert_allclose(a.x, b.x, atol=1e-10)
    # without constraint projections the substeps are smooth, so several stay in step too
    loose = build_model(g, ClothParams(floor=None, limit_iterations=0, final_sweeps=0))
    a = step(state, loose, EMPTY, pins, 1 / 60, n_substeps=6)
    b = step_reference(state, loose, EMPTY, pins, 1 / 60, n_substeps=6)
    np.testing.assert_allclose(a.x, b.x, atol=1e-10)


def test_stable_substep_and_planning() -> None:
    g = make_cape(default_body(), 600)
    model = build_model(g)
    assert 2e-4 < model.stable_dt < 0.02
    from cloth_client.solver.cloth import plan_substeps

    still = CapsuleTrack.static(np.zeros((1, 3)), np.ones((1, 3)), np.full((1, 2), 0.05))
    n = plan_substeps(model, still, 1 / 60)
    assert n * min(model.stable_dt, model.params.max_substep_dt) >= 1 / 60 - 1e-12
    a = np.zeros((2, 1, 3))
    b = np.ones((2, 1, 3))
    b[1, 0, 0] += 0.5  # one end travels 0.5 m = 10 radii within the step
    fast = CapsuleTrack(a, b, np.full((1, 2), 0.05))
    assert plan_substeps(model, fast, 1 / 60) >= 20
    # with the cloth's state, only capsules that can reach the cloth within the step count
    state = initial_state(model)
    centre = g.rest.mean(axis=0)
    lo, hi = g.rest.min(axis=0), g.rest.max(axis=0)
    for offset, refined in ((np.zeros(3), True), (np.array([0.0, hi[1] - lo[1] + 0.3, 0.0]), False)):
        a_k = np.stack([centre + offset, centre + offset + [0.2, 0.0, 0.0]])[:, None]
        track = CapsuleTrack(a_k, a_k + np.array([0.0, 0.1, 0.0]), np.full((1, 2), 0.05))
        assert (plan_substeps(model, track, 1 / 60, state) >= 8) == refined
        assert plan_substeps(model, track, 1 / 60) >= 8  # without the state: every capsule counts
    state.v[0] = [0.0, 40.0, 0.0]  # a particle fast enough to reach the far capsule: it counts again
    assert plan_substeps(model, track, 1 / 60, state) >= 8


def test_bad_inputs_are_rejected() -> None:
    g = make_sheet(3, 3)
    model = build_model(g)
    state = initial_state(model)
    for stepper in (step, step_reference):
        with pytest.raises(ValueError, match="dt"):
            stepper(state, model, EMPTY, _pins(g), 0.0)
        with pytest.raises(ValueError, match="pin_keys"):
            stepper(state, model, EMPTY, _pins(g)[:, :1], 0.01)
    with pytest.raises(ValueError, match="extra_above"):  # extra rounds would run on every substep
        build_model(g, ClothParams(extra_above=0.01))
    with pytest.raises(ValueError, match="extra_rounds"):
        build_model(g, ClothParams(extra_rounds=-1))


def test_strain_kernel_matches_numpy(model, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    """The numba strain of the structural springs equals the numpy reference on a crumpled cloth."""
    x = model.garment.rest + rng.normal(0.0, 0.01, model.garment.rest.shape)
    g = model.garment
    got, ref = structural_strain(model, x), spring_strain_reference(x, g.structural, g.structural_rest)
    np.testing.assert_allclose(got, ref, atol=1e-12, rtol=0)
    assert ref.min() < 0.0 < ref.max()
    out = np.empty(len(model.springs))  # the kernel on every spring family at once
    F.spring_strain(x, model.springs, model.rest, out)
    np.testing.assert_allclose(out, spring_strain_reference(x, model.springs, model.rest), atol=1e-12, rtol=0)
