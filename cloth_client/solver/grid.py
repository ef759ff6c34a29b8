"""A garment's particle grid: topology, masses, pins, long-range attachments and strain-limiting order.

:func:`build_garment` assembles a :class:`Garment` from grid positions placed round a body (the
parametric shapes of :mod:`cloth_client.solver.garment` do the placing). The grid gives

* three spring families with rest lengths taken from that placement: *structural* (grid edges),
  *shear* (both quad diagonals) and *bending* (every second particle along rows and columns);
* triangles for rendering, air drag and per-particle mass (density x 1/3 of the adjacent area);
* pins: top-row particles, each attached to a joint with a fixed offset in that joint's frame,
  optionally anchored on a bone axis and rolling with a line of joints;
* long-range attachments: every particle's nearest pin and its rest distance along the cloth
  (shortest path over structural and shear springs), which bound how far the cloth can sag;
* the order in which strain limiting visits the structural springs: by graph distance from the
  pins (so one sweep carries a pull from the pins down to the hem), split into batches of springs
  that share no particle (so a vectorised batch update equals the sequential Gauss-Seidel sweep).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from protocol.kinematics import fk_global
from protocol.skeleton import JOINT_INDEX, Body

__all__ = ["Garment", "build_garment", "grid_topology"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@dataclass(frozen=True)
class Garment:
    """A garment's particles, topology, masses and pins (all arrays read-only).

    Attributes
    ----------
    kind : str
        ``"cape"`` or ``"skirt"``.
    rest : (N, 3) float64
        Particle positions in the build pose (``pose``), metres.
    triangles : (T, 3) int64
    structural, shear, bend : (S_k, 2) int64
        Spring endpoints of each family.
    structural_rest, shear_rest, bend_rest : (S_k,) float64
        Rest lengths, metres.
    mass : (N,) float64
        Particle masses, kg.
    pin_index : (P,) int64
        Pinned particles.
    pin_joint : (P,) int64
        Joint each pin is attached to (its frame carries ``pin_local``).
    pin_local : (P, 3) float64
        Pin position in its joint's frame, relative to the pin's anchor point, metres.
    pin_axis : (P, 2) int64
        Joints ``a, b`` of the bone axis each pin is anchored on.
    pin_axis_s : (P,) float64
        Position of the anchor along that axis: the pin's target is
        ``(1 - s) J_a + s J_b + R_joint pin_local``. A plain joint pin has ``a = b = pin_joint``,
        ``s = 0``; the skirt's waistband rides the abdomen's axis (pelvis to chest joint), so it
        stays round the trunk when the spine bends.
    pin_axis_local : (P, 3) float64 or None
        Unit direction of that axis in the pin joint's frame in the build pose, for pins whose
        frame is swung to stay square to the axis (the skirt's waistband: the spine joint's frame
        tilts differently from the pelvis-to-chest line when the back bends); None for plain joint pins.
    limit_springs : (S_structural, 2) int64
        The structural springs in strain-limiting order (from the pins outwards).
    limit_rest : (S_structural,) float64
        Their rest lengths, metres.
    limit_batches : (B + 1,) int64
        Offsets into ``limit_springs``; the springs of one batch share no particle.
    anchor : (N,) int64
        Nearest pinned particle of every particle along the cloth (itself for a pin).
    anchor_dist : (N,) float64
        Rest distance along the cloth to that pin (long-range attachments), metres.
    grid_shape : tuple[int, int]
        ``(rows, cols)``; particle ``(r, c)`` has index ``r * cols + c``.
    wrap : bool
        Columns wrap around (a tube).
    seam : {"slide", "release"}
        What happens to pins a body part moves into: ``"slide"`` moves their targets out onto that
        surface (the cape's collar under a shrugging shoulder: a large, smooth capsule), ``"release"``
        lets them and their neighbours go for that step (the skirt's waistband under a thigh or a
        hand, which would otherwise throw a projected pin to the far side of a thin limb).
    pose : (P_pose,) float64
        The body pose the rest shape was built in.
    pin_roll : (2,) int64 or None
        Joints of the line an axis-anchored ring of pins rolls with (the skirt's waistband: the hip
        joints; :meth:`~cloth_client.avatar.capsules.AvatarKeys.pin_targets`), None for none.
    """

    kind: str
    rest: F64
    triangles: I64
    structural: I64
    structural_rest: F64
    shear: I64
    shear_rest: F64
    bend: I64
    bend_rest: F64
    mass: F64
    pin_index: I64
    pin_joint: I64
    pin_local: F64
    pin_axis: I64
    pin_axis_s: F64
    pin_axis_local: F64 | None
    limit_springs: I64
    limit_rest: F64
    limit_batches: I64
    anchor: I64
    anchor_dist: F64
    grid_shape: tuple[int, int]
    wrap: bool
    pose: F64
    seam: str = "slide"
    pin_roll: I64 | None = None

    def __post_init__(self) -> None:
        for value in self.__dict__.values():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)

    @property
    def n_particles(self) -> int:
        return int(self.rest.shape[0])

    @property
    def total_mass(self) -> float:
        return float(self.mass.sum())


def grid_topology(rows: int, cols: int, wrap: bool) -> tuple[I64, I64, I64, I64]:
    """Springs and triangles of a ``rows x cols`` particle grid.

    Parameters
    ----------
    rows, cols : int
        At least 3 each.
    wrap : bool
        Connect column ``cols - 1`` to column 0 (a tube).

    Returns
    -------
    structural, shear, bend : (S_k, 2) int64
    triangles : (T, 3) int64
    """
    if rows < 3 or cols < 3:
        raise ValueError(f"a garment grid needs at least 3 x 3 particles, got {rows} x {cols}")
    idx = np.arange(rows * cols, dtype=np.int64).reshape(rows, cols)
    right = np.roll(idx, -1, axis=1) if wrap else idx[:, 1:]
    left = idx if wrap else idx[:, :-1]
    horiz = np.stack([left.ravel(), right.ravel()], axis=1)
    vert = np.stack([idx[:-1].ravel(), idx[1:].ravel()], axis=1)
    q00, q01 = left[:-1].ravel(), right[:-1].ravel()
    q10, q11 = left[1:].ravel(), right[1:].ravel()
    shear = np.concatenate([np.stack([q00, q11], 1), np.stack([q01, q10], 1)])
    right2 = np.roll(idx, -2, axis=1) if wrap else idx[:, 2:]
    left2 = idx if wrap else idx[:, :-2]
    bend = np.concatenate([np.stack([left2.ravel(), right2.ravel()], 1),
                           np.stack([idx[:-2].ravel(), idx[2:].ravel()], 1)])
    tris = np.concatenate([np.stack([q00, q10, q11], 1), np.stack([q00, q11, q01], 1)])
    return np.concatenate([horiz, vert]), shear, bend, tris


def _limit_batches(n: int, springs: I64, pins: I64) -> tuple[I64, I64]:
    """Order springs by hop distance from the pins and split them into particle-disjoint batches.

    Returns the order (indices into ``springs``) and the batch offsets."""
    graph = coo_matrix((np.ones(len(springs)), (springs[:, 0], springs[:, 1])), shape=(n, n))
    level = dijkstra(graph, directed=False, indices=pins, unweighted=True, min_only=True)
    level = np.where(np.isfinite(level), level, level[np.isfinite(level)].max() + 1).astype(np.int64)
    li, lj = level[springs[:, 0]], level[springs[:, 1]]
    key = 2 * np.minimum(li, lj) + (li == lj)  # pulls away from the pins first, then lateral ones
    order = np.argsort(key, kind="stable")
    batches: list[list[int]] = []
    batch_key: list[int] = []
    used: list[set[int]] = []
    group_start = 0
    for s in order.tolist():  # build-time greedy colouring (not per step)
        i, j = int(springs[s, 0]), int(springs[s, 1])
        if batch_key and key[s] != batch_key[-1]:
            group_start = len(batches)
        for b in range(group_start, len(batches) + 1):
            if b == len(batches):
                batches.append([])
                batch_key.append(int(key[s]))
                used.append(set())
            if i not in used[b] and j not in used[b]:
                batches[b].append(s)
                used[b].update((i, j))
                break
    flat = np.array([s for b in batches for s in b], dtype=np.int64)
    ptr = np.concatenate([[0], np.cumsum([len(b) for b in batches])]).astype(np.int64)
    return flat, ptr


def build_garment(kind: str, pos: F64, wrap: bool, body: Body, pose: F64, joint: str | NDArray[np.int64],
                  density: float, pin_cols: NDArray[np.bool_] | None = None, seam: str = "slide",
                  axis: tuple[str, str, float] | None = None, roll: tuple[str, str] | None = None) -> Garment:
    """Assemble a :class:`Garment` from grid positions ``pos (rows, cols, 3)``; the top row's
    particles in ``pin_cols`` (default: all) are pinned to ``joint`` (a name, or one joint index per
    top-row particle), anchored at that joint or, with ``axis = (joint_a, joint_b, s)``, at the point
    ``s`` of the way from ``joint_a`` to ``joint_b``, rolling with the line from joint ``roll[0]`` to
    ``roll[1]`` if given (with ``axis`` only)."""
    if roll is not None and axis is None:
        raise ValueError("a ring rolls with a line only when anchored on an axis")
    rows, cols = pos.shape[:2]
    x = pos.reshape(-1, 3)
    structural, shear, bend, tris = grid_topology(rows, cols, wrap)
    area = 0.5 * np.linalg.norm(np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]]), axis=1)
    mass = np.asarray(np.bincount(tris.ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(x)) * density,
                      dtype=np.float64)
    pins = np.arange(cols, dtype=np.int64) if pin_cols is None else np.flatnonzero(pin_cols).astype(np.int64)
    joints, rot = fk_global(pose, body)
    pin_joint = (np.full(len(pins), JOINT_INDEX[joint], dtype=np.int64) if isinstance(joint, str)
                 else np.asarray(joint, dtype=np.int64)[pins])
    if axis is None:
        pin_axis, pin_s = np.stack([pin_joint, pin_joint], axis=1), np.zeros(len(pins))
    else:
        pin_axis = np.tile(np.array([JOINT_INDEX[axis[0]], JOINT_INDEX[axis[1]]], dtype=np.int64), (len(pins), 1))
        pin_s = np.full(len(pins), float(axis[2]))
    origin = (1.0 - pin_s[:, None]) * joints[pin_axis[:, 0]] + pin_s[:, None] * joints[pin_axis[:, 1]]
    local = np.einsum("pji,pj->pi", rot[pin_joint], x[pins] - origin)  # R^T (x - anchor)
    axis_local = None
    if axis is not None:
        u = joints[pin_axis[:, 1]] - joints[pin_axis[:, 0]]
        axis_local = np.einsum("pji,pj->pi", rot[pin_joint], u / np.linalg.norm(u, axis=1, keepdims=True))
    order, ptr = _limit_batches(len(x), structural, pins)
    lim = structural[order]
    edges = np.concatenate([structural, shear])
    lengths = np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1)
    graph = coo_matrix((lengths, (edges[:, 0], edges[:, 1])), shape=(len(x), len(x))).tocsr()
    dist, _, source = dijkstra(graph, directed=False, indices=pins, min_only=True, return_predecessors=True)

    def rest(s: I64) -> F64:
        out: F64 = np.linalg.norm(x[s[:, 1]] - x[s[:, 0]], axis=1)
        return out

    return Garment(
        kind=kind, rest=x.copy(), triangles=tris, structural=structural, structural_rest=rest(structural),
        shear=shear, shear_rest=rest(shear), bend=bend, bend_rest=rest(bend), mass=mass,
        pin_index=pins, pin_joint=pin_joint, pin_local=local, pin_axis=pin_axis, pin_axis_s=pin_s,
        pin_axis_local=axis_local,
        limit_springs=lim, limit_rest=rest(lim), limit_batches=ptr, anchor=source.astype(np.int64), anchor_dist=dist,
        grid_shape=(rows, cols), wrap=wrap, pose=pose.copy(), seam=seam,
        pin_roll=None if roll is None else np.array([JOINT_INDEX[roll[0]], JOINT_INDEX[roll[1]]], dtype=np.int64),
    )
