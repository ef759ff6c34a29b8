"""Bundled gesture scripts, their ground truth, and variants (speed, amplitude, body, facing, noise).

The scripts in ``game_client/scripts/`` use the Foundation's format (:mod:`protocol.formats.gesture_script`);
``labels.toml`` next to them lists the gestures each contains and when each one is complete.
A :class:`Variant` rewrites a script's TOML text before it is parsed, so every variant is itself a
valid script (``write_variant`` saves one for ``mocap-tracker replay --script``):

* ``speed`` stretches time (2.0 = twice as slow); label times scale with it;
* ``amplitude`` scales every keyed joint angle's departure from the standing pose and the root
  offsets (0.85 = a smaller movement);
* ``height_m`` sets ``[body] height_m`` (the whole skeleton scales);
* ``yaw_deg`` turns the player about the vertical (root yaw and root offsets rotate together, so a
  side-step stays sideways to the body);
* ``noise_rot_deg`` / ``noise_pos_m`` / ``seed`` set the script's ``[noise]`` (per-frame jitter on
  every joint rotation and the root position);
* ``fps`` is the sampling rate of the produced motion.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from protocol.formats.gesture_script import parse_script, script_poses
from protocol.motion import Motion
from protocol.skeleton import body_from_measurements, default_body

__all__ = ["SCRIPTS_DIR", "Label", "Variant", "dump_script", "load_labels", "script_path", "variant_labels",
           "variant_motion", "variant_text", "write_variant"]

#: Folder of the bundled scripts and ``labels.toml``.
SCRIPTS_DIR: Final[Path] = Path(__file__).resolve().parent / "scripts"
# Script angles (degrees, x/y/z) of the "stand" base pose; amplitude scales departures from these.
_STAND: Final[dict[str, tuple[float, float, float]]] = {
    "l_shoulder": (0.0, 0.0, -80.0), "r_shoulder": (0.0, 0.0, 80.0),
    "l_elbow": (0.0, -8.0, 0.0), "r_elbow": (0.0, 8.0, 0.0),
}


@dataclass(frozen=True)
class Label:
    """One ground-truth gesture of a script: its name, completion time and side-step direction."""

    gesture: str
    end_s: float
    direction: str | None = None


@dataclass(frozen=True)
class Variant:
    """How to vary a script (see the module docstring). The default changes nothing."""

    speed: float = 1.0
    amplitude: float = 1.0
    height_m: float | None = None
    yaw_deg: float = 0.0
    noise_rot_deg: float = 0.0
    noise_pos_m: float = 0.0
    seed: int = 0
    fps: float = 30.0

    @property
    def tag(self) -> str:
        """Short text naming the variant, e.g. ``"x1.4_a0.85_h1.5_y-40_n1.5_30Hz"``."""
        h = f"_h{self.height_m:g}" if self.height_m else ""
        return (f"x{self.speed:g}_a{self.amplitude:g}{h}_y{self.yaw_deg:g}_n{self.noise_rot_deg:g}"
                f"_{self.fps:g}Hz")


def script_path(name: str) -> Path:
    """Path of a bundled script by name (``"fire_ring"``) or the path itself if it is a file."""
    p = Path(name)
    if p.suffix == ".toml" and p.is_file():
        return p
    q = SCRIPTS_DIR / f"{name}.toml"
    if not q.is_file():
        raise FileNotFoundError(f"no bundled gesture script {name!r} in {SCRIPTS_DIR}")
    return q


def load_labels(path: Path | None = None) -> dict[str, tuple[Label, ...]]:
    """Ground truth per script name from ``labels.toml``.

    Raises
    ------
    ValueError
        If an entry is malformed.
    """
    p = path or SCRIPTS_DIR / "labels.toml"
    doc = tomllib.loads(p.read_text(encoding="utf-8"))
    out: dict[str, tuple[Label, ...]] = {}
    for name, entry in doc.items():
        try:
            out[name] = tuple(Label(str(g["gesture"]), float(g["end_s"]), g.get("direction"))
                              for g in entry["gestures"])
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"{p}: bad entry [{name}]: {e}") from None
    return out


def variant_labels(labels: tuple[Label, ...], v: Variant) -> tuple[Label, ...]:
    """Labels of a variant (times scale with ``speed``)."""
    return tuple(Label(lb.gesture, lb.end_s * v.speed, lb.direction) for lb in labels)


def _scale_angles(joint: str, ang: Any, a: float) -> dict[str, float]:
    base = _STAND.get(joint, (0.0, 0.0, 0.0))
    vals = dict(zip("xyz", ang, strict=True)) if isinstance(ang, list) else dict(ang)
    return {ax: base[i] + a * (float(vals[ax]) - base[i]) for i, ax in enumerate("xyz") if ax in vals}


def variant_text(text: str, v: Variant) -> str:
    """A script's TOML text rewritten for variant ``v`` (comments are not kept)."""
    doc = tomllib.loads(text)
    c, s = math.cos(math.radians(v.yaw_deg)), math.sin(math.radians(v.yaw_deg))
    for i, key in enumerate(doc.get("key", [])):
        key["t"] = float(key["t"]) * v.speed
        root = dict(key.get("root", {}))
        x, z = float(root.get("x", 0.0)) * v.amplitude, float(root.get("z", 0.0)) * v.amplitude
        if "x" in root or "z" in root:  # a yaw turns the body about +Y: offsets turn with it
            root["x"], root["z"] = c * x + s * z, -s * x + c * z
        if "y" in root:
            root["y"] = float(root["y"]) * v.amplitude
        if i == 0 or "yaw" in root:
            root["yaw"] = float(root.get("yaw", 0.0)) + v.yaw_deg
        key["root"] = root
        if "joints" in key:
            key["joints"] = {j: _scale_angles(j, ang, v.amplitude) for j, ang in key["joints"].items()}
    if "duration" in doc:
        doc["duration"] = float(doc["duration"]) * v.speed
    if v.height_m is not None:
        doc["body"] = {**doc.get("body", {}), "height_m": float(v.height_m)}
    if v.noise_rot_deg > 0 or v.noise_pos_m > 0:
        doc["noise"] = {"rotation_deg": float(v.noise_rot_deg), "position_m": float(v.noise_pos_m),
                        "seed": int(v.seed)}
    doc["fps"] = float(v.fps)
    return dump_script(doc)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to a gesture script")


