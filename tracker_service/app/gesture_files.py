"""The gesture-script files a build adds to the recordings (the game's and protocol's bundled scripts)."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = ["gesture_scripts"]


def gesture_scripts(dirs: Sequence[str]) -> list[Path]:
    """The gesture scripts (``*.toml`` with ``[[key]]`` tables) in the given folders; other TOML
    files there (e.g. a game's label file) are skipped with a note."""
    import tomllib

    out = []
    for p in sorted(q for d in dirs for q in Path(d).glob("*.toml")):
        try:
            doc = tomllib.loads(p.read_text())
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
            out.append(p)  # let the script reader report it with file and line
            continue
        if "key" in doc:
            out.append(p)
        else:
            print(f"{p} has no [[key]] tables: not a gesture script, skipped", file=sys.stderr)
    return out
