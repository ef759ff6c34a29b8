"""The shipped appearance network's provenance: a model card beside the weights.

``python -m tracker_service.build.model_card NET.npz --version N --command "..."`` writes a trained
network file into the package, its weights in float16 (``tracker_service/cues/models/appearance-vN.npz``) and writes its
card (``appearance-vN.json``): the training command, a digest of the training data (the recordings'
index and every gesture script), the validation figures the training reported, the file's sha256,
and a *probe*: the network's outputs on a fixed pseudo-random input, so that a test can hold the
shipped file to what was measured when it was made (:func:`probe_input`, :func:`check_card`).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tracker_service.cues.appearance import AppearanceNet, forward, load_appearance, save_appearance
from tracker_service.paths import PACKAGE_DIR

__all__ = ["MODELS_DIR", "check_card", "model_card", "probe_input"]

#: Where the shipped networks live (package data).
MODELS_DIR = PACKAGE_DIR / "cues" / "models"
#: The probe: this many inputs from :func:`probe_input`.
PROBE_N = 4
PROBE_SEED = 20261206


def sha256(path: Path) -> str:
    """Hex sha256 of a file."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def probe_input(size: int, n: int = PROBE_N, seed: int = PROBE_SEED) -> NDArray[np.float32]:
    """A fixed network input ``(n, size, size, 4)``: a blob of colour in a mask, as the crops are."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:size, :size] / size
    out = np.empty((n, size, size, 4), np.float32)
    for i in range(n):
        cx, cy, rx, ry = rng.uniform(0.35, 0.65), rng.uniform(0.35, 0.65), rng.uniform(0.1, 0.3), rng.uniform(0.3, 0.45)
        m = (((xx - cx) / rx) ** 2 + ((yy - cy) / ry) ** 2 <= 1.0).astype(np.float32)
        colour = rng.uniform(-0.5, 0.5, (size, size, 3)).astype(np.float32)
        out[i, ..., :3] = colour * m[..., None]
        out[i, ..., 3] = m
    return out


def probe_outputs(net: AppearanceNet) -> list[list[list[float]]]:
    """Every member's raw output on :func:`probe_input`, ``[member][n][outputs]``."""
    x = probe_input(net.size)
    return [np.asarray(forward(net, x, k), np.float64).round(6).tolist() for k in range(1 + len(net.members))]


def data_digest(mocap_index: Path, scripts: list[Path]) -> str:
    """sha256 over the recordings' index and the gesture scripts (names and contents)."""
    h = hashlib.sha256()
    h.update(mocap_index.read_bytes())
    for p in sorted(scripts, key=lambda q: q.name):
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def model_card(net_file: Path, version: int, command: str, data_sha256: str) -> dict[str, Any]:
    """The card of a network file (see the module docstring)."""
    net = load_appearance(net_file)
    members = net.meta.get("members") or [net.meta]
    validation = [{k: m[k] for k in ("samples", "val_rms_x", "val_rms_y", "val_rms_z", "epochs", "width") if k in m}
                  for m in members]
    return {
        "model": "appearance", "version": version, "file": f"appearance-v{version}.npz",
        "sha256": sha256(net_file), "input_size": net.size, "members": 1 + len(net.members),
        "training_command": command, "training_data_sha256": data_sha256,
        "training_takes": net.meta.get("training_takes"), "scripts": len(net.meta.get("scripts", [])),
        "render_s": net.meta.get("render_s"), "train_s": net.meta.get("train_s"),
        "validation": validation,
        "probe": {"seed": PROBE_SEED, "n": PROBE_N, "outputs": probe_outputs(net)},
        "made": time.strftime("%Y-%m-%d"), "machine": f"{platform.machine()}, {platform.python_version()}",
        "licence": "trained on CC BY-NC recordings (Bandai Namco, CMU): non-commercial use",
    }


def check_card(card: dict[str, Any], net_file: Path, atol: float = 1e-4) -> list[str]:
    """What disagrees between a card and its file (empty when they agree)."""
    problems = []
    if sha256(net_file) != card["sha256"]:
        problems.append("sha256 differs")
    net = load_appearance(net_file)
    got = probe_outputs(net)
    want = card["probe"]["outputs"]
    if len(got) != len(want) or any(not np.allclose(g, w, atol=atol) for g, w in zip(got, want, strict=True)):
        problems.append("probe outputs differ")
    members = net.meta.get("members") or [net.meta]
    if len(members) != len(card["validation"]) or any(
            any(m.get(k) != val for k, val in v.items()) for m, v in zip(members, card["validation"], strict=True)):
        problems.append("validation figures differ")
    return problems


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tracker_service.build.model_card",
                                 description="Ship a trained appearance network in the package, with its card.")
    ap.add_argument("net", type=Path, help="a network file made by mocap-tracker train-appearance")
    ap.add_argument("--version", type=int, required=True)
    ap.add_argument("--command", required=True, help="the training command, as run")
    ap.add_argument("--mocap", type=Path, default=None, help="recordings folder (default: the shared one)")
    args = ap.parse_args(argv)
    from protocol.formats.mocap_data import mocap_root
    from tracker_service.app.resources import DEFAULT_SCRIPT_DIRS

    root = args.mocap or mocap_root()
    scripts = [p for d in DEFAULT_SCRIPT_DIRS for p in Path(d).glob("*.toml")]
    dest = MODELS_DIR / f"appearance-v{args.version}.npz"
    dest.parent.mkdir(parents=True, exist_ok=True)
    save_appearance(dest, load_appearance(args.net), half=True)  # float16 weights: half the size
    card = model_card(dest, args.version, args.command, data_digest(root / "INDEX.tsv", scripts))
    dest.with_suffix(".json").write_text(json.dumps(card, indent=1) + "\n")
    print(f"{dest} ({dest.stat().st_size / 1e6:.1f} MB) and its card", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
