"""The gesture-script files a build adds to the recordings (the game's and protocol's bundled scripts)."""

from __future__ import annotations

import hashlib
import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = ["gesture_scripts", "scripts_digest"]


def gesture_scripts(dirs: Sequence[str], quiet: bool = False) -> list[Path]:
    """The gesture scripts (``*.toml`` with ``[[key]]`` tables) in the given folders; other TOML
    files there (e.g. a game's label file) are skipped with a note (none when ``quiet``)."""
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
        elif not quiet:
            print(f"{p} has no [[key]] tables: not a gesture script, skipped", file=sys.stderr)
    return out


def scripts_digest(dirs: Sequence[str]) -> str:
    """SHA-256 (hex) of the ``*.toml`` files in the given folders: their names and contents, in name
    order. A database records it to tell when the bundled scripts it was built from have changed."""
    h = hashlib.sha256()
    for p in sorted((q for d in dirs for q in Path(d).glob("*.toml")), key=lambda q: (q.parent.name, q.name)):
        h.update(f"{p.parent.name}/{p.name}\0".encode())
        try:
            h.update(p.read_bytes())
        except OSError:
            h.update(b"\0unreadable")
        h.update(b"\0")
    return h.hexdigest()
