"""Drive a garment with a stream of poses: dressing, interpolation, resets and quality metrics.

:class:`ClothDriver` is shared by the offline ``simulate`` command and the live Zenoh client. Feed
it ``(pose, time)`` pairs as they arrive:

* **first two poses** - *dressing*: the garment, built around the standing pose, is carried to
  the first pose's root frame, the limbs are blended from standing to the first pose over
  ``dress_s`` seconds, then the avatar holds that pose for ``settle_s`` seconds while the cloth
  comes to rest (the energy of that hold gives :attr:`RunStats.energy_drift`). Throughout, the
  avatar glides at the root velocity of the first two poses, so a stream that starts mid-walk
  does not hit a cloth at rest; the simulation starts at the first pose;
* **continuous motion** - the cloth is stepped over the time between the two poses with the
  avatar interpolated at ``key_dt`` spacing (15-120 Hz input and dropped frames alike);
* **discontinuity** (:func:`cloth_client.avatar.capsules.is_discontinuity`) - *smooth reset*: the cloth is
  moved rigidly with the root, the limbs swing from their old to their new angles over
  ``reset_blend_s`` of simulated time with extra damping, then extra damping fades out over
  ``reset_calm_s``;
* **a body part over the seam** (a shrug under the collar, a hand or forearm on the waistband) -
  the garment's ``seam`` policy applies: a collar slides out onto the covering surface; a
  waistband lets the covered pins (a body part other than the one it is sewn round within
  ``seam_reach``) and their neighbours go for that step (they collide like free
  cloth) unless more than ``slide_fraction`` of it is covered, when it slides too (pushing a
  waistband's pins out to the nearest surface sends neighbours to opposite sides of a thigh: the
  rest of the pins carries the garment meanwhile); a forearm or hand on the waistband slides it
  instead (``DriverConfig.slide_under_arms``: released, the band let a forearm pressed on it
  into the gap and stretched over it); what a slide still stretches of the seam is shortened
  again (``DriverConfig.keep_seam_length``);
* a non-finite value (never expected) re-dresses the garment and is counted.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from cloth_client.avatar.capsules import (
    LIMBS,
    AvatarKeys,
    Continuity,
    avatar_capsules,
    capsule_endpoints,
    interpolate_poses,
    is_discontinuity,
    limb_overlap,
    pose_keys,
    rigid_root_delta,
)
from cloth_client.avatar.limb_clearance import LIMB_CLEARANCE
from cloth_client.contact.collision import CapsuleTrack, round_cone_reference
from cloth_client.contact.cone_kernels import penetration
from cloth_client.solver.cloth import (
    ClothModel,
    ClothParams,
    ClothState,
    build_model,
    energy,
    initial_state,
    plan_substeps,
    step,
    structural_strain,
    tethers_held,
)
from cloth_client.solver.garment import Garment
from protocol.kinematics import fk
from protocol.skeleton import Body

__all__ = ["ClothDriver", "DriverConfig", "FrameStats", "RunStats"]

log = logging.getLogger(__name__)
F64 = NDArray[np.float64]
GHOST_RADIUS = 1e-3  # radius of a limb that is sunk into the trunk (m); see ClothDriver._ghosted


@dataclass(frozen=True)
class DriverConfig:
    """Timing of dressing, interpolation and resets (seconds; damping in 1/s); the sunk-limb rules
    (metres): ``limb_clearance`` the gap sunk upper arms, forearms and hands are turned out to
    (:mod:`cloth_client.avatar.limb_clearance`; None keeps the recorded limbs, the legs too, which are
    otherwise kept :data:`~cloth_client.avatar.leg_clearance.LEG_CLEARANCE` apart), ``ghost_depth`` /
    ``ghost_clear`` when what is left sunk stops / starts pushing the cloth again; a slid seam's
    move spread along ``seam_spread`` metres of the seam either side (``AvatarKeys.slide_seam``,
    rounded to whole pins: 8 at 2,000 particles; 0: none), and with ``keep_seam_length`` what the
    slide still stretched shortened again (``AvatarKeys.keep_seam_length``; False: the slide alone);
    with ``slide_under_arms`` a forearm or hand on a waistband slides it instead of releasing the
    pins it covers (``ClothDriver._seam_action``; False: every covering body part releases them)."""

    key_dt: float = 1.0 / 240.0
    dress_s: float = 0.6
    settle_s: float = 0.6
    frame_dt: float = 1.0 / 60.0
    reset_blend_s: float = 0.1
    reset_calm_s: float = 0.3
    reset_damping: float = 6.0
    seam_reach: float = 0.04
    slide_fraction: float = 0.8
    seam_spread: float = 0.09
    ghost_depth: float = 0.02
    ghost_clear: float = -0.03
    limb_clearance: float | None = LIMB_CLEARANCE
    keep_seam_length: bool = True
    slide_under_arms: bool = True
    continuity: Continuity = field(default_factory=Continuity)


@dataclass(frozen=True)
class FrameStats:
    """Quality of the cloth after one fed pose.

    Attributes
    ----------
    t : float
        Pose time, seconds.
    substeps : int
        Substeps taken for this pose.
    max_penetration, mean_penetration : float
        Deepest and mean depth of the particles inside the body, metres (0 when none is).
    penetrating : int
        Number of particles inside the body.
    max_strain : float
        Largest structural strain (0.05 = 5 % longer than at rest).
    reset : bool
        This pose was a discontinuity and the cloth was reset.
    """

    t: float
    substeps: int
    max_penetration: float
    mean_penetration: float
    penetrating: int
    max_strain: float
    reset: bool


@dataclass
class RunStats:
    """Totals over a run (see :meth:`ClothDriver.summary`)."""

    frames: int = 0
    substeps: int = 0
    sim_time: float = 0.0
    max_penetration: float = 0.0
    penetration_sum: float = 0.0
    penetrating: int = 0
    max_strain: float = 0.0
    resets: int = 0
    recoveries: int = 0
    skipped: int = 0
    energy_drift: float = 0.0
    settle_kinetic: float = 0.0
    nan: bool = False


class ClothDriver:
    """Simulate ``garment`` on ``body`` driven by poses; see the module docstring.

    Parameters
    ----------
    body : Body
    garment : Garment
    params : ClothParams, optional
    config : DriverConfig, optional
    """

    def __init__(self, body: Body, garment: Garment, params: ClothParams | None = None,
                 config: DriverConfig | None = None) -> None:
        self.body = body
        self.garment = garment
        self.model: ClothModel = build_model(garment, params)
        self.config = config or DriverConfig()
        self.state: ClothState | None = None
        self.pose: F64 | None = None
        self.stats = RunStats()
        self._calm_until = -math.inf
        self._depth = np.empty(garment.n_particles)
        self._free = self.model.inv_mass > 0
        self._first: tuple[F64, float] | None = None
        self._seam_margin = self._seam_reach()
        if not self.config.seam_spread >= 0.0:
            raise ValueError(f"seam_spread must be >= 0 metres, got {self.config.seam_spread}")
        seam = garment.rest[garment.pin_index]
        spacing = float(np.linalg.norm(np.diff(seam, axis=0), axis=1).mean()) if len(seam) > 1 else 0.0
        self._spread_pins = round(self.config.seam_spread / spacing) if spacing > 0.0 else 0
        ring = np.vstack([seam, seam[:1]]) if garment.wrap else seam
        self._seam_rest = np.linalg.norm(np.diff(ring, axis=0), axis=1)  # segment rest lengths of the seam
        self._body_end: tuple[F64, F64] | None = None
        self._ghost = np.zeros(len(LIMBS), dtype=bool)
        self._overlap: F64 | None = None
        self._limb_memory: F64 | None = None  # sunk-limb corrections carried from step to step
        self._tethers: dict[bytes, tuple[NDArray[np.int64], F64]] = {}
        self._joints: tuple[F64, F64] | None = None  # (self.pose, its joint positions)

    # -- public ---------------------------------------------------------------------------------------
    def feed(self, pose: F64, t: float) -> FrameStats | None:
        """Advance the cloth to pose ``pose (P,)`` at time ``t`` (s); None if the pose was skipped
        (not newer than the previous one)."""
        pose = np.asarray(pose, dtype=np.float64)
        if not np.all(np.isfinite(pose)):
            self.stats.skipped += 1
            return None
        if self.state is None or self.pose is None:
            if self._first is None or not t > self._first[1]:
                self._first = (pose, t)  # dress once the second pose tells how fast the body moves
                return None
            p0, t0 = self._first
            gap = t - t0
            moving = not is_discontinuity(self.body, p0, pose, gap, self.config.continuity)
            glide = (pose[:3] - p0[:3]) / gap if moving else np.zeros(3)
            glide[1] = 0.0  # horizontal only: the vertical bob of a gait averages out
            self.dress(p0, t0, glide)
            self.stats.frames += 1
        assert self.state is not None and self.pose is not None
        dt = t - self.state.t
        if not dt > 1e-6:
            self.stats.skipped += 1
            return None
        before = self.state.substeps
        j1 = fk(pose, self.body)
        j0 = self._joints[1] if self._joints is not None and self._joints[0] is self.pose else fk(self.pose, self.body)
        reset = is_discontinuity(self.body, self.pose, pose, dt, self.config.continuity, joints=(j0, j1))
        if reset:
            self._reset(pose, t)
        else:
            self._advance(self.pose, pose, dt)
        if not np.all(np.isfinite(self.state.x)) or not np.all(np.isfinite(self.state.v)):
            log.error("cloth state became non-finite at t=%.3f s; re-dressing", t)
            self.stats.nan = True
            self.stats.recoveries += 1
            self.dress(pose, t)
        self.state.t = t
        self.pose = pose
        self._joints = (pose, j1)  # the next frame's discontinuity test starts from these joints
        self.stats.sim_time += dt
        return self._measure(pose, t, self.state.substeps - before, reset)

    def dress(self, pose: F64, t: float, root_velocity: F64 | None = None) -> None:
        """Put the garment on the avatar at ``pose`` (see the module docstring); the clock is set to ``t``.

        With ``root_velocity`` (m/s) the avatar glides at that velocity during dressing and settling
        and arrives at ``pose`` at time ``t``, so the cloth is already moving with a body that was
        walking when the stream began."""
        cfg = self.config
        vel = np.zeros(3) if root_velocity is None else np.asarray(root_velocity, dtype=np.float64)
        t0 = t - cfg.dress_s - cfg.settle_s

        def at(limbs: F64, tau: float) -> F64:  # ``limbs`` with the root where the glide puts it at tau
            q = limbs.copy()
            q[:3] = pose[:3] - vel * (t - tau)
            return q

        standing = self.garment.pose.copy()
        standing[3:6] = pose[3:6]
        start = at(standing, t0)
        rot, shift = rigid_root_delta(self.garment.pose, start)
        self.state = initial_state(self.model, self.garment.rest @ rot.T + shift, t0)
        self._limb_memory = None
        self.state.v[:] = vel
        self.pose = start
        n_dress = max(1, round(cfg.dress_s / cfg.frame_dt))
        for k in range(1, n_dress + 1):
            target = at(interpolate_poses(start, pose, np.array([k / n_dress]))[0], t0 + k * cfg.dress_s / n_dress)
            self._advance(self.pose, target, cfg.dress_s / n_dress)
            self.pose = target
        e0 = top = self._energy_in_body_frame(vel)
        n_settle = max(1, round(cfg.settle_s / cfg.frame_dt))
        for k in range(1, n_settle + 1):
            target = at(pose, t0 + cfg.dress_s + k * cfg.settle_s / n_settle)
            self._advance(self.pose, target, cfg.settle_s / n_settle)
            self.pose = target
            top = max(top, self._energy_in_body_frame(vel))
        scale = self.garment.total_mass * abs(self.model.params.gravity[1]) * float(np.ptp(self.garment.rest[:, 1]))
        self.stats.energy_drift = max(self.stats.energy_drift, (top - e0) / max(scale, 1e-12))
        self.stats.settle_kinetic = self._energy_in_body_frame(vel, "kinetic")
        self.state.t = t
        self.pose = pose

    def _energy_in_body_frame(self, velocity: F64, part: str = "total") -> float:
        """Energy of the cloth seen from a frame gliding with the avatar (joules)."""
        assert self.state is not None
        moving = ClothState(self.state.x, self.state.v - velocity, self.state.t)
        return energy(self.model, moving)[part]

    @property
    def body_capsules(self) -> tuple[F64, F64] | None:
        """Capsule endpoints ``(C, 3)``, ``(C, 3)`` of the avatar at the last pose fed (sunk limbs
        turned out as the cloth saw them); None before the garment is dressed."""
        return self._body_end

    def summary(self) -> dict[str, float | int | bool]:
        """Run totals in SI units (metres, seconds)."""
        s = self.stats
        return {
            "frames": s.frames, "substeps": s.substeps, "sim_time_s": s.sim_time,
            "max_penetration_m": s.max_penetration,
            "mean_penetration_m": s.penetration_sum / s.penetrating if s.penetrating else 0.0,
            "penetrating_particle_frames": s.penetrating, "max_strain": s.max_strain, "resets": s.resets,
            "recoveries": s.recoveries, "skipped": s.skipped, "energy_drift": s.energy_drift,
            "settle_kinetic_j": s.settle_kinetic, "nan": s.nan,
        }

    # -- internals ------------------------------------------------------------------------------------
    def _advance(self, p0: F64, p1: F64, dt: float, extra_damping: float = 0.0) -> None:
        assert self.state is not None
        n_keys = max(1, math.ceil(dt / self.config.key_dt - 1e-9))
        keys = pose_keys(self.body, interpolate_poses(p0, p1, np.linspace(0.0, 1.0, n_keys + 1)),
                         self.config.limb_clearance, self._limb_memory)
        self._limb_memory = keys.limb_memory
        g = self.garment
        pins = keys.pin_targets(g.pin_joint, g.pin_local, g.pin_axis, g.pin_axis_s, g.pin_axis_local, g.pin_roll)
        body = self._ghosted(keys.track)  # first: the seam rule reads this step's sunk limbs
        slide, released = self._seam_action(keys, pins)
        if slide:
            # slide the seam over the body part that covers it (always for a collar; for a
            # waistband when most of it is covered, instead of letting the garment go, or with
            # slide_under_arms where a forearm or hand covers it)
            pins = keys.slide_seam(pins, self.model.params.margin, self._spread_pins, self.garment.wrap,
                                   self._seam_rest if self.config.keep_seam_length else None)
        if extra_damping == 0.0 and self.state.t < self._calm_until:
            left = (self._calm_until - self.state.t) / self.config.reset_calm_s
            extra_damping = self.config.reset_damping * min(1.0, left)
        # substeps planned on the full-size limbs: a sunk limb's thin stand-in would count as fast
        n_sub = plan_substeps(self.model, keys.track, dt, self.state)
        self.state = step(self.state, self.model, body, pins, dt, released=released,
                          n_substeps=n_sub, extra_damping=extra_damping, tethers=self._held_tethers(released))
        self._body_end = (keys.track.a[-1], keys.track.b[-1])  # the capsules at p1, for _measure
        self._free = self.model.inv_mass > 0
        self._free[self.garment.pin_index[released]] = True

    def _held_tethers(self, released: NDArray[np.bool_]) -> tuple[NDArray[np.int64], F64] | None:
        """Long-range attachments to the held pins while some are released (None: the model's own);
        cached per released set (:func:`~cloth_client.solver.cloth.tethers_held`)."""
        if not released.any():
            return None
        key = np.packbits(released).tobytes()
        if key not in self._tethers:
            if len(self._tethers) >= 512:
                self._tethers.clear()
            self._tethers[key] = tethers_held(self.model, released)
        return self._tethers[key]

    def _ghosted(self, track: CapsuleTrack) -> CapsuleTrack:
        """``track`` with the forearms and hands that are still sunk into the trunk shrunk to a line.

        :mod:`~cloth_client.avatar.limb_clearance` turns a sunk limb out of the trunk when it can. One it
        cannot (passing through the trunk, deeper than its ``MAX_PUSH``), or every sunk limb when
        ``limb_clearance`` is None, sinks more than ``ghost_depth`` at the start or end of the step:
        it then no longer pushes the cloth (it keeps a ``GHOST_RADIUS``), so the cloth stays on the
        trunk under it instead of being squeezed into the overlap, dragged into the body with the
        limb and left with the limb inside the garment. It pushes again once it is clear of the
        trunk: turned out (half the clearance away; the cloth on the trunk under it is then
        between the two) or, without the clearance rule, ``ghost_clear`` away (a gap when
        negative). The forearm and the hand of a side go together (a hand left active at a sunk
        wrist wedges cloth into the crease)."""
        cfg = self.config
        end = limb_overlap(track.a[-1], track.b[-1], track.radii)  # the start is the previous step's end
        depth = end if self._overlap is None else np.maximum(end, self._overlap)
        self._overlap = end
        clear = cfg.ghost_clear if cfg.limb_clearance is None else -0.5 * cfg.limb_clearance
        ghost = np.where(self._ghost, depth > clear, depth > cfg.ghost_depth)
        self._ghost = ghost.reshape(-1, 2).any(axis=1).repeat(2)  # forearm and hand of a side together
        if not self._ghost.any():
            return track
        radii = track.radii.copy()
        radii[LIMBS[self._ghost]] = GHOST_RADIUS
        return CapsuleTrack(track.a, track.b, radii)

    def _seam_reach(self) -> F64:
        """Per-capsule distance ``(C,)`` at which a body part counts as covering a seam pin.

        The cloth margin for the body parts the seam is sewn round (within ``seam_reach`` of a pin
        in the build pose); ``seam_reach`` for the others (for a waistband: arms and hands), which
        would otherwise wedge between the pinned row and the cloth just below it."""
        g, p = self.garment, self.model.params
        out = np.full(len(self.body.capsule_radii), p.margin)
        if g.seam != "release":
            return out
        a, b = capsule_endpoints(self.body, g.pose)
        d, _, _ = round_cone_reference(g.rest[g.pin_index], a, b, self.body.capsule_radii[:, 0],
                                       self.body.capsule_radii[:, 1])
        out[d.min(axis=0) > self.config.seam_reach] = self.config.seam_reach
        return out

    def _seam_action(self, keys: AvatarKeys, pins: F64) -> tuple[bool, NDArray[np.bool_]]:
        """What the seam does over one frame's keys: ``(slide, released (P,) bool)``.

        A collar always slides and releases nothing. A waistband lets go of the pins a body part
        covers (:meth:`_widen`), unless more than ``slide_fraction`` of them are covered, when it
        slides instead and releases nothing; with ``slide_under_arms`` only the trunk, legs and
        upper arms (and a limb sunk into the trunk) release pins, and a forearm or hand on the
        waistband slides it (the released pins, free, are not moved by the slide).

        Parameters
        ----------
        keys : AvatarKeys
            The body over the frame's ``K + 1`` keys.
        pins : (K + 1, P, 3) float64
            The seam pins' targets at each key.
        """
        if self.garment.seam == "slide":
            return True, np.zeros(pins.shape[1], dtype=bool)
        if not self.config.slide_under_arms:
            released, slide = self._widen(keys.covered(pins, self._seam_margin)), False
        else:
            arm, trunk = self._split_reach()
            released = self._widen(keys.covered(pins, trunk))
            slide = bool(keys.covered(pins, arm).any())
        if released.sum() > self.config.slide_fraction * len(released):
            return True, np.zeros_like(released)
        return slide, released

    def _split_reach(self) -> tuple[F64, F64]:
        """``_seam_margin`` split into the reach of the forearms and hands that slide the seam
        and that of the body parts that release it, each ``(C,)`` with the others out of reach
        (``-inf``). A forearm and hand ghosted for this step (sunk into the trunk,
        :meth:`_ghosted`) release, as without ``slide_under_arms``: a slide would push the pins
        out of a limb that is inside the hips."""
        arm = np.zeros(len(self._seam_margin), dtype=bool)
        arm[LIMBS[~self._ghost]] = True
        return np.where(arm, self._seam_margin, -np.inf), np.where(arm, -np.inf, self._seam_margin)

    def _widen(self, covered: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """``covered`` pins plus their neighbours along the seam (the seam gives way around the
        body part that pushes into it instead of tearing at its edge)."""
        if not covered.any():
            return covered
        order = self.garment.pin_index  # pins are top-row particles, in column order
        cols = self.garment.grid_shape[1]
        near = np.abs(order[:, None] - order[None, :])
        if self.garment.wrap:
            near = np.minimum(near, cols - near)
        out: NDArray[np.bool_] = ((near <= 1) & covered[None, :]).any(axis=1)
        return out

    def _reset(self, pose: F64, t: float) -> None:
        assert self.state is not None and self.pose is not None
        cfg = self.config
        self.stats.resets += 1
        mid = self.pose.copy()
        mid[:6] = pose[:6]
        rot, shift = rigid_root_delta(self.pose, mid)
        if self._limb_memory is not None:  # the limbs' corrections (world offsets) move with the root
            self._limb_memory = self._limb_memory @ rot.T
        log.info("pose discontinuity at t=%.3f s: root moved %.2f m; resetting the cloth smoothly",
                 t, float(np.linalg.norm(shift + (rot - np.eye(3)) @ self.pose[:3])))
        self.state = ClothState(self.state.x @ rot.T + shift, 0.5 * self.state.v @ rot.T,
                                t - cfg.reset_blend_s, self.state.substeps)
        self._advance(mid, pose, cfg.reset_blend_s, extra_damping=cfg.reset_damping)
        self._calm_until = t + cfg.reset_calm_s

    def _measure(self, pose: F64, t: float, substeps: int, reset: bool) -> FrameStats:
        assert self.state is not None
        a, b = self._body_end if self._body_end is not None else avatar_capsules(self.body, pose,
                                                                                 self.config.limb_clearance)
        penetration(self.state.x, a, b, self.body.capsule_radii, self._free.astype(np.float64), self._depth)
        inside = self._depth > 0.0
        n_in = int(inside.sum())
        deepest = float(self._depth.max()) if n_in else 0.0
        strain = float(structural_strain(self.model, self.state.x).max())
        s = self.stats
        s.substeps += substeps
        s.frames += 1
        s.max_penetration = max(s.max_penetration, deepest)
        s.penetration_sum += float(self._depth[inside].sum())
        s.penetrating += n_in
        s.max_strain = max(s.max_strain, strain)
        return FrameStats(t, substeps, deepest, float(self._depth[inside].mean()) if n_in else 0.0, n_in,
                          strain, reset)
