"""Gesture scripts: keyframed joint angles and root motion in a small TOML format.

They author the motions the shared recordings lack (side-steps, crouches, the game's gestures).
A script is a list of keys; each key sets some joints and/or the root at a time ``t`` and
inherits everything else from the previous key. Between keys, joint rotations are slerped and
the root is interpolated linearly, both along an easing curve. Example (``protocol/scripts/
crouch.toml`` ships with the package)::

    name = "crouch"            # optional, default: file stem
    feet = "planted"           # "planted": the root is solved to keep both feet on the floor in
                               # place (root x/y/z of keys ignored); "free" (default): as keyed
    fps = 30                   # optional sampling rate of the produced motion
    base = "stand"             # "stand" (arms relaxed at the sides) or "tpose"
    euler_order = "ZYX"        # joint angles: R = Rz(z) @ Ry(y) @ Rx(x), degrees
    duration = 3.0             # optional; default: time of the last key

    [body]                     # optional target body (protocol.skeleton.body_from_measurements)
    height_m = 1.70

    [noise]                    # optional, deterministic for a seed
    rotation_deg = 1.0         # std of Gaussian noise on every joint rotation component
    position_m = 0.005         # std on the root position
    seed = 3

    [[key]]
    t = 0.0

    [[key]]
    t = 0.5
    ease = "in_out"            # linear | in | out | in_out | step (easing of the segment ending here)
    root = { y = -0.30 }       # metres relative to the base's standing position; yaw/pitch/roll in degrees
    joints.l_hip = { x = -70 }
    joints.l_knee = { x = 110 }

Joint names are those of :data:`protocol.skeleton.JOINT_NAMES` with a rotation
(:data:`~protocol.skeleton.ROT_JOINTS` minus the root); angles are relative to the T-pose rest
frame (see :mod:`protocol.skeleton`): a joint given in a key replaces that joint's rotation.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from protocol.kinematics import fk
from protocol.motion import Motion
from protocol.rotations import (
    euler_to_matrix,
    matrix_to_euler,
    matrix_to_quat,
    matrix_to_rotvec,
    quat_slerp,
    quat_to_matrix,
    rotvec_to_matrix,
)
from protocol.skeleton import (
    JOINT_INDEX,
    POSE_SIZE,
    ROT_JOINTS,
    Body,
    body_from_measurements,
    default_body,
    rest_pose,
    standing_pose,
)

__all__ = ["EASINGS", "ScriptError", "load_script", "parse_script", "script_poses"]

_EASE = {
    "linear": lambda a: a,
    "in": lambda a: a * a,
    "out": lambda a: 1 - (1 - a) ** 2,
    "in_out": lambda a: a * a * (3 - 2 * a),
    "step": lambda a: np.where(a >= 1.0, 1.0, 0.0),
}
EASINGS = tuple(_EASE)
_ROOT_KEYS = ("x", "y", "z", "yaw", "pitch", "roll")
_TOP_KEYS = {"name", "fps", "base", "euler_order", "duration", "body", "noise", "key", "description", "feet"}


class ScriptError(ValueError):
    """A malformed gesture script; the message names the file and the offending key."""


#: Longest script accepted (seconds): key times and ``duration`` beyond it are rejected before
#: anything is sampled (a typo such as ``duration = 1e9`` would otherwise allocate hundreds of GiB).
MAX_DURATION_S = 3600.0


@dataclass(frozen=True)
class _Key:
    t: float
    ease: str
    root: dict[str, float]
    joints: dict[str, NDArray[np.float64]]  # joint -> (3, 3) rotation matrix


@dataclass(frozen=True)
class Script:
    """A parsed script (see module docstring)."""

    name: str
    fps: float
    base: str
    feet: str
    duration: float
    keys: tuple[_Key, ...]
    body: dict[str, float]
    noise_rot_deg: float
    noise_pos_m: float
    noise_seed: int


def _num(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ScriptError(f"{where}: expected a finite number, got {v!r}")
    return float(v)


def parse_script(text: str, origin: str = "<script>") -> Script:
    """Parse and validate script text.

    Raises
    ------
    ScriptError
        Bad TOML, unknown fields or joints, non-increasing times, bad values.
    """
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ScriptError(f"{origin}: invalid TOML: {e}") from None
    unknown = set(doc) - _TOP_KEYS
    if unknown:
        raise ScriptError(f"{origin}: unknown top-level fields {sorted(unknown)}")
    order = str(doc.get("euler_order", "ZYX")).upper()
    if len(order) != 3 or set(order) != set("XYZ"):
        raise ScriptError(f"{origin}: euler_order must be a permutation of XYZ, got {order!r}")
    base = doc.get("base", "stand")
    if base not in ("stand", "tpose"):
        raise ScriptError(f"{origin}: base must be 'stand' or 'tpose', got {base!r}")
    feet = doc.get("feet", "free")
    if feet not in ("free", "planted"):
        raise ScriptError(f"{origin}: feet must be 'free' or 'planted', got {feet!r}")
    fps = _num(doc.get("fps", 30), f"{origin}: fps")
    if not 1 <= fps <= 1000:
        raise ScriptError(f"{origin}: fps must be in [1, 1000]")
    raw_keys = doc.get("key")
    if not isinstance(raw_keys, list) or not raw_keys:
        raise ScriptError(f"{origin}: needs at least one [[key]]")
    keys: list[_Key] = []
    last_t = -math.inf
    for i, k in enumerate(raw_keys):
        where = f"{origin}: key {i + 1}"
        if not isinstance(k, dict):
            raise ScriptError(f"{where}: must be a table")
        extra = set(k) - {"t", "ease", "root", "joints"}
        if extra:
            raise ScriptError(f"{where}: unknown fields {sorted(extra)}")
        t = _num(k.get("t"), f"{where}: t")
        if t <= last_t or t < 0:
            raise ScriptError(f"{where}: times must start at >= 0 and increase (t = {t})")
        if t > MAX_DURATION_S:
            raise ScriptError(f"{where}: t = {t} s is beyond the longest script allowed "
                              f"({MAX_DURATION_S:g} s = 1 hour)")
        last_t = t
        ease = k.get("ease", "in_out")
        if ease not in _EASE:
            raise ScriptError(f"{where}: ease must be one of {EASINGS}, got {ease!r}")
        root = k.get("root", {})
        if not isinstance(root, dict) or set(root) - set(_ROOT_KEYS):
            raise ScriptError(f"{where}: root takes {_ROOT_KEYS}")
        root_v = {a: _num(v, f"{where}: root.{a}") for a, v in root.items()}
        joints: dict[str, NDArray[np.float64]] = {}
        for jn, ang in (k.get("joints") or {}).items():
            if jn not in ROT_JOINTS[1:]:
                raise ScriptError(f"{where}: unknown joint {jn!r} (use root for the pelvis)")
            if isinstance(ang, list):
                if len(ang) != 3:
                    raise ScriptError(f"{where}: joints.{jn} needs 3 angles [x, y, z]")
                xyz = [_num(a, f"{where}: joints.{jn}") for a in ang]
            elif isinstance(ang, dict):
                if set(ang) - {"x", "y", "z"}:
                    raise ScriptError(f"{where}: joints.{jn} takes x, y, z (degrees)")
                xyz = [_num(ang.get(a, 0.0), f"{where}: joints.{jn}.{a}") for a in "xyz"]
            else:
                raise ScriptError(f"{where}: joints.{jn} must be {{x=, y=, z=}} or [x, y, z]")
            by_axis = dict(zip("XYZ", np.radians(xyz), strict=True))
            joints[jn] = euler_to_matrix([by_axis[a] for a in order], order)
        keys.append(_Key(t, ease, root_v, joints))
    duration = _num(doc.get("duration", keys[-1].t), f"{origin}: duration")
    if duration < keys[-1].t:
        raise ScriptError(f"{origin}: duration {duration} is before the last key")
    if duration > MAX_DURATION_S:
        raise ScriptError(f"{origin}: duration {duration} s is longer than the longest script allowed "
                          f"({MAX_DURATION_S:g} s = 1 hour)")
    body = doc.get("body", {})
    noise = doc.get("noise", {})
    if not isinstance(body, dict) or not isinstance(noise, dict):
        raise ScriptError(f"{origin}: [body] and [noise] must be tables")
    if set(noise) - {"rotation_deg", "position_m", "seed"}:
        raise ScriptError(f"{origin}: [noise] takes rotation_deg, position_m, seed")
    return Script(
        name=str(doc.get("name", Path(origin).stem)),
        fps=fps, base=base, feet=feet, duration=duration, keys=tuple(keys),
        body={str(a): _num(v, f"{origin}: body.{a}") for a, v in body.items()},
        noise_rot_deg=_num(noise.get("rotation_deg", 0.0), f"{origin}: noise"),
        noise_pos_m=_num(noise.get("position_m", 0.0), f"{origin}: noise"),
        noise_seed=int(_num(noise.get("seed", 0), f"{origin}: noise.seed")),
    )


def script_poses(script: Script, body: Body, fps: float | None = None,
                 rng: np.random.Generator | None = None) -> NDArray[np.float64]:
    """Sample a script into pose vectors.

    Parameters
    ----------
    script : Script
    body : Body
        Sets the standing root height.
    fps : float, optional
        Sampling rate (default the script's).
    rng : np.random.Generator, optional
        Noise source (default: seeded from the script's ``[noise] seed``).

    Returns
    -------
    (F, P) float64
    """
    rate = fps or script.fps
    base = standing_pose(body) if script.base == "stand" else rest_pose()
    if script.base == "tpose":
        base[1] = body.standing_root_height()
    nj = len(ROT_JOINTS)
    # key states: per key the full set of local rotations (quaternions) and root values
    cur_q = matrix_to_quat(rotvec_to_matrix(base[3:].reshape(nj, 3)))
    cur_root = dict.fromkeys(_ROOT_KEYS, 0.0)
    states_q, states_r = [], []
    for key in script.keys:
        cur_q = cur_q.copy()
        for jn, m in key.joints.items():
            cur_q[ROT_JOINTS.index(jn)] = matrix_to_quat(m)
        cur_root = {**cur_root, **key.root}
        states_q.append(cur_q)
        states_r.append(np.array([cur_root[a] for a in _ROOT_KEYS]))
    times = np.array([k.t for k in script.keys])
    if not (math.isfinite(rate) and 0 < rate <= 1000):
        raise ScriptError(f"{script.name}: sampling rate must be in (0, 1000] fps, got {rate}")
    if script.duration > MAX_DURATION_S:
        raise ScriptError(f"{script.name}: duration {script.duration} s is longer than the longest script "
                          f"allowed ({MAX_DURATION_S:g} s = 1 hour)")
    n = math.floor(script.duration * rate + 1e-9) + 1
    t = np.arange(n) / rate
    n_keys = len(times)
    idx = np.searchsorted(times, t, side="right")  # number of keys at or before t
    k1 = np.clip(idx, 0, n_keys - 1)  # key ending the current segment
    k0 = np.clip(idx - 1, 0, n_keys - 1)
    alpha = np.zeros(n)
    for k in range(1, n_keys):
        sel = idx == k
        frac = (t[sel] - times[k - 1]) / (times[k] - times[k - 1])
        alpha[sel] = _EASE[script.keys[k].ease](np.clip(frac, 0.0, 1.0))
    k1 = np.where(idx >= n_keys, n_keys - 1, np.where(idx == 0, 0, k1))  # hold before the first / after the last key
    q_all = np.stack(states_q)  # (K, R, 4)
    r_all = np.stack(states_r)  # (K, 6)
    q = quat_slerp(q_all[k0], q_all[k1], np.broadcast_to(alpha[:, None], (n, nj)))
    r = (1 - alpha)[:, None] * r_all[k0] + alpha[:, None] * r_all[k1]
    rots = matrix_to_rotvec(quat_to_matrix(q))  # (n, R, 3)
    yaw_pitch_roll = np.radians(r[:, 3:6])
    root_m = euler_to_matrix(yaw_pitch_roll, "YXZ") @ rotvec_to_matrix(rots[:, 0])
    rots[:, 0] = matrix_to_rotvec(root_m)
    out = np.zeros((n, POSE_SIZE))
    out[:, :3] = base[:3] + r[:, :3]
    out[:, 3:] = rots.reshape(n, -1)
    if script.feet == "planted":
        out = _plant_feet(out, body)
    if script.noise_rot_deg > 0 or script.noise_pos_m > 0:
        g = rng or np.random.default_rng(script.noise_seed)
        out[:, :3] += g.normal(0.0, script.noise_pos_m, (n, 3))
        out[:, 6:] += g.normal(0.0, np.radians(script.noise_rot_deg), (n, POSE_SIZE - 6))
    return out


def _plant_feet(poses: NDArray[np.float64], body: Body) -> NDArray[np.float64]:
    """Move the root so the ankles' mid-point keeps its first-frame floor position and the lowest
    foot point touches the floor in every frame."""
    j = fk(poses, body)
    feet = [JOINT_INDEX[n] for n in ("l_ankle", "l_toe", "r_ankle", "r_toe")]
    mid = 0.5 * (j[:, JOINT_INDEX["l_ankle"]] + j[:, JOINT_INDEX["r_ankle"]])
    out = poses.copy()
    out[:, 0] -= mid[:, 0] - mid[0, 0]
    out[:, 2] -= mid[:, 2] - mid[0, 2]
    out[:, 1] -= j[:, feet, 1].min(axis=1) - j[0, feet, 1].min()
    return out


def load_script(path: str | Path, *, fps: float | None = None, body: Body | None = None,
                rng: np.random.Generator | None = None) -> Motion:
    """Read a gesture script file as a :class:`~protocol.motion.Motion`.

    Parameters
    ----------
    path : str or Path
    fps : float, optional
        Sampling rate (default: the script's ``fps``).
    body : Body, optional
        Target body; default: the script's ``[body]`` or :func:`~protocol.skeleton.default_body`.
    rng : np.random.Generator, optional
        Noise source overriding the script's seed.

    Raises
    ------
    ScriptError, OSError
    """
    p = Path(path)
    script = parse_script(p.read_text(encoding="utf-8"), str(p))
    if body is None:
        try:
            body = body_from_measurements(**script.body, name=script.name) if script.body else default_body()
        except (TypeError, ValueError) as e:
            raise ScriptError(f"{p}: bad [body]: {e}") from None
    poses = script_poses(script, body, fps, rng)
    return Motion(poses=poses, fps=float(fps or script.fps), name=script.name, body=body, source=str(p))


def euler_of(rotvec: NDArray[np.float64], order: str = "ZYX") -> NDArray[np.float64]:
    """Script angles (degrees, x/y/z) of a joint rotation vector, for authoring tools."""
    ang = np.degrees(matrix_to_euler(rotvec_to_matrix(rotvec), order))
    by_axis = dict(zip(order, ang, strict=True))
    return np.array([by_axis["X"], by_axis["Y"], by_axis["Z"]])
