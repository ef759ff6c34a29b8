"""Which tracker a client follows when told to follow whichever is alive (``--follow``): the first
tracker whose liveliness token appeared (of those found together, the first by id, so that clients
started beside each other follow the same one), and when it stops or dies, the next one still alive.

Pure bookkeeping over liveliness samples (``mocap/tracker/<id>/alive``, ``PUT`` when a tracker
appears, ``DELETE`` when it goes); the apps declare the liveliness subscriber (with history, so
trackers already running are seen) and re-subscribe when :meth:`TrackerFollower.on_token` says the
choice changed.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

from protocol.wire.keys import ALL_ALIVE, split_key

__all__ = ["TrackerFollower", "alive_keys", "follow_step"]

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
        return self.on_tokens([(key, alive)])

    def on_tokens(self, samples: list[tuple[str, bool]]) -> bool:
        """Take the liveliness samples that arrived together; trackers that appear in the same
        batch are ordered by id, so that every client started beside them follows the same one.
        True when the followed tracker changed."""
        new: list[str] = []
        for key, alive in samples:
            try:
                parts = split_key(key)
            except ValueError:
                continue
            if parts.domain != "tracker" or parts.leaf != "alive":
                continue
            if alive:
                if parts.id not in self.alive and parts.id not in new:
                    new.append(parts.id)
            else:
                self.alive.pop(parts.id, None)
                new = [n for n in new if n != parts.id]
        for tid in sorted(new):
            self.alive[tid] = self._seen
            self._seen += 1
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


def alive_keys(session: Any, timeout: float = 0.5) -> list[str]:
    """Ask the network which trackers are alive (a liveliness ``get``): the key of every token
    that answered within ``timeout`` seconds."""
    return [str(r.ok.key_expr) for r in session.liveliness().get(ALL_ALIVE, timeout=timeout) if r.ok is not None]


def follow_step(session: Any, live_sub: Any, follower: TrackerFollower, asked_at: float, now: float,
                ask_every_s: float = 1.0) -> tuple[bool, float]:
    """One poll of a following client: take the liveliness samples waiting on ``live_sub`` and,
    while nobody is followed, ask the network too.

    While nobody is followed, the choice is never made from the subscriber's samples alone: its
    history arrives as the connection forms and can bring the trackers already running one at a
    time, so a client would follow whichever came first over the wire rather than the first by
    id. Whenever samples arrive (or at most every ``ask_every_s`` seconds) the network is asked
    (a liveliness ``get``, which waits for every answer) and its answers join the same batch; when
    it answers nothing in time, the samples wait for the next answer (the tokens they announce
    are in it).

    Returns
    -------
    changed : bool
        The followed tracker changed (re-subscribe to ``follower.current``).
    asked_at : float
        When the network was last asked (``now`` if it was asked now).
    """
    import zenoh

    batch = []
    while (tok := live_sub.try_recv()) is not None:
        batch.append((str(tok.key_expr), tok.kind == zenoh.SampleKind.PUT))
    if follower.current is None and (batch or now - asked_at >= ask_every_s):
        asked_at = now
        answers = alive_keys(session)
        if not answers:
            # no answer in time (a loaded machine, a slow router): the history alone may hold the
            # trackers one at a time, so wait for the next answer, which holds every token alive
            return False, asked_at
        batch += [(k, True) for k in answers]
    changed = follower.on_tokens(batch) if batch else False
    return changed, asked_at
