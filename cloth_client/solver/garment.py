"""Parametric garments sized to a body: a cape pinned at the shoulders and a skirt pinned at the waist.

Every garment is a regular particle grid (``rows x cols``, the skirt wrapping around in columns)
placed around the body in its relaxed standing pose (:func:`protocol.skeleton.standing_pose`) so
that it clears every body capsule by a margin; :func:`cloth_client.solver.grid.build_garment`
assembles the :class:`~cloth_client.solver.grid.Garment` (springs, triangles, masses, pins,
long-range attachments, strain-limiting order) from those positions. The pins are top-row particles:
the cape's collar, between the roots of the arms and clear of the shoulders, sewn to the chest; the
skirt's waistband, all round the natural waist, sewn to the spine, anchored on the abdomen's axis and
rolling with the hip line.
"""

from __future__ import annotations

from typing import Final, Literal

import numpy as np
from numpy.typing import NDArray

from cloth_client.avatar.capsules import capsule_endpoints
from cloth_client.contact.collision import round_cone_reference
from cloth_client.contact.cone_kernels import penetration
from cloth_client.solver.grid import Garment, build_garment, grid_topology
from protocol.kinematics import fk_global
from protocol.skeleton import CAPSULE_INDEX, JOINT_INDEX, Body, default_body, standing_pose

__all__ = ["DEFAULT_PARTICLES", "GARMENTS", "Garment", "GarmentKind", "grid_topology", "make_cape", "make_garment",
           "make_sheet", "make_skirt"]

F64 = NDArray[np.float64]
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
    penetration(pts, np.ascontiguousarray(a), np.ascontiguousarray(b), np.ascontiguousarray(radii),
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
    return build_garment("cape", pos, False, body, pose, "chest", density, np.abs(xs[0]) <= half_span)


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
        10 % strain by a fifth but not the recordings over it (docs/CLOTH.md).
    roll_with_hips : bool
        The waistband rolls with the hip line (``Garment.pin_roll``): square to the abdomen's axis
        otherwise, it is crossed by the high hip of a pelvis rolled against the chest.
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
        d, _, _ = round_cone_reference(centre + waist[:, None] * dirs_p, a, b, radii[:, 0], radii[:, 1])
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
    return build_garment("skirt", pos, True, body, pose, "spine", density, seam="release",
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
    return build_garment("sheet", pos, False, b, pose, "pelvis", density)


def make_garment(kind: str, body: Body, n_particles: int = DEFAULT_PARTICLES) -> Garment:
    """:func:`make_cape` or :func:`make_skirt` by name (``"cape"`` / ``"skirt"``)."""
    if kind == "cape":
        return make_cape(body, n_particles)
    if kind == "skirt":
        return make_skirt(body, n_particles)
    raise ValueError(f"unknown garment {kind!r}; choose one of {', '.join(GARMENTS)}")
