"""The product's built-in input source: a realistic synthetic camera view of a person whose true
pose is known.

A :class:`SyntheticScene` plays a motion (BVH recording or gesture script, read by
:func:`protocol.formats.load.load_motion`) on a randomly proportioned, clothed person
(:mod:`tracker_service.scene.subject`) standing in a furnished room (:mod:`tracker_service.scene.room`)
seen by the paper's camera (:func:`tracker_service.camera.default_camera`), and yields
``(timestamp, frame, truth)``: a BGR uint8 image and its :class:`GroundTruth` (pose vector, 3D and
2D joints, true silhouette, part labels, per-part visibility).

Per frame: the person's mesh is skinned on the CPU and drawn by pyrender (lit colour pass with 4x
multisampling, then a segmentation pass that also draws the planar shadows on the floor and the
back wall); it is composited over the pre-rendered room, whose shadowed pixels are darkened by the
soft (blurred) shadow; then exposure drift and flicker, vignetting and sensor noise (read + shot)
are applied. An optional sub-pixel camera jitter moves the principal point, and an optional radial
distortion warps the final image and the ground truth together. Everything random comes from the
seed: the same seed and motion give identical frames, in any order of access.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from protocol.formats.load import load_motion
from protocol.motion import Motion, ground, resample
from protocol.rotations import matrix_to_rotvec, rotvec_to_matrix
from protocol.skeleton import JOINT_INDEX, N_JOINTS, N_PARTS, POSE_SIZE, ROT_SLOT
from tracker_service.body.raster import render_labels_with_areas
from tracker_service.camera import Camera, default_camera
from tracker_service.scene.gl import labels_from_seg
from tracker_service.scene.render import SceneRenderer
from tracker_service.scene.subject import ClothedSubject, SubjectSpec, build_subject, random_subject_spec
from tracker_service.scene.variation import SceneVariation, degrade_frame, vary_subject

__all__ = ["GroundTruth", "SceneConfig", "SceneFrame", "SyntheticScene", "place_motion", "scene_subject", "stooped"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SceneConfig:
    """Options of the synthetic scene (defaults: the paper's 320×240 camera, realistic noise).

    Attributes
    ----------
    width, height : int
        Image size (4:3).
    fps : float or None
        Resample the motion to this rate (None: the motion's own rate).
    empty_prefix : int
        Frames of empty room before the person appears (for background learning).
    camera_jitter_px : float
        Amplitude (pixels) of a small principal-point wobble; 0 for a steady tripod.
    distortion : tuple of float
        Radial distortion ``(k1, k2)`` of the camera (0, 0: none).
    noise : bool
        Sensor noise, exposure drift / flicker and vignetting (False: clean renders).
    face_camera : bool
        Turn the motion about the vertical so the person faces the camera in its first frame.
    in_place : bool
        Remove the root's horizontal travel (walks stay on the spot) instead of only centring it.
    variation : tuple of str
        Domain-randomisation axes (:data:`tracker_service.scene.variation.AXES`); empty: the
        default draw.
    camera : Camera, optional
        The camera filming the scene (its size wins over ``width`` and ``height``); None: the
        paper's camera at ``width`` x ``height``.
    """

    width: int = 320
    height: int = 240
    fps: float | None = None
    empty_prefix: int = 0
    camera_jitter_px: float = 0.0
    distortion: tuple[float, float] = (0.0, 0.0)
    noise: bool = True
    face_camera: bool = True
    in_place: bool = False
    variation: tuple[str, ...] = ()
    camera: Camera | None = None


@dataclass(frozen=True)
class GroundTruth:
    """What the tracker should recover from one frame.

    Attributes
    ----------
    index : int
        Frame number (0 = first frame, including the empty prefix).
    present : bool
        False during the empty-background prefix (then the arrays below are NaN / empty).
    pose : (P,) float64
        Pose vector of the person in the scene's world frame.
    joints : (J, 3) float64
        World joint positions, metres.
    joints_2d : (J, 2) float64
        Their pixel coordinates (OpenCV convention), with this frame's camera.
    silhouette : (H, W) bool
        Pixels covered by the person (clothes and hair included; not the shadow).
    part_labels : (H, W) int8
        Body part (index into :data:`~protocol.skeleton.PARTS`) seen at each pixel, -1 elsewhere.
    part_pixels : (N_PARTS,) int64
        Visible pixels of each part (0 = fully occluded or off-screen, eq. 14).
    visibility : (N_PARTS,) float64
        Visible fraction of each part's projected area, from the person's capsule proxy
        (:func:`~tracker_service.body.raster.render_labels_with_areas`).
    camera : Camera
        The camera of this frame (jitter included).
    """

    index: int
    present: bool
    pose: NDArray[np.float64]
    joints: NDArray[np.float64]
    joints_2d: NDArray[np.float64]
    silhouette: NDArray[np.bool_]
    part_labels: NDArray[np.int8]
    part_pixels: NDArray[np.int64]
    visibility: NDArray[np.float64]
    camera: Camera


class SceneFrame(NamedTuple):
    """``(timestamp seconds, image (H, W, 3) uint8 BGR, truth)``."""

    timestamp: float
    image: NDArray[np.uint8]
    truth: GroundTruth


def place_motion(poses: NDArray[np.float64], *, face_camera: bool = True,
                 in_place: bool = False) -> NDArray[np.float64]:
    """Put a motion on the scene's stage: heading of frame 0 towards the camera (+Z), horizontal
    root travel centred on the origin (or removed with ``in_place``).

    Parameters
    ----------
    poses : (F, P) float

    Returns
    -------
    (F, P) float64
    """
    p = np.array(poses, dtype=np.float64, copy=True)
    if face_camera:
        fwd = rotvec_to_matrix(p[0, 3:6])[:, 2]
        yaw = -np.arctan2(fwd[0], fwd[2])
        ry = rotvec_to_matrix(np.array([0.0, yaw, 0.0]))
        p[:, 3:6] = matrix_to_rotvec(ry[None] @ rotvec_to_matrix(p[:, 3:6]))
        p[:, 0:3] = p[:, 0:3] @ ry.T
    if in_place:
        p[:, [0, 2]] = 0.0
    else:
        lo, hi = p[:, [0, 2]].min(axis=0), p[:, [0, 2]].max(axis=0)
        p[:, [0, 2]] -= 0.5 * (lo + hi)
        if np.any(hi - lo > 2.5):
            log.warning("the motion travels %.1f x %.1f m; the person may leave the view", *(hi - lo))
    return p


def scene_subject(seed: int, axes: tuple[str, ...] = (),
                  rng: np.random.Generator | None = None) -> tuple[SubjectSpec, SceneVariation]:
    """The person that ``seed`` draws, varied along ``axes``, and the scene-wide variation.

    ``rng``: the scene's generator (``default_rng([seed, 0])``), advanced past the person's draw;
    the variation has a stream of its own."""
    spec = random_subject_spec(rng if rng is not None else np.random.default_rng([int(seed), 0]))
    if not axes:
        return spec, SceneVariation()
    vary = np.random.default_rng([int(seed), 3, 0])
    return vary_subject(spec, axes, vary), SceneVariation.draw(axes, vary)


def stooped(poses: NDArray[np.float64], angle: float) -> NDArray[np.float64]:
    """``poses`` with the spine and the neck flexed forward by ``angle`` (radians) in all, as an
    elderly person stoops (half at the chest, a quarter each at the spine and the neck)."""
    out = np.array(poses, np.float64, copy=True)
    for joint, share in (("spine", 0.25), ("chest", 0.5), ("neck", 0.25)):
        sl = slice(3 + 3 * ROT_SLOT[JOINT_INDEX[joint]], 6 + 3 * ROT_SLOT[JOINT_INDEX[joint]])
        bend = rotvec_to_matrix(np.array([share * angle, 0.0, 0.0]))
        out[:, sl] = matrix_to_rotvec(rotvec_to_matrix(out[:, sl]) @ bend)
    return out


class SyntheticScene:
    """A synthetic video of a clothed person performing ``motion``.

    Parameters
    ----------
    motion : Motion
        Played on the scene's own person (joint rotations kept; root re-grounded and placed).
    seed : int
        Chooses the person, outfit, room, lighting and all noise.
    config : SceneConfig

    Notes
    -----
    Holds an EGL context: use as a context manager or call :meth:`close`. Frames can be read in
    any order with :meth:`frame`; iteration yields them all. Use it from one thread.
    """

    def __init__(self, motion: Motion, seed: int = 0, config: SceneConfig | None = None) -> None:
        self.config = cfg = config or SceneConfig()
        self.seed = int(seed)
        rng = np.random.default_rng([self.seed, 0])
        spec, self.variation = scene_subject(self.seed, cfg.variation, rng)
        self.subject: ClothedSubject = build_subject(spec)
        m = resample(motion, cfg.fps) if cfg.fps else motion
        placed = place_motion(m.poses, face_camera=cfg.face_camera, in_place=cfg.in_place)
        if spec.stoop > 0:
            placed = stooped(placed, spec.stoop)
        self.poses = ground(placed, self.subject.body)
        self.fps = float(m.fps)
        self.motion_name = m.name
        self.camera = cfg.camera if cfg.camera is not None else default_camera(cfg.width, cfg.height,
                                                                                dist=cfg.distortion)
        self._renderer = SceneRenderer(self.subject, self.camera, rng, self.variation,
                                       np.random.default_rng([self.seed, 3, 1]))
        self._jitter = rng.uniform(0.0, 2 * np.pi, 4), rng.uniform(0.2, 0.6, 2)
        self._expo = rng.uniform(0.0, 2 * np.pi, 3), rng.uniform(0.05, 0.25), rng.uniform(7.0, 13.0)
        log.info("synthetic scene seed %d: %s person %.2f m, %d frames at %.1f fps", self.seed,
                 self.subject.spec.group, self.subject.spec.height, self.n_frames, self.fps)

    @classmethod
    def from_file(cls, path: str | Path, seed: int = 0, config: SceneConfig | None = None) -> SyntheticScene:
        """Load a ``.bvh`` recording or ``.toml`` gesture script, retargeted onto the person that
        ``seed`` chooses, and build the scene for it."""
        body = build_subject(scene_subject(int(seed), (config or SceneConfig()).variation)[0]).body
        return cls(load_motion(path, body=body), seed, config)

    def __enter__(self) -> SyntheticScene:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Release the GL context."""
        self._renderer.close()

    def __len__(self) -> int:
        return self.n_frames

    @property
    def n_frames(self) -> int:
        """Empty prefix plus motion frames."""
        return self.config.empty_prefix + len(self.poses)

    def __iter__(self) -> Iterator[SceneFrame]:
        for i in range(self.n_frames):
            yield self.frame(i)

    def frame_camera(self, i: int) -> Camera:
        """The (jittered) camera of frame ``i``."""
        a = self.config.camera_jitter_px
        if a <= 0:
            return self.camera
        ph, fr = self._jitter
        t = i / self.fps
        du = a * (0.7 * np.sin(2 * np.pi * fr[0] * t + ph[0]) + 0.3 * np.sin(2 * np.pi * 3.1 * fr[0] * t + ph[1]))
        dv = a * (0.7 * np.sin(2 * np.pi * fr[1] * t + ph[2]) + 0.3 * np.sin(2 * np.pi * 2.7 * fr[1] * t + ph[3]))
        return self.camera.shifted(float(du), float(dv))

    def frame(self, i: int) -> SceneFrame:
        """Render frame ``i`` (0 <= i < :attr:`n_frames`)."""
        if not 0 <= i < self.n_frames:
            raise IndexError(f"frame {i} outside 0..{self.n_frames - 1}")
        cfg = self.config
        rng = np.random.default_rng([self.seed, 1, i])
        cam = self.frame_camera(i)
        k = i - cfg.empty_prefix
        h, w = self.camera.height, self.camera.width
        joints = np.full((N_JOINTS, 3), np.nan)
        if k < 0:
            linear = self._renderer.empty(cam)
            seg = np.zeros((h, w, 3), np.uint8)
        else:
            linear, seg, joints = self._renderer.render(self.poses[k], cam)
        gain = self._exposure(i, rng) if cfg.noise else np.ones(3, np.float32)
        image = self._renderer.finish(linear, gain, rng if cfg.noise else None)
        labels = labels_from_seg(seg)
        labels = np.where(labels < N_PARTS, labels, -1).astype(np.int8)  # drop shadow codes
        image, labels = self._renderer.distort(image, labels)
        if self.variation.blur_px > 0 or self.variation.codec != "none":
            image = degrade_frame(image, self.variation, np.random.default_rng([self.seed, 4, i]))
        truth = self._truth(i, k, cam, labels, joints)
        return SceneFrame(i / self.fps, image, truth)

    def _exposure(self, i: int, rng: np.random.Generator) -> NDArray[np.float32]:
        ph, slow, flick = self._expo
        t = i / self.fps
        swing = self.variation.exposure_swing
        g = 1.0 + swing * np.sin(2 * np.pi * slow * t + ph[0]) + 0.008 * np.sin(2 * np.pi * flick * t + ph[1])
        g += 0.004 * rng.standard_normal()
        wb = 1.0 + 0.01 * np.sin(2 * np.pi * 0.5 * slow * t + ph[2] + np.array([0.0, 2.1, 4.2]))
        return (g * wb).astype(np.float32)

    def _truth(self, i: int, k: int, cam: Camera, labels: NDArray[np.int8], joints: NDArray[np.float64]) -> GroundTruth:
        if k < 0:
            return GroundTruth(i, False, np.full(POSE_SIZE, np.nan), joints, joints[:, :2].copy(), labels >= 0,
                               labels, np.zeros(N_PARTS, np.int64), np.zeros(N_PARTS), cam)
        counts = np.bincount(labels[labels >= 0].astype(np.int64), minlength=N_PARTS)[:N_PARTS]
        _, vis, area = render_labels_with_areas(joints, self.subject.body.capsule_radii, cam)
        frac = np.where(area > 0, vis / np.maximum(area, 1), 0.0)[:N_PARTS]
        return GroundTruth(i, True, self.poses[k].copy(), joints, cam.project(joints), labels >= 0, labels,
                           counts.astype(np.int64), frac, cam)
