"""Mass-spring cloth solver: a pure step function over particle positions and velocities.

One call of :func:`step` advances the cloth by ``dt`` (one received frame) in ``n`` substeps, each

1. forces: gravity, Hooke springs with axial damping (structural, shear, bending), quadratic air
   drag on the particle's normal velocity (``0.5 rho_air C_d A v_n |v_n|``);
2. semi-implicit (symplectic) Euler, with mass-proportional damping ``v /= 1 + c dt``;
3. pinned particles placed on their targets (interpolated between the step's keys);
4. strain limiting (:mod:`cloth_client.solver.reference` describes it): long-range attachments, line
   solves and a Gauss-Seidel sweep, then collision with the body capsules and the floor
   (:mod:`cloth_client.contact.collision`), ``limit_iterations`` times; then ``final_rounds`` rounds of
   *[line solves, Gauss-Seidel sweep, collision]* (Provot's order: the strain limit, then the
   body, has the last word), and up to ``extra_rounds`` more while a structural spring is still
   stretched beyond ``extra_above`` (with ``release_straddles``, each first lifts a stretched
   spring with a limb between its two particles off that limb), so every substep ends outside the
   body wherever it leaves room; the
   strain passes are contact-aware throughout (a particle touching the body only slides along the
   surfaces the last collision pass found);
   velocities follow the corrected positions;
5. a speed clamp as the last guard against a blow-up.

``n`` is the smallest count that (a) keeps the explicit springs stable (largest eigenvalue of the
mass-normalised stiffness matrix, with a margin for stretched springs, reduced for the spring
damping), (b) respects ``max_substep_dt``, and (c) lets no capsule move more than ``max_travel``
of its radius per substep (continuous collision), capped at ``max_substeps``.

The numba kernel :func:`cloth_client.solver.substep_kernels.simulate_substeps` runs the substeps of
:func:`step`; :func:`step_reference` runs its plain numpy reference
(:func:`cloth_client.solver.reference.simulate_substeps_reference`) instead, which tests compare with
the kernel. The parameters, the compiled model and the state are defined in
:mod:`cloth_client.solver.model` (and importable from here).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from cloth_client.contact.collision import CapsuleTrack, capsules_near, max_relative_travel
from cloth_client.solver.force_kernels import spring_strain
from cloth_client.solver.model import ClothModel, ClothParams, ClothState, build_model, initial_state, tethers_held
from cloth_client.solver.reference import simulate_substeps_reference
from cloth_client.solver.substep_kernels import simulate_substeps

__all__ = [
    "ClothModel",
    "ClothParams",
    "ClothState",
    "build_model",
    "energy",
    "initial_state",
    "plan_substeps",
    "step",
    "step_reference",
    "structural_strain",
    "tethers_held",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
#: Distance (m) beyond the cloth's reach within a step at which a capsule still counts as near it.
NEAR_ALLOWANCE = 0.05


def plan_substeps(model: ClothModel, track: CapsuleTrack, dt: float, state: ClothState | None = None) -> int:
    """Number of substeps for a step of ``dt`` seconds with body motion ``track`` (see module doc).

    With ``state``, only capsules that can reach the cloth within the step count for the travel
    limit (:func:`~cloth_client.contact.collision.capsules_near`, with the cloth's fastest particle, a 5 cm
    allowance and the margin): a hand flung overhead does not refine a skirt's substeps."""
    p = model.params
    limit_dt = min(p.max_substep_dt, model.stable_dt)
    near = None
    if state is not None and track.n_keys > 0:
        speed = float(np.sqrt(np.einsum("ij,ij->i", state.v, state.v).max())) if len(state.v) else 0.0
        near = capsules_near(track, state.x, speed * dt + NEAR_ALLOWANCE + p.margin)
    n = max(1, math.ceil(dt / limit_dt - 1e-9), math.ceil(max_relative_travel(track, near) / p.max_travel - 1e-9))
    return int(min(n, max(p.max_substeps, math.ceil(dt / model.stable_dt - 1e-9))))


