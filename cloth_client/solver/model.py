"""The cloth's parameters, its compiled model and its state (SI units throughout).

:class:`ClothParams` holds the physical and numerical parameters, :func:`build_model` compiles a
:class:`~cloth_client.solver.grid.Garment` with them into the flat arrays of a :class:`ClothModel`
(the kernels' inputs, and the largest stable substep), :class:`ClothState` is what
:func:`cloth_client.solver.cloth.step` advances, and :func:`tethers_held` moves the long-range
attachments to the pins still held while others are released.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.sparse.linalg import ArpackNoConvergence, eigsh

from cloth_client.solver.grid import Garment

__all__ = ["ClothModel", "ClothParams", "ClothState", "build_model", "initial_state", "tethers_held"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


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
        that limb (:func:`cloth_client.contact.response_kernels.release_straddles`, with the side test
        below: the 252 recordings' sweep gains 2 takes per garment, docs/CLOTH.md).
    straddle_opposed : float
        A straddle needs the limb's outward normals at the spring's two ends to point apart,
        ``n_i . n_j < straddle_opposed`` (-0.5: more than 120 degrees): a limb between the two
        particles, not cloth draped round it (> 1 turns the side test off).
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
        the ring solves (:func:`cloth_client.solver.strain_kernels.ring_limit`, each ring cut at its slackest
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
    if g.wrap:  # the rows again, as closed rings (strain_kernels.ring_limit)
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
