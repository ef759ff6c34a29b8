"""Parametric garments sized to a body: a cape pinned at the shoulders and a skirt pinned at the waist.

Every garment is a regular particle grid (``rows x cols``, the skirt wrapping around in columns)
placed around the body in its relaxed standing pose (:func:`protocol.skeleton.standing_pose`) so
that it clears every body capsule by a margin. The grid gives

* three spring families with rest lengths taken from that placement: *structural* (grid edges),
  *shear* (both quad diagonals) and *bending* (every second particle along rows and columns);
* triangles for rendering, air drag and per-particle mass (density x 1/3 of the adjacent area);
* pins: top-row particles, each attached to a joint with a fixed offset in that joint's frame (the
  cape's collar, between the roots of the arms and clear of the shoulders, to the chest; the
  skirt's waistband, all round the natural waist, to the spine, anchored on the abdomen's axis and
  rolling with the hip line);
* long-range attachments: every particle's nearest pin and its rest distance along the cloth
  (shortest path over structural and shear springs), which bound how far the cloth can sag;
* the order in which strain limiting visits the structural springs: by graph distance from the
  pins (so one sweep carries a pull from the pins down to the hem), split into batches of springs
  that share no particle (so a vectorised batch update equals the sequential Gauss-Seidel sweep).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from cloth_client.avatar.capsules import capsule_endpoints
from cloth_client.contact.collision import round_cone_np
from cloth_client.solver import _kernels
from protocol.kinematics import fk_global
from protocol.skeleton import CAPSULE_INDEX, JOINT_INDEX, Body, default_body, standing_pose

__all__ = ["DEFAULT_PARTICLES", "GARMENTS", "Garment", "GarmentKind", "grid_topology", "make_cape", "make_garment",
           "make_sheet", "make_skirt"]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
GarmentKind = Literal["cape", "skirt"]
GARMENTS: Final[tuple[str, ...]] = ("cape", "skirt")
#: Particles per garment unless asked otherwise: real time on one core with room to spare.
DEFAULT_PARTICLES: Final[int] = 2000
#: Cotton twill / light wool, kg per square metre.
DEFAULT_DENSITY: Final[float] = 0.20
#: Distance kept between a garment's rest shape and the body, metres.
REST_CLEARANCE: Final[float] = 0.012
#: Distance between a seam (cape collar, skirt waistband) and the body, metres: room for a shrug or
#: a bend of the trunk before a body part reaches the pinned row.
COLLAR_CLEARANCE: Final[float] = 0.025
#: Highest the skirt's waistband may sit above the spine joint to clear the hips by
#: ``REST_CLEARANCE`` in 3D (metres; it takes 5 mm for the default body).
WAIST_RAISE_MAX: Final[float] = 0.05


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


def _build(kind: str, pos: F64, wrap: bool, body: Body, pose: F64, joint: str | NDArray[np.int64],
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


def _extent(body: Body, pose: F64, origin: F64, dirs: F64, reach: float = 0.8, samples: int = 161,
            capsules: NDArray[np.int64] | None = None, first: bool = False) -> F64:
    """Distance from ``origin (M, 3)`` along unit ``dirs (M, 3)`` to the outermost body surface
    point (0 where the ray meets no capsule), metres, sampled every ``reach / (samples - 1)``.

    ``capsules`` restricts the body to those capsule indices; ``first`` returns the distance at
    which each ray first enters the body instead (``inf`` where it meets none)."""
    a, b = capsule_endpoints(body, pose)
    radii = body.capsule_radii
    if capsules is not None:
        a, b, radii = a[capsules], b[capsules], radii[capsules]
    r = np.linspace(0.0, reach, samples)
    pts = (origin[:, None, :] + r[None, :, None] * dirs[:, None, :]).reshape(-1, 3)
    depth = np.empty(len(pts))
    _kernels.penetration(pts, np.ascontiguousarray(a), np.ascontiguousarray(b), np.ascontiguousarray(radii),
                         np.ones(len(pts)), depth)
    inside = (depth > 0.0).reshape(len(origin), samples)
    if first:
        hit: F64 = np.where(inside.any(axis=1), r[np.argmax(inside, axis=1)] - reach / (samples - 1), np.inf)
        return hit
    last = np.where(inside.any(axis=1), samples - 1 - np.argmax(inside[:, ::-1], axis=1), -1)
    out: F64 = np.where(last >= 0, r[np.maximum(last, 0)] + reach / (samples - 1), 0.0)
    return out


def _grid_counts(width: float, length: float, n_particles: int) -> tuple[int, int]:
    h = np.sqrt(width * length / max(n_particles, 9))
    return max(3, round(length / h) + 1), max(3, round(width / h) + 1)


def make_cape(body: Body, n_particles: int = DEFAULT_PARTICLES, *, length: float | None = None, flare: float = 2.0,
              density: float = DEFAULT_DENSITY) -> Garment:
    """A cape hanging down the back from the shoulders, flaring towards the hem.

    Parameters
    ----------
    body : Body
    n_particles : int
        Approximate number of particles (the grid is rounded to whole rows and columns).
    length : float, optional
        Shoulder-to-hem length, metres (default: down to 30 % of the body height, mid-calf).
    flare : float
        Hem width / top width.
    density : float
        kg / m^2.
    """
    pose = standing_pose(body)
    joints, _ = fk_global(pose, body)
    ls, rs = joints[JOINT_INDEX["l_shoulder"]], joints[JOINT_INDEX["r_shoulder"]]
    r_sh = float(body.capsule_radii[3].max())  # the "shoulders" capsule
    top_y = 0.5 * (ls[1] + rs[1]) + 0.5 * r_sh
    length = float(length) if length is not None else top_y - 0.30 * body.height
    w_top = float(np.linalg.norm(ls - rs)) + r_sh
    rows, cols = _grid_counts(0.5 * (1.0 + flare) * w_top, length, n_particles)
    v = np.linspace(0.0, 1.0, rows)[:, None]
    u = np.linspace(-0.5, 0.5, cols)[None, :]
    xs = u * w_top * (1.0 + (flare - 1.0) * v)
    ys = np.broadcast_to(top_y - length * v, xs.shape)
    # depth: just behind the body; once the cloth hangs past a bulge it cannot tuck back in
    origin = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    back = _extent(body, pose, origin, np.tile([0.0, 0.0, -1.0], (xs.size, 1))).reshape(xs.shape)
    depth = np.maximum.accumulate(np.maximum(back, r_sh) + REST_CLEARANCE, axis=0)
    depth[0] += COLLAR_CLEARANCE - REST_CLEARANCE
    pos = np.stack([xs + pose[0], ys, -depth + pose[2]], axis=-1)
    # sewn at the collar only: the top row between the roots of the arms (whose capsules would
    # otherwise swallow the outer pins when an arm swings back); the corners rest on the shoulders
    r_arm = float(body.capsule_radii[6].max())
    half_span = max(0.5 * float(np.linalg.norm(ls - rs)) - r_arm - 0.01, 0.25 * w_top)
    return _build("cape", pos, False, body, pose, "chest", density, np.abs(xs[0]) <= half_span)


def make_skirt(body: Body, n_particles: int = DEFAULT_PARTICLES, *, length: float | None = None,
               flare_deg: float = 22.0, density: float = DEFAULT_DENSITY, hip_ease: float = 0.0,
               roll_with_hips: bool = True) -> Garment:
    """An A-line skirt hanging from the natural waist to below the knees, inside the arms.

    The waistband is a ring round the abdomen at the natural waist, anchored on the abdomen's axis
    (pelvis to chest joint) and turned with the spine frame swung onto that axis, rolling with the
    hip line (``roll_with_hips``): at the spine
    joint's height or just above it, as low as keeps it :data:`REST_CLEARANCE` from the pelvis and
    thighs in 3D as well as :data:`COLLAR_CLEARANCE` from the trunk in its plane (the pelvis
    capsule's hip-joint spheres reach up to the spine joint's height: the in-plane probe alone left
    9 mm over the hips, which a swaying walk closes), so no thigh or hip reaches it in a high kick
    or a walk, and well inside the elbows. Below it the skirt clears
    the hips and buttocks (a fitted yoke) and flares by ``flare_deg``; where an arm hangs beside it
    the flare is capped to stay inside the arm, so the hands swing outside the cloth instead of
    catching it against the hips.

    Parameters
    ----------
    body : Body
    n_particles : int
        Approximate number of particles.
    length : float, optional
        Waistband-to-hem length, metres (default: to 4 % of the height below the knees).
    flare_deg : float
        Angle between the skirt's side and the vertical, degrees.
    density : float
        kg / m^2.
    hip_ease : float
        Extra room (metres, radial) over the hips and buttocks beyond :data:`REST_CLEARANCE`, where
        the hanging arms leave it: a bow or a hip swing tilts the pelvis inside the ring and needs
        a longer circumference than standing. 0 by default: 2 cm cut the skirt sweep's frames over
        10 % strain by a fifth but not the recordings over it (docs/CLOTH.md, session 7).
    roll_with_hips : bool
        The waistband rolls with the hip line (``Garment.pin_roll``; session 20): square to the
        abdomen's axis otherwise, it is crossed by the high hip of a pelvis rolled against the
        chest.
    """
    pose = standing_pose(body)
    joints, _ = fk_global(pose, body)
    pelvis, chest = joints[JOINT_INDEX["pelvis"]], joints[JOINT_INDEX["chest"]]
    arms = np.array([CAPSULE_INDEX[f"{side}_{part}"] for side in "lr" for part in ("upper_arm", "forearm", "hand")])
    trunk_legs = np.setdiff1d(np.arange(len(body.capsule_radii)), arms)
    # waistband: a ring hugging the trunk at top_y, angle 0 = front (+Z), increasing towards +X
    probe = 72
    theta_p = np.linspace(0.0, 2 * np.pi, probe, endpoint=False)
    dirs_p = np.stack([np.sin(theta_p), np.zeros(probe), np.cos(theta_p)], axis=1)
    a, b = capsule_endpoints(body, pose)
    a, b, radii = a[trunk_legs], b[trunk_legs], body.capsule_radii[trunk_legs]
    for raise_y in np.arange(0.0, WAIST_RAISE_MAX + 1e-9, 0.0025):  # the lowest ring that clears the hips
        top_y = float(joints[JOINT_INDEX["spine"], 1]) + raise_y
        s_waist = (top_y - pelvis[1]) / (chest[1] - pelvis[1])
        centre = pelvis + s_waist * (chest - pelvis)
        waist = _extent(body, pose, np.tile(centre, (probe, 1)), dirs_p, capsules=trunk_legs) + COLLAR_CLEARANCE
        d, _, _ = round_cone_np(centre + waist[:, None] * dirs_p, a, b, radii[:, 0], radii[:, 1])
        if d.min() >= REST_CLEARANCE:
            break
    knee_y = 0.5 * (joints[JOINT_INDEX["l_knee"], 1] + joints[JOINT_INDEX["r_knee"], 1])
    length = float(length) if length is not None else top_y - (knee_y - 0.04 * body.height)
    tan_f = np.tan(np.radians(flare_deg))
    circumference = 2 * np.pi * (float(waist.mean()) + 0.5 * length * tan_f)
    rows, cols = _grid_counts(circumference, length, n_particles)
    theta = np.linspace(0.0, 2 * np.pi, cols, endpoint=False)
    r_top = np.interp(theta, theta_p, waist, period=2 * np.pi)
    v = np.linspace(0.0, 1.0, rows)[:, None]
    radius = r_top[None, :] + tan_f * length * v
    ys = np.broadcast_to(top_y - length * v, radius.shape)
    dirs = np.tile(np.stack([np.sin(theta), np.zeros(cols), np.cos(theta)], axis=1), (rows, 1))
    origin = np.stack([np.full(radius.size, centre[0]), ys.ravel(), np.full(radius.size, centre[2])], axis=1)
    clear = _extent(body, pose, origin, dirs, capsules=trunk_legs).reshape(radius.shape) + REST_CLEARANCE
    arm = _extent(body, pose, origin, dirs, capsules=arms, first=True).reshape(radius.shape) - REST_CLEARANCE
    ease = np.full(radius.shape, hip_ease)
    ease[0] = 0.0  # not the waistband
    clear = np.maximum(clear, np.minimum(clear + ease, arm))  # the ease, where the hanging arms leave room
    clear = np.maximum.accumulate(clear, axis=0)  # once past the hips the cloth does not tuck back in
    radius = np.maximum(np.minimum(radius, arm), clear)
    pos = np.stack([centre[0] + radius * dirs[:cols, 0], ys, centre[2] + radius * dirs[:cols, 2]], axis=-1)
    return _build("skirt", pos, True, body, pose, "spine", density, seam="release",
                  axis=("pelvis", "chest", float(s_waist)), roll=("l_hip", "r_hip") if roll_with_hips else None)


def make_sheet(rows: int, cols: int, spacing: float = 0.02, *, height: float = 2.0,
               density: float = DEFAULT_DENSITY, body: Body | None = None) -> Garment:
    """A flat horizontal sheet (no body needed): ``rows x cols`` particles ``spacing`` apart in the
    plane ``y = height``, row 0 along +X at ``z = 0`` and rows advancing towards -Z; the whole
    first row is pinned (to the pelvis of ``body`` in its standing pose, for bookkeeping only:
    drive the pins with explicit targets). Used by tests and benchmarks."""
    b = body or default_body()
    pose = standing_pose(b)
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    pos = np.stack([c * spacing, np.full(r.shape, height), -r * spacing], axis=-1).astype(np.float64)
    return _build("sheet", pos, False, b, pose, "pelvis", density)


def make_garment(kind: str, body: Body, n_particles: int = DEFAULT_PARTICLES) -> Garment:
    """:func:`make_cape` or :func:`make_skirt` by name (``"cape"`` / ``"skirt"``)."""
    if kind == "cape":
        return make_cape(body, n_particles)
    if kind == "skirt":
        return make_skirt(body, n_particles)
    raise ValueError(f"unknown garment {kind!r}; choose one of {', '.join(GARMENTS)}")