def step(state: ClothState, model: ClothModel, track: CapsuleTrack, pin_keys: F64, dt: float, *,
         released: NDArray[np.bool_] | None = None, n_substeps: int | None = None, extra_damping: float = 0.0,
         tethers: tuple[I64, F64] | None = None) -> ClothState:
    """Advance the cloth by ``dt`` seconds (:func:`step_reference` takes the same step in plain numpy).

    Parameters
    ----------
    state : ClothState
        Not modified.
    model : ClothModel
    track : CapsuleTrack
        Body capsules at ``K + 1`` evenly spaced instants of the step.
    pin_keys : (K' + 1, P, 3) float64
        Pin targets at evenly spaced instants of the step (``K'`` may differ from ``K``).
    dt : float
        Step length, seconds (> 0).
    released : (P,) bool, optional
        Pins let go for this step (they move freely, e.g. while a body part covers their target).
    n_substeps : int, optional
        Force the substep count (default: :func:`plan_substeps`).
    extra_damping : float
        Added to ``params.mass_damping`` for this step, 1/s (used to calm the cloth after a reset).
    tethers : (anchor (N,) int64, reach (N,) float64), optional
        Long-range attachments to use instead of the model's (:func:`tethers_held` for released pins).

    Returns
    -------
    ClothState
        The new state at ``state.t + dt``.
    """
    x, v, n, inv_mass, pin_idx, pins, anchor, reach = _step_inputs(state, model, track, pin_keys, dt, released,
                                                                   n_substeps, tethers)
    p = model.params
    simulate_substeps(
        x, v, inv_mass, model.springs, model.rest, model.k, model.kd, model.garment.triangles,
        0.5 * p.air_density * p.drag_coefficient, np.asarray(p.wind, dtype=np.float64),
        np.asarray(p.gravity, dtype=np.float64), p.mass_damping + extra_damping,
        model.lim_springs, model.lim_lo, model.lim_hi, p.limit_iterations, p.limit_sweeps, p.final_sweeps,
        p.final_rounds, p.extra_rounds if p.final_rounds > 0 else 0,
        ((1.0 + p.extra_above) / (1.0 + p.max_stretch)) ** 2, p.release_straddles, p.straddle_opposed,
        np.ascontiguousarray(anchor, dtype=np.int64), np.ascontiguousarray(reach, dtype=np.float64),
        model.lines_v, model.rest_v, model.lines_h, model.rest_h, model.lines_s, model.rest_s,
        p.max_stretch, p.max_compression,
        pin_idx, pins, track.a, track.b,
        track.radii,
        p.margin, p.friction, 0.0 if p.floor is None else p.floor, p.floor is not None, p.max_speed, n, dt)
    return ClothState(x, v, state.t + dt, state.substeps + n)


def step_reference(state: ClothState, model: ClothModel, track: CapsuleTrack, pin_keys: F64, dt: float, *,
                   released: NDArray[np.bool_] | None = None, n_substeps: int | None = None,
                   extra_damping: float = 0.0, tethers: tuple[I64, F64] | None = None) -> ClothState:
    """:func:`step` with the plain numpy reference of its substep kernel
    (:func:`cloth_client.solver.reference.simulate_substeps_reference`); same parameters and result
    (to rounding). Far too slow for real time: tests compare it with :func:`step`."""
    x, v, n, inv_mass, pin_idx, pins, anchor, reach = _step_inputs(state, model, track, pin_keys, dt, released,
                                                                   n_substeps, tethers)
    simulate_substeps_reference(x, v, model, inv_mass, pin_idx, track, pins, n, dt,
                                model.params.mass_damping + extra_damping, anchor, reach)
    return ClothState(x, v, state.t + dt, state.substeps + n)


def _step_inputs(state: ClothState, model: ClothModel, track: CapsuleTrack, pin_keys: F64, dt: float,
                 released: NDArray[np.bool_] | None, n_substeps: int | None,
                 tethers: tuple[I64, F64] | None) -> tuple[F64, F64, int, F64, I64, F64, I64, F64]:
    """The checked inputs of one step: ``(x, v, n, inv_mass, pin_idx, pins, anchor, reach)`` (copies of
    the state's positions and velocities, the substep count, and the released pins made free)."""
    if not dt > 0:
        raise ValueError(f"dt must be positive, got {dt}")
    n = n_substeps if n_substeps is not None else plan_substeps(model, track, dt, state)
    x, v = state.x.copy(), state.v.copy()
    pins = np.ascontiguousarray(pin_keys, dtype=np.float64)
    if pins.ndim != 3 or pins.shape[1:] != (len(model.garment.pin_index), 3) or pins.shape[0] < 2:
        raise ValueError(f"pin_keys must be (K+1 >= 2, {len(model.garment.pin_index)}, 3), got {pins.shape}")
    inv_mass, pin_idx = model.inv_mass, model.garment.pin_index
    anchor, reach = tethers if tethers is not None else (model.garment.anchor, model.reach)
    if released is not None and released.any():
        inv_mass = inv_mass.copy()
        inv_mass[pin_idx[released]] = 1.0 / model.garment.mass[pin_idx[released]]
        pin_idx, pins = pin_idx[~released], np.ascontiguousarray(pins[:, ~released])
    return x, v, n, inv_mass, pin_idx, pins, anchor, reach


# --- diagnostics ---------------------------------------------------------------------------------------

def structural_strain(model: ClothModel, x: F64) -> F64:
    """Engineering strain ``(l - L) / L`` of every structural spring, ``(S_structural,)`` (the kernel
    :func:`cloth_client.solver.force_kernels.spring_strain`; reference:
    :func:`cloth_client.solver.reference.spring_strain_reference`)."""
    g = model.garment
    res = np.empty(len(g.structural))
    spring_strain(np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(g.structural, dtype=np.int64),
                  np.ascontiguousarray(g.structural_rest, dtype=np.float64), res)
    return res


def energy(model: ClothModel, state: ClothState) -> dict[str, float]:
    """Kinetic, gravitational (relative to y = 0) and elastic energy of the cloth, joules."""
    m = model.garment.mass
    kinetic = 0.5 * float(np.sum(m * np.einsum("ij,ij->i", state.v, state.v)))
    potential = -float(np.sum(m * (state.x @ np.asarray(model.params.gravity))))
    d = np.linalg.norm(state.x[model.springs[:, 1]] - state.x[model.springs[:, 0]], axis=1) - model.rest
    elastic = 0.5 * float(np.sum(model.k * d * d))
    return {"kinetic": kinetic, "potential": potential, "elastic": elastic,
            "total": kinetic + potential + elastic}
