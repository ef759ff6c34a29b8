"""Mass-spring cloth solver: a pure step function over particle positions and velocities.

One call of :func:`step` advances the cloth by ``dt`` (one received frame) in ``n`` substeps, each

1. forces: gravity, Hooke springs with axial damping (structural, shear, bending), quadratic air
   drag on the particle's normal velocity (``0.5 rho_air C_d A v_n |v_n|``);
2. semi-implicit (symplectic) Euler, with mass-proportional damping ``v /= 1 + c dt``;
3. pinned particles placed on their targets (interpolated between the step's keys);
4. strain limiting (numpy references in :mod:`cloth_client.solver.reference`): long-range attachments, line solves and a
   Gauss-Seidel sweep, then collision with the body capsules and the floor
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

The numba kernels in :mod:`cloth_client.solver._kernels` run the substeps; ``backend="numpy"`` runs the
plain numpy references (:mod:`cloth_client.solver.reference`), which tests compare against the kernels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.sparse.linalg import ArpackNoConvergence, eigsh

from cloth_client.contact.collision import CapsuleTrack, capsules_near, check_backend, max_relative_travel
from cloth_client.solver import _kernels as K
from cloth_client.solver.garment import Garment
from cloth_client.solver.reference import substeps_np

__all__ = [
    "ClothModel",
    "ClothParams",
    "ClothState",
    "build_model",
    "energy",
    "initial_state",
    "plan_substeps",
    "step",
    "structural_strain",
    "tethers_held",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
#: Distance (m) beyond the cloth's reach within a step at which a capsule still counts as near it.
NEAR_ALLOWANCE = 0.05


@dataclass(frozen=True)
class ClothParams:
    """Physical and numerical parameters (SI units).

    Attributes
    ----------
    stretch_stiffness, shear_stiffness, bend_stiffness : float
        Spring constants per spring, N/m. Deliberately soft (explicit stability at real-time
        substeps); strain limiting, not the springs, keeps the cloth from stretching.
    damping_ratio : float
        Axial damping of each spring as a fraction of its critical damping.
    mass_damping : float
        Global velocity damping, 1/s.
    air_density, drag_coefficient : float
        kg/m^3 and the dimensionless normal drag coefficient of a flat sheet.
    gravity, wind : tuple of float
        m/s^2 and m/s, world frame (Y up).
    max_stretch, max_compression : float
        Strain limits of the structural springs (0.05 = 5 %).
    limit_iterations : int
        Rounds of *[long-range attachments, line solves, Gauss-Seidel sweep, collision]* per substep.
    limit_sweeps : int
        Line-solve sweeps in each of those rounds.
    final_sweeps : int
        Line-solve sweeps in each final round.
    final_rounds : int
        Final rounds of *[contact-aware line solves, Gauss-Seidel sweep, collision]*; 0 = one
        contact-aware strain pass without collision after it (the previous scheme).
    extra_rounds : int
        Up to this many more final rounds in a substep while any structural spring with a free end
        is stretched beyond ``extra_above`` after the last one (a solver that has not converged, e.g. after a
        jerk); none when ``final_rounds`` is 0. With ``release_straddles`` each starts by lifting
        stretched springs that straddle a body part off it.
    extra_above : float
        Strain that triggers the extra rounds (0.08 = 8 %, under the 10 % quality target).
    release_straddles : bool
        The extra rounds first lift stretched springs with a limb between their two particles off
        that limb (``_contact_kernels.release_straddles``; session 17, on since session 18 with the
        side test below: the 252 recordings' sweep gains 2 takes per garment, docs/CLOTH.md).
    straddle_opposed : float
        A straddle needs the limb's outward normals at the spring's two ends to point apart,
        ``n_i . n_j < straddle_opposed`` (-0.5: more than 120 degrees): a limb between the two
        particles, not cloth draped round it (session 18; > 1 turns the side test off).
    tethers : bool
        Long-range attachments on.
    friction : float
        Coulomb coefficient between cloth and body / floor.
    margin : float
        Cloth half thickness kept from the body, metres.
    floor : float or None
        Floor height (None: no floor).
    max_substep_dt : float
        Upper bound on the substep, seconds.
    max_travel : float
        Largest capsule motion per substep, in capsule radii.
    max_substeps : int
        Cap on substeps per step.
    max_speed : float
        Particle speed clamp, m/s.
    stability_safety : float
        Fraction of the explicit stability limit used.
    """

    stretch_stiffness: float = 2.0
    shear_stiffness: float = 0.5
    bend_stiffness: float = 0.25
    damping_ratio: float = 0.1
    mass_damping: float = 0.3
    air_density: float = 1.2
    drag_coefficient: float = 1.0
    gravity: tuple[float, float, float] = (0.0, -9.81, 0.0)
    wind: tuple[float, float, float] = (0.0, 0.0, 0.0)
    max_stretch: float = 0.03
    max_compression: float = 0.10
    limit_iterations: int = 1
    limit_sweeps: int = 1
    final_sweeps: int = 2
    final_rounds: int = 2
    extra_rounds: int = 32
    extra_above: float = 0.08
    release_straddles: bool = True
    straddle_opposed: float = -0.5
    tethers: bool = True
    friction: float = 0.2
    margin: float = 0.006
    floor: float | None = 0.0
    max_substep_dt: float = 1.0 / 240.0
    max_travel: float = 0.5
    max_substeps: int = 48
    max_speed: float = 30.0
    stability_safety: float = 0.9


@dataclass(frozen=True)
class ClothModel:
    """A garment compiled with its parameters into the flat arrays the kernels use.

    Attributes
    ----------
    garment : Garment
    params : ClothParams
    springs : (S, 2) int64
        Structural, shear and bending springs concatenated.
    rest, k, kd : (S,) float64
        Rest length (m), stiffness (N/m) and axial damping (N s/m) per spring.
    inv_mass : (N,) float64
        0 for pinned particles.
    reach : (N,) float64
        Long-range attachment radius of every particle around ``garment.anchor``, metres.
    lines_v, lines_h : (cols, rows) and (rows, cols) int64
        Particles of every grid column and row, in order (for the line solves); a wrapping
        garment's rows are solved both as these open lines (cut at the seam) and as rings
        (``lines_s``).
    rest_v, rest_h : (cols, rows - 1) and (rows, cols - 1) float64
        Rest lengths between neighbours along those lines, metres.
    lines_s, rest_s : (rows, cols) int64, (rows, cols) float64
        For a garment wrapping round, the rows as closed rings (column 0, the front centre, follows
        the last column) and the rest length from each particle to the next round the ring, for
        the ring solves (:func:`cloth_client.solver._kernels.ring_limit`, each ring cut at its slackest
        spring); empty ``(0, 2)`` otherwise.
    lim_springs : (L, 2) int64
    lim_lo, lim_hi : (L,) float64
        Structural springs in strain-limiting order (``garment.limit_springs``) and their length
        bounds (m).
    stable_dt : float
        Largest stable substep, seconds.
    """

    garment: Garment
    params: ClothParams
    springs: I64
    rest: F64
    k: F64
    kd: F64
    inv_mass: F64
    reach: F64
    lines_v: I64
    rest_v: F64
    lines_h: I64
    rest_h: F64
    lines_s: I64
    rest_s: F64
    lim_springs: I64
    lim_lo: F64
    lim_hi: F64
    stable_dt: float


@dataclass
class ClothState:
    """Positions ``x (N, 3)`` and velocities ``v (N, 3)`` (float64, m and m/s) at time ``t`` (s);
    ``substeps`` counts the substeps taken so far."""

    x: F64
    v: F64
    t: float = 0.0
    substeps: int = field(default=0)

    def copy(self) -> ClothState:
        return ClothState(self.x.copy(), self.v.copy(), self.t, self.substeps)


def build_model(garment: Garment, params: ClothParams | None = None) -> ClothModel:
    """Compile ``garment`` and ``params`` into a :class:`ClothModel` (also computes the stable substep)."""
    p = params or ClothParams()
    if p.extra_rounds < 0 or not p.extra_above >= p.max_stretch:
        raise ValueError(f"extra_rounds must be >= 0 and extra_above >= max_stretch ({p.max_stretch}), got "
                         f"{p.extra_rounds} and {p.extra_above}")
    g = garment
    springs = np.concatenate([g.structural, g.shear, g.bend])
    rest = np.concatenate([g.structural_rest, g.shear_rest, g.bend_rest])
    k = np.concatenate([np.full(len(g.structural), p.stretch_stiffness), np.full(len(g.shear), p.shear_stiffness),
                        np.full(len(g.bend), p.bend_stiffness)])
    mi, mj = g.mass[springs[:, 0]], g.mass[springs[:, 1]]
    kd = p.damping_ratio * 2.0 * np.sqrt(k * mi * mj / (mi + mj))
    inv_mass = 1.0 / g.mass
    inv_mass[g.pin_index] = 0.0
    rl = g.limit_rest
    z = p.damping_ratio
    omega = math.sqrt(_max_eigenvalue(g.rest, springs, k, inv_mass) * (1.0 + p.max_stretch))
    stable = p.stability_safety * 2.0 / omega * (math.sqrt(1.0 + z * z) - z)
    reach = g.anchor_dist * (1.0 + p.max_stretch) if p.tethers else np.full(g.n_particles, np.inf)
    idx = np.arange(g.n_particles, dtype=np.int64).reshape(g.grid_shape)
    lines_v, lines_h = np.ascontiguousarray(idx.T), idx
    lines_s, rest_s = np.zeros((0, 2), np.int64), np.zeros((0, 2))
    if g.wrap:  # the rows again, as closed rings (K.ring_limit)
        lines_s = idx
        rest_s = np.linalg.norm(g.rest[np.roll(idx, -1, axis=1)] - g.rest[idx], axis=-1)

    def line_rest(lines: I64) -> F64:
        out: F64 = np.linalg.norm(g.rest[lines[:, 1:]] - g.rest[lines[:, :-1]], axis=-1)
        return out

    return ClothModel(g, p, np.ascontiguousarray(springs), rest, k, kd, inv_mass, reach, lines_v, line_rest(lines_v),
                      lines_h, line_rest(lines_h), lines_s, rest_s, np.ascontiguousarray(g.limit_springs),
                      rl * (1.0 - p.max_compression), rl * (1.0 + p.max_stretch), stable)


def _max_eigenvalue(x: F64, springs: I64, k: F64, inv_mass: F64) -> float:
    """Largest eigenvalue of ``M^-1/2 K M^-1/2`` over the free particles at configuration ``x``
    (``K`` the springs' stiffness matrix; its square root is the highest angular frequency, 1/s).
    Falls back to the Gershgorin bound if ARPACK does not converge. The start vector is fixed, so the
    same model always gets the same substep count (a run is reproducible)."""
    n = len(x)
    d = x[springs[:, 1]] - x[springs[:, 0]]
    u = d / np.maximum(np.linalg.norm(d, axis=1), 1e-12)[:, None]
    blocks = (k[:, None, None] * u[:, :, None] * u[:, None, :]).reshape(-1, 9)
    comp_r, comp_c = np.divmod(np.arange(9), 3)
    rows, cols, vals = [], [], []
    for ii, jj, sign in ((0, 0, 1.0), (1, 1, 1.0), (0, 1, -1.0), (1, 0, -1.0)):
        rows.append((3 * springs[:, ii, None] + comp_r).ravel())
        cols.append((3 * springs[:, jj, None] + comp_c).ravel())
        vals.append(sign * blocks.ravel())
    w = np.repeat(np.sqrt(inv_mass), 3)
    stiff = coo_matrix((np.concatenate(vals) * w[np.concatenate(rows)] * w[np.concatenate(cols)],
                        (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, 3 * n)).tocsr()
    start = np.random.default_rng(0).standard_normal(3 * n)  # fixed: ARPACK's random start made runs differ
    try:
        return float(eigsh(stiff, k=1, which="LA", return_eigenvectors=False, tol=1e-4, v0=start)[0])
    except ArpackNoConvergence:
        return float(np.abs(stiff).sum(axis=1).max())


def tethers_held(model: ClothModel, released: NDArray[np.bool_]) -> tuple[I64, F64]:
    """Long-range attachments to the pins that are still held while ``released (P,)`` are let go.

    A released pin is a free particle, so the attachments of the cloth below it (and its own) would
    vanish and a released stretch of a waistband would sag under the garment's weight, stretched
    far beyond the strain limit. Instead every particle is attached to its nearest *held* pin along
    the cloth (shortest path over structural and shear springs at rest, as in :func:`build_model`).

    Returns
    -------
    anchor : (N,) int64
        Nearest held pin of every particle (itself when no pin is held: no attachment).
    reach : (N,) float64
        Rest distance to it times ``1 + max_stretch``, metres (``inf`` when no pin is held).
    """
    g, p = model.garment, model.params
    held = g.pin_index[~np.asarray(released, dtype=bool)]
    n = g.n_particles
    if not p.tethers or len(held) == 0:
        return np.arange(n, dtype=np.int64), np.full(n, np.inf)
    edges = np.concatenate([g.structural, g.shear])
    lengths = np.concatenate([g.structural_rest, g.shear_rest])
    graph = coo_matrix((lengths, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    dist, _, source = dijkstra(graph, directed=False, indices=held, min_only=True, return_predecessors=True)
    reach: F64 = dist * (1.0 + p.max_stretch)
    return source.astype(np.int64), reach


def initial_state(model: ClothModel, x: F64 | None = None, t: float = 0.0) -> ClothState:
    """Cloth at rest at ``x`` (default: the garment's rest shape)."""
    pos = np.array(model.garment.rest if x is None else x, dtype=np.float64)
    return ClothState(pos, np.zeros_like(pos), t)


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
         tethers: tuple[I64, F64] | None = None, backend: str = "numba") -> ClothState:
    """Advance the cloth by ``dt`` seconds.

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
    backend : {"numba", "numpy"}

    Returns
    -------
    ClothState
        The new state at ``state.t + dt``.
    """
    if not dt > 0:
        raise ValueError(f"dt must be positive, got {dt}")
    n = n_substeps if n_substeps is not None else plan_substeps(model, track, dt, state)
    x, v = state.x.copy(), state.v.copy()
    p = model.params
    pins = np.ascontiguousarray(pin_keys, dtype=np.float64)
    if pins.ndim != 3 or pins.shape[1:] != (len(model.garment.pin_index), 3) or pins.shape[0] < 2:
        raise ValueError(f"pin_keys must be (K+1 >= 2, {len(model.garment.pin_index)}, 3), got {pins.shape}")
    inv_mass, pin_idx = model.inv_mass, model.garment.pin_index
    anchor, reach = tethers if tethers is not None else (model.garment.anchor, model.reach)
    if released is not None and released.any():
        inv_mass = inv_mass.copy()
        inv_mass[pin_idx[released]] = 1.0 / model.garment.mass[pin_idx[released]]
        pin_idx, pins = pin_idx[~released], np.ascontiguousarray(pins[:, ~released])
    if backend == "numba":
        K.simulate_substeps(
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
    elif backend == "numpy":
        substeps_np(x, v, model, inv_mass, pin_idx, track, pins, n, dt, p.mass_damping + extra_damping, anchor, reach)
    else:
        raise ValueError(f"unknown backend {backend!r}")
    return ClothState(x, v, state.t + dt, state.substeps + n)


# --- diagnostics ---------------------------------------------------------------------------------------

def structural_strain(model: ClothModel, x: F64, backend: str = "numba") -> F64:
    """Engineering strain ``(l - L) / L`` of every structural spring, ``(S_structural,)``
    (``backend="numpy"``: the plain reference of the kernel)."""
    g = model.garment
    check_backend(backend)
    if backend == "numba":
        res = np.empty(len(g.structural))
        K.spring_strain(np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(g.structural, dtype=np.int64),
                        np.ascontiguousarray(g.structural_rest, dtype=np.float64), res)
        return res
    out: F64 = np.linalg.norm(x[g.structural[:, 1]] - x[g.structural[:, 0]], axis=1) / g.structural_rest - 1.0
    return out


def energy(model: ClothModel, state: ClothState) -> dict[str, float]:
    """Kinetic, gravitational (relative to y = 0) and elastic energy of the cloth, joules."""
    m = model.garment.mass
    kinetic = 0.5 * float(np.sum(m * np.einsum("ij,ij->i", state.v, state.v)))
    potential = -float(np.sum(m * (state.x @ np.asarray(model.params.gravity))))
    d = np.linalg.norm(state.x[model.springs[:, 1]] - state.x[model.springs[:, 0]], axis=1) - model.rest
    elastic = 0.5 * float(np.sum(model.k * d * d))
    return {"kinetic": kinetic, "potential": potential, "elastic": elastic,
            "total": kinetic + potential + elastic}
