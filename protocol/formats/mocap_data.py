"""Locate the shared motion-capture recordings and read their index (``INDEX.tsv``).

The recordings (BVH files from the Bandai Namco Research Motion Dataset and the CMU database)
live outside the repository, in a folder shared between checkouts::

    $MOCAP_DATA                      if the environment variable is set, else
    <repo root>/../shared/mocap      where <repo root> is the folder holding ``protocol/``

The location is computed from this file, never from the working directory, so commands behave the
same wherever they are started. ``INDEX.tsv`` lists every file with the columns ``path source
subject motion tags frames fps joints licence`` (tab-separated, one header line); see the folder's
``README.md`` for the skeletons, units and known quirks of each source, and ``LICENSE.md`` for the
terms (the ``bandai/`` files are CC BY-NC 4.0, non-commercial only).
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Final

__all__ = [
    "ENV_VAR",
    "INDEX_NAME",
    "IndexEntry",
    "index_entries",
    "mocap_root",
    "recording_path",
]

#: Environment variable that overrides the recordings folder.
ENV_VAR: Final[str] = "MOCAP_DATA"
#: Name of the index file inside the recordings folder.
INDEX_NAME: Final[str] = "INDEX.tsv"
_COLUMNS: Final[tuple[str, ...]] = (
    "path", "source", "subject", "motion", "tags", "frames", "fps", "joints", "licence",
)


def _default_root() -> Path:
    return Path(__file__).resolve().parents[2].parent / "shared" / "mocap"


def mocap_root() -> Path:
    """The shared recordings folder.

    Returns
    -------
    Path
        ``$MOCAP_DATA`` if set, else ``<repo root>/../shared/mocap`` (resolved, absolute).

    Raises
    ------
    FileNotFoundError
        If the chosen folder does not exist; the message names both places and the variable.
    """
    default = _default_root()
    env = os.environ.get(ENV_VAR, "").strip()
    root = Path(env).expanduser() if env else default
    if root.is_dir():
        return root.resolve()
    where = f"{ENV_VAR}={env!r} (does not exist)" if env else f"{ENV_VAR} is not set"
    raise FileNotFoundError(
        f"motion-capture recordings not found: {where}; default location {default} "
        f"{'is not a folder' if not default.is_dir() else 'exists but was not used'}. "
        f"Set {ENV_VAR} to the folder that holds {INDEX_NAME}."
    )


@dataclass(frozen=True)
class IndexEntry:
    """One row of ``INDEX.tsv``.

    Attributes
    ----------
    path : str
        File path relative to :func:`mocap_root`, e.g. ``"bandai/dataset-1_bow_normal_001.bvh"``.
    source : str
        Upstream repository and path the file came from.
    subject : str
        Performer / style description.
    motion : str
        What the motion shows (measured with forward kinematics where stated).
    tags : tuple of str
        Gesture tags such as ``"wave"``, ``"point"``, ``"crouch"``, ``"other"``.
    frames : int
        Number of frames.
    fps : float
        Frame rate stamped in the file (see the README for files whose stamp is wrong).
    joints : int
        Number of joints in the file's skeleton.
    licence : str
        Licence of the recording.
    """

    path: str
    source: str
    subject: str
    motion: str
    tags: tuple[str, ...]
    frames: int
    fps: float
    joints: int
    licence: str

    @property
    def duration(self) -> float:
        """Length in seconds at the stamped frame rate."""
        return self.frames / self.fps if self.fps > 0 else 0.0

    def absolute(self, root: Path | None = None) -> Path:
        """Absolute path of the file (``root`` defaults to :func:`mocap_root`)."""
        return (root if root is not None else mocap_root()) / self.path


def _parse_row(row: dict[str, str], line: int, index: Path) -> IndexEntry:
    try:
        return IndexEntry(
            path=row["path"].strip(),
            source=row["source"].strip(),
            subject=row["subject"].strip(),
            motion=row["motion"].strip(),
            tags=tuple(t.strip() for t in row["tags"].split(",") if t.strip()),
            frames=int(row["frames"]),
            fps=float(row["fps"]),
            joints=int(row["joints"]),
            licence=row["licence"].strip(),
        )
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{index}:{line}: malformed index row ({exc})") from exc


def index_entries(root: Path | None = None) -> list[IndexEntry]:
    """Read ``INDEX.tsv`` of the recordings folder.

    Parameters
    ----------
    root : Path, optional
        Recordings folder (default :func:`mocap_root`).

    Returns
    -------
    list of IndexEntry
        In file order.

    Raises
    ------
    FileNotFoundError
        If the folder or its index is missing.
    ValueError
        If the header lacks a column or a row cannot be parsed.
    """
    base = root if root is not None else mocap_root()
    index = base / INDEX_NAME
    if not index.is_file():
        raise FileNotFoundError(f"index file not found: {index}")
    with index.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh, delimiter="\t", quoting=csv.QUOTE_NONE)
        missing = [c for c in _COLUMNS if c not in (reader.fieldnames or ())]
        if missing:
            raise ValueError(f"{index}: missing column(s) {', '.join(missing)}")
        return [_parse_row(row, n, index) for n, row in enumerate(reader, start=2)]


def recording_path(rel: str | Path, root: Path | None = None) -> Path:
    """Absolute path of a recording given relative to the recordings folder.

    Parameters
    ----------
    rel : str or Path
        E.g. ``"bandai/dataset-2_raise-up-both-hands_normal_001.bvh"``.
    root : Path, optional
        Recordings folder (default :func:`mocap_root`).

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        If ``rel`` is absolute or points outside the folder.
    FileNotFoundError
        If the file does not exist.
    """
    base = (root if root is not None else mocap_root()).resolve()
    rel_path = Path(rel)
    if rel_path.is_absolute():
        raise ValueError(f"recording path must be relative to {base}, got {rel_path}")
    path = (base / rel_path).resolve()
    if not path.is_relative_to(base):
        raise ValueError(f"recording path {rel_path} points outside {base}")
    if not path.is_file():
        raise FileNotFoundError(f"recording not found: {path}")
    return path
