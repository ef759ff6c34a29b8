"""Which tracker a client follows when told to follow whichever is alive (``--follow``): the first
tracker whose liveliness token appeared, and when it stops or dies, the next one still alive.

Pure bookkeeping over liveliness samples (``mocap/tracker/<id>/alive``, ``PUT`` when a tracker
appears, ``DELETE`` when it goes); the apps declare the liveliness subscriber (with history, so
trackers already running are seen) and re-subscribe when :meth:`TrackerFollower.on_token` says the
choice changed.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

from protocol.wire.keys import split_key

__all__ = ["TrackerFollower"]

log = logging.getLogger(__name__)


@dataclass
class TrackerFollower:
    """The trackers alive, in the order they appeared, and the one followed.

    Attributes
    ----------
    alive : dict[str, int]
        Tracker id -> the order its token appeared in.
    current : str or None
        The tracker followed (None while no tracker is alive).
    switches : int
        How many times the followed tracker changed after the first.
    """

    alive: dict[str, int] = field(default_factory=dict)
    current: str | None = None
    switches: int = 0
    _seen: int = 0

    def on_token(self, key: str, alive: bool) -> bool:
        """Take one liveliness sample (``key``: ``mocap/tracker/<id>/alive``); True when the
        followed tracker changed. Keys that are not a tracker's token are ignored."""
        try:
            parts = split_key(key)
        except ValueError:
            return False
        if parts.domain != "tracker" or parts.leaf != "alive":
            return False
        if alive:
            if parts.id not in self.alive:
                self.alive[parts.id] = self._seen
                self._seen += 1
        else:
            self.alive.pop(parts.id, None)
        if self.current is not None and self.current in self.alive:
            return False
        first = min(self.alive, key=self.alive.__getitem__) if self.alive else None
        if first == self.current:
            return False
        if self.current is not None and first is not None:
            self.switches += 1
            log.warning("tracker %r is gone: following %r", self.current, first)
        elif first is not None:
            log.info("following tracker %r", first)
        self.current = first
        return True
