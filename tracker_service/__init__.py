"""The tracker service: from camera frames to 3D poses published over Zenoh (Okada & Stenger's
tree-based filter), plus the replay publisher and the evaluation tools.

The data path reads as the folder tree: ``sources`` (frames in) -> ``silhouette`` (background,
features, distances, placement) -> ``cues`` (skin, shoes, appearance) -> ``estimators`` (the estimator
interface and the tree filter over ``templates``) -> ``pipeline`` (observe, estimate, publish; phases;
body selection) -> ``app`` (commands, daemon). ``body``, ``build`` and ``scene`` hold the body models,
the offline builds and the synthetic scene.

The public Python API is :class:`Tracker` (imported lazily: ``python -m tracker_service`` starts
without loading numpy).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from tracker_service.api import Tracker

__all__ = ["Tracker"]


def __getattr__(name: str) -> Any:
    if name == "Tracker":
        from tracker_service.api import Tracker

        return Tracker
    raise AttributeError(f"module 'tracker_service' has no attribute {name!r}")
