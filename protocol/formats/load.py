"""Reading any supported motion file (BVH recording or gesture script) as a :class:`~protocol.motion.Motion`.

This module sits above both readers: :mod:`protocol.motion` (BVH) and :mod:`protocol.formats.gesture_script`
(which builds on :class:`~protocol.motion.Motion`), so neither of them imports the other's dispatcher.
"""

from __future__ import annotations

from pathlib import Path

from protocol.formats.gesture_script import load_script
from protocol.motion import Motion, load_bvh_motion
from protocol.skeleton import Body

__all__ = ["load_motion"]


def load_motion(path: str | Path, *, fps: float | None = None, body: Body | None = None) -> Motion:
    """Read a BVH recording or a gesture script (``.toml``) as a :class:`~protocol.motion.Motion` on our skeleton.

    Parameters
    ----------
    path : str or Path
        ``*.bvh`` (retargeted onto the shared skeleton) or ``*.toml`` (gesture script).
    fps : float, optional
        Resample to this rate (default: the file's own rate; 30 Hz for scripts without one).
    body : Body, optional
        Target body (default: :func:`protocol.skeleton.default_body`).

    Raises
    ------
    FileNotFoundError, BvhError, ScriptError, ValueError
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"no such motion file: {p}")
    suffix = p.suffix.lower()
    if suffix == ".bvh":
        return load_bvh_motion(p, body=body, fps=fps)
    if suffix == ".toml":
        return load_script(p, fps=fps, body=body)
    raise ValueError(f"{p}: unknown motion file type {suffix!r} (expected .bvh or .toml)")
