"""Where the tracker keeps what it makes: the checkout's ``out/`` folder, or a user cache directory.

Databases, rendered training views and other rebuildable caches go under :func:`out_dir`: ``<repo>/out``
when the package runs from a checkout (a ``pyproject.toml`` beside the package), otherwise
``$MOCAP_CACHE`` or ``$XDG_CACHE_HOME/mocap-service`` (``~/.cache/mocap-service``), so that an installed
wheel never writes into ``site-packages``. Models the product needs ship inside the package instead.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["PACKAGE_DIR", "REPO_ROOT", "out_dir"]

#: The ``tracker_service`` package folder.
PACKAGE_DIR = Path(__file__).resolve().parent
#: The folder holding the packages (a checkout's root, or ``site-packages`` when installed).
REPO_ROOT = PACKAGE_DIR.parent


def out_dir() -> Path:
    """The folder for rebuildable caches (databases, rendered views, videos).

    Returns
    -------
    Path
        ``$MOCAP_CACHE`` when set; ``<checkout>/out`` when running from a checkout; else the user
        cache directory ``$XDG_CACHE_HOME/mocap-service`` (default ``~/.cache/mocap-service``).
    """
    if env := os.environ.get("MOCAP_CACHE"):
        return Path(env)
    if (REPO_ROOT / "pyproject.toml").is_file():
        return REPO_ROOT / "out"
    cache = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(cache) / "mocap-service"
