"""Compose whole-round gesture scripts from the bundled single-gesture scripts.

A round script is a timeline of segments (``(start_s, script name)``); each segment's keys are
shifted to its start. The result is one script in the Foundation's format with ``feet = "free"``:
segments authored with ``feet = "planted"`` (crouch, arm gestures) get the root offsets the
planted-feet solver computes at their key times, and side-steps' root offsets accumulate, so
the player ends a side-step where it landed and the next segment starts from there.

``python -m game_client.compose`` rewrites ``scripts/round_win.toml`` and
``scripts/round_lose.toml`` and prints their labels for ``scripts/labels.toml``; a test checks
that the files in the repository are what this module generates.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from typing import Any

import numpy as np

from protocol.formats.gesture_script import euler_of, parse_script, script_poses
from protocol.skeleton import ROT_JOINTS, default_body, standing_pose

from .game import GameConfig
from .variants import SCRIPTS_DIR, Label, dump_script, load_labels, script_path

__all__ = ["ROUNDS", "Segment", "compose", "round_segments", "write_rounds"]

#: Recognition delay assumed after a gesture's end when timing the next segment, seconds.
_DELAY = 0.06
#: Resampling interval of planted-feet segments whose root moves (crouches), seconds.
_SAMPLE_S = 0.1


@dataclass(frozen=True)
class Segment:
    """One gesture script placed on the round's timeline."""

    start_s: float
    script: str


def _planted_keys(text: str, doc: dict[str, Any]) -> list[dict[str, Any]]:
    """Keys reproducing a planted-feet script in free-feet mode.

    Where the planted solver moves the root (a crouch), the motion is resampled every
    :data:`_SAMPLE_S` with explicit root offsets and joint angles (linear between samples), so the
    feet stay on the floor; otherwise the original keys are kept with the solver's root offsets.
    """
    script = parse_script(text)
    body = default_body()
    poses = script_poses(script, body, 1000.0)
    base = standing_pose(body)[:3]
    offsets = poses[:, :3] - base
    keys = [dict(k) for k in doc["key"]]
    if np.abs(offsets).max() < 0.01:
        for k in keys:
            k.pop("root", None)
        return keys
    joints = sorted({j for k in keys for j in k.get("joints", {})})
    times = sorted({round(float(k["t"]), 4) for k in keys}
                   | {round(float(t), 4) for t in np.arange(0.0, float(keys[-1]["t"]), _SAMPLE_S)})
    out = []
    for t in times:
        i = min(round(t * 1000.0), len(poses) - 1)
        rot = poses[i, 3:].reshape(-1, 3)
        angles = {j: euler_of(rot[ROT_JOINTS.index(j)], "ZYX") for j in joints}
        out.append({"t": t, "ease": "linear",
                    "root": {a: round(float(v), 4) for a, v in zip("xyz", offsets[i], strict=True)},
                    "joints": {j: {a: round(float(v), 2) for a, v in zip("xyz", ang, strict=True)}
                               for j, ang in angles.items()}})
    return out


def compose(segments: list[Segment], duration: float, name: str) -> tuple[dict[str, Any], tuple[Label, ...]]:
    """Merge segments into one script document and its labels.

    Returns
    -------
    doc : dict
        Script document (write it with :func:`game_client.variants.dump_script`).
    labels : tuple of Label
    """
    keys: list[dict[str, Any]] = [{"t": 0.0}]
    labels: list[Label] = []
    all_labels = load_labels()
    ox = oz = 0.0
    for seg in sorted(segments, key=lambda s: s.start_s):
        text = script_path(seg.script).read_text(encoding="utf-8")
        doc = tomllib.loads(text)
        if doc.get("euler_order", "ZYX") != "ZYX" or doc.get("base", "stand") != "stand":
            raise ValueError(f"{seg.script}: only ZYX scripts on the standing base can be composed")
        planted = doc.get("feet", "free") == "planted"
        seg_keys = _planted_keys(text, doc) if planted else doc["key"]
        last_x = last_z = 0.0
        for i, key in enumerate(seg_keys):
            t = round(seg.start_s + float(key["t"]), 4)
            if t <= keys[-1]["t"]:
                if i == 0:
                    continue  # the segment's opening key coincides with the previous end
                raise ValueError(f"segment {seg.script} at {seg.start_s} s overlaps the previous one")
            out: dict[str, Any] = {"t": t}
            if "ease" in key:
                out["ease"] = key["ease"]
            if "root" in key:
                root = dict(key["root"])
                if not planted:
                    last_x, last_z = float(root.get("x", last_x)), float(root.get("z", last_z))
                root["x"] = round(ox + (last_x if not planted else float(root.get("x", 0.0))), 4)
                root["z"] = round(oz + (last_z if not planted else float(root.get("z", 0.0))), 4)
                out["root"] = root
            if "joints" in key:
                out["joints"] = key["joints"]
            keys.append(out)
        ox, oz = ox + last_x, oz + last_z
        labels += [Label(lb.gesture, round(seg.start_s + lb.end_s, 4), lb.direction)
                   for lb in all_labels[seg.script]]
    doc_out = {"name": name, "fps": 30, "base": "stand", "feet": "free", "euler_order": "ZYX",
               "duration": float(duration), "key": keys}
    return doc_out, tuple(labels)


