"""Pose sequences: the common in-memory form of recordings and gesture scripts, and resampling."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .skeleton import POSE_SIZE, Body, default_body

__all__ = ["Motion", "load_motion"]


@dataclass(frozen=True)
class Motion:
    """A pose sequence on the shared skeleton.

    Attributes
    ----------
    poses : (F, P) float64
        One pose vector per frame (layout in :mod:`protocol.skeleton`).
    fps : float
        Frames per second.
    name : str
        Human-readable name (file stem or script name).
    body : Body
        Body the poses were retargeted for (root height and translation are scaled to it).
    source : str
        Where it came from (path), empty if built in memory.
    valid : (F,) bool
        False for frames flagged as artefacts (glitches, converter T-poses) that a pose database
        should skip; all True unless the reader found some.
    """

    poses: NDArray[np.float64]
    fps: float
    name: str = ""
    body: Body = field(default_factory=default_body)
    source: str = ""
    valid: NDArray[np.bool_] | None = None

    def __post_init__(self) -> None:
        p = np.asarray(self.poses, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != POSE_SIZE:
            raise ValueError(f"poses must be (F, {POSE_SIZE}), got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError("poses contain NaN or inf")
        if not (self.fps > 0 and np.isfinite(self.fps)):
            raise ValueError(f"fps must be positive, got {self.fps}")
        object.__setattr__(self, "poses", p)
        v = np.ones(len(p), dtype=bool) if self.valid is None else np.asarray(self.valid, dtype=bool)
        if v.shape != (len(p),):
            raise ValueError("valid must have one entry per frame")
        object.__setattr__(self, "valid", v)

    @property
    def n_frames(self) -> int:
        return int(self.poses.shape[0])

    @property
    def duration(self) -> float:
        """Seconds from the first to one frame past the last frame."""
        return self.n_frames / self.fps

    @property
    def times(self) -> NDArray[np.float64]:
        """(F,) float64 frame times in seconds, starting at 0."""
        return np.arange(self.n_frames) / self.fps


def load_motion(path: str | Path, *, fps: float | None = None, body: Body | None = None) -> Motion:
    """Read a BVH recording or a gesture script (``.toml``) as a :class:`Motion` on our skeleton.

    Parameters
    ----------
    path : str or Path
        ``*.bvh`` (retargeted onto the shared skeleton) or ``*.toml`` (gesture script).
    fps : float, optional
        Resample to this rate (default: the file's own rate).
    body : Body, optional
        Target body (default: :func:`protocol.skeleton.default_body`).
    """
    raise NotImplementedError("being written in this change")