def dump_script(doc: dict[str, Any]) -> str:
    """TOML text of a gesture-script document (the subset of TOML the format uses)."""
    lines = [f"{k} = {_value(v)}" for k, v in doc.items() if k not in ("body", "noise", "key")]
    for table in ("body", "noise"):
        if doc.get(table):
            lines += ["", f"[{table}]"] + [f"{k} = {_value(v)}" for k, v in doc[table].items()]
    for key in doc.get("key", []):
        lines += ["", "[[key]]"]
        for k, v in key.items():
            if k == "joints":
                lines += [f"joints.{j} = {_value(a)}" for j, a in v.items()]
            elif not (k == "root" and not v):
                lines.append(f"{k} = {_value(v)}")
    return "\n".join(lines) + "\n"


def variant_motion(name: str | Path, v: Variant | None = None) -> Motion:
    """The motion of a bundled script (or script file) under variant ``v``.

    Returns
    -------
    Motion
        ``poses (F, P) float64`` at ``v.fps`` on a body of ``v.height_m`` (or the script's own).
    """
    v = v or Variant()
    path = script_path(str(name))
    text = variant_text(path.read_text(encoding="utf-8"), v)
    script = parse_script(text, f"{path}[{v.tag}]")
    body = body_from_measurements(**script.body, name=script.name) if script.body else default_body()
    poses = script_poses(script, body, v.fps)
    return Motion(poses=poses, fps=float(v.fps), name=f"{script.name}[{v.tag}]", body=body, source=str(path))


def write_variant(name: str | Path, v: Variant, out: Path) -> Path:
    """Write variant ``v`` of a script as a script file (for ``mocap-tracker replay --script``)."""
    path = script_path(str(name))
    out.write_text(variant_text(path.read_text(encoding="utf-8"), v), encoding="utf-8")
    return out