def round_segments(kind: str, config: GameConfig | None = None) -> tuple[list[Segment], float]:
    """The timeline of a scripted round against the default game schedule.

    ``"win"``: transform, duck the first (high) attack and answer with a strike, side-step the
    second (sideways) attack and answer with a fire ring, which knocks the opponent out.
    ``"lose"``: transform, then stand still and take every hit.

    Returns
    -------
    segments : list of Segment
    duration : float
        Script length, seconds.
    """
    c = config or GameConfig()
    labels = load_labels()
    fight = labels["transform"][0].end_s + _DELAY
    segs = [Segment(0.0, "transform")]
    if kind == "lose":
        last = fight + c.first_attack_s + 3 * c.attack_period_s + c.windup_s + 2.0
        return segs, round(last + 1.0, 2)
    if kind != "win":
        raise ValueError(f"unknown round {kind!r} (win or lose)")
    crouch_end, step_end = labels["crouch"][0].end_s, labels["side_step_right"][0].end_s
    steps = ["side_step_right", "side_step_left"]
    for i in range(2):
        t_attack = fight + c.first_attack_s + i * c.attack_period_s
        if c.attack_pattern[i % len(c.attack_pattern)] == "high":
            # the crouch is recognised about 0.35 s before the blade arrives (impact ~1.75 s in)
            segs.append(Segment(round(t_attack + 1.4 - crouch_end, 2), "crouch"))
            segs.append(Segment(round(t_attack + 2.8, 2), "strike"))
        else:
            # the step lands about 1.1 s after the wind-up starts, well before the fireball arrives
            segs.append(Segment(round(t_attack + 1.1 - step_end, 2), steps[(i // 2) % 2]))
            segs.append(Segment(round(t_attack + 2.05, 2), "fire_ring"))
    end = segs[-1].start_s + 3.5
    return segs, round(end, 2)


#: The bundled round scripts: name -> round kind.
ROUNDS: dict[str, str] = {"round_win": "win", "round_lose": "lose"}


def write_rounds() -> dict[str, tuple[Label, ...]]:
    """Regenerate the bundled round scripts; returns their labels."""
    out = {}
    for name, kind in ROUNDS.items():
        segs, duration = round_segments(kind)
        doc, labels = compose(segs, duration, name)
        what = ("transform, duck the high attack and strike back, side-step the sideways attack and "
                "throw a fire ring: the opponent is knocked out" if kind == "win"
                else "transform, then stand still and take every hit")
        header = (f"# Whole round, {kind}: {what}.\n"
                  "# Generated by `python -m game_client.compose` from the single-gesture scripts in this folder\n"
                  "# (timed against the default GameConfig attack schedule); edit those, not this file.\n"
                  "# Ground truth: labels.toml.\n")
        (SCRIPTS_DIR / f"{name}.toml").write_text(header + dump_script(doc), encoding="utf-8")
        out[name] = labels
    return out


if __name__ == "__main__":  # pragma: no cover - maintenance entry point
    for name, labels in write_rounds().items():
        items = ", ".join(
            "{ " + f'gesture = "{lb.gesture}", end_s = {lb.end_s:g}'
            + (f', direction = "{lb.direction}"' if lb.direction else "") + " }" for lb in labels)
        print(f"[{name}]\ngestures = [{items}]\n")
