"""Zenoh key expressions used by every process, and tracker-id validation.

Layout
------
::

    mocap/tracker/<id>/pose     PoseFrame, one per tracked frame            (publisher)
    mocap/tracker/<id>/body     BodyInfo, on start and on every ``get``     (publisher + queryable)
    mocap/tracker/<id>/status   TrackerStatus, about once per second        (publisher)
    mocap/tracker/<id>/alive    liveliness token while the tracker runs
    mocap/tracker/<id>/preview  PreviewFrame (JPEG of the overlay) while a viewer subscribes
    mocap/game/<id>/event       game events                                 (game client)
    mocap/game/<id>/state       game state                                  (game client)
    mocap/cloth/<id>/mesh       cloth mesh                                  (cloth client)

``<id>`` is one key chunk matching ``^[A-Za-z0-9_-]{1,64}$`` (see :func:`validate_id`). Subscribers
may pass :data:`ANY` (``"*"``) instead of an id to match every tracker, e.g. ``pose_key(ANY) ==
"mocap/tracker/*/pose"`` (also available as :data:`ALL_POSES`).

This module has no dependency on zenoh; the strings are plain key expressions.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Final

__all__ = [
    "ALL_ALIVE",
    "ALL_BODIES",
    "ALL_POSES",
    "ALL_STATUS",
    "ANY",
    "DEFAULT_ENDPOINT",
    "DEFAULT_TRACKER_ID",
    "PREFIX",
    "KeyParts",
    "alive_key",
    "body_key",
    "cloth_mesh_key",
    "game_event_key",
    "game_state_key",
    "pose_key",
    "preview_key",
    "split_key",
    "status_key",
    "validate_id",
]

#: First chunk of every key this project uses.
PREFIX: Final[str] = "mocap"
#: Where a publisher listens and a subscriber connects unless told otherwise (loopback only).
DEFAULT_ENDPOINT: Final[str] = "tcp/127.0.0.1:7447"
#: Tracker id used when none is given on the command line.
DEFAULT_TRACKER_ID: Final[str] = "default"
#: Single-chunk wildcard accepted by the key builders in place of an id (subscribers only).
ANY: Final[str] = "*"

_ID_RE: Final[re.Pattern[str]] = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_TRACKER_LEAVES: Final[frozenset[str]] = frozenset({"pose", "body", "status", "alive", "preview"})
_GAME_LEAVES: Final[frozenset[str]] = frozenset({"event", "state"})
_CLOTH_LEAVES: Final[frozenset[str]] = frozenset({"mesh"})
_DOMAINS: Final[dict[str, frozenset[str]]] = {
    "tracker": _TRACKER_LEAVES,
    "game": _GAME_LEAVES,
    "cloth": _CLOTH_LEAVES,
}


def validate_id(tracker_id: str, *, allow_any: bool = False) -> str:
    """Check that ``tracker_id`` can be used as one key chunk and return it unchanged.

    Parameters
    ----------
    tracker_id : str
        Letters, digits, ``_`` and ``-``; 1 to 64 characters.
    allow_any : bool
        Also accept :data:`ANY` (``"*"``), the wildcard that matches every id (for subscribers).

    Returns
    -------
    str
        ``tracker_id``.

    Raises
    ------
    ValueError
        If the id is empty, too long, or contains any other character (``/``, ``*``, spaces, ...).
    """
    if allow_any and tracker_id == ANY:
        return tracker_id
    if not isinstance(tracker_id, str):
        raise ValueError(f"id must be a string, got {type(tracker_id).__name__}")
    if _ID_RE.fullmatch(tracker_id) is None:
        what = "empty" if tracker_id == "" else f"{tracker_id!r}"
        raise ValueError(
            f"invalid id {what}: use 1-64 characters from A-Z, a-z, 0-9, '_' and '-'"
            + (" (or '*' for any)" if allow_any else "")
        )
    return tracker_id


def _key(domain: str, tracker_id: str, leaf: str) -> str:
    validate_id(tracker_id, allow_any=True)
    return f"{PREFIX}/{domain}/{tracker_id}/{leaf}"


def pose_key(tracker_id: str) -> str:
    """``mocap/tracker/<id>/pose``: where :class:`~protocol.wire.messages.PoseFrame` messages go."""
    return _key("tracker", tracker_id, "pose")


def body_key(tracker_id: str) -> str:
    """``mocap/tracker/<id>/body``: :class:`~protocol.wire.messages.BodyInfo` (published and queryable)."""
    return _key("tracker", tracker_id, "body")


def status_key(tracker_id: str) -> str:
    """``mocap/tracker/<id>/status``: periodic :class:`~protocol.wire.messages.TrackerStatus`."""
    return _key("tracker", tracker_id, "status")


def alive_key(tracker_id: str) -> str:
    """``mocap/tracker/<id>/alive``: the tracker's liveliness token."""
    return _key("tracker", tracker_id, "alive")


def preview_key(tracker_id: str) -> str:
    """``mocap/tracker/<id>/preview``: :class:`~protocol.wire.media.PreviewFrame` (the camera frame
    with the overlay, JPEG), published only while somebody subscribes."""
    return _key("tracker", tracker_id, "preview")


def game_event_key(game_id: str) -> str:
    """``mocap/game/<id>/event``: events emitted by a game client."""
    return _key("game", game_id, "event")


def game_state_key(game_id: str) -> str:
    """``mocap/game/<id>/state``: state snapshots of a game client."""
    return _key("game", game_id, "state")


def cloth_mesh_key(cloth_id: str) -> str:
    """``mocap/cloth/<id>/mesh``: meshes published by a cloth client."""
    return _key("cloth", cloth_id, "mesh")


#: ``mocap/tracker/*/pose``: every tracker's poses.
ALL_POSES: Final[str] = pose_key(ANY)
#: ``mocap/tracker/*/body``: every tracker's body description.
ALL_BODIES: Final[str] = body_key(ANY)
#: ``mocap/tracker/*/status``: every tracker's status.
ALL_STATUS: Final[str] = status_key(ANY)
#: ``mocap/tracker/*/alive``: every tracker's liveliness token.
ALL_ALIVE: Final[str] = alive_key(ANY)


@dataclass(frozen=True)
class KeyParts:
    """A concrete key split into its parts, e.g. ``("tracker", "cam0", "pose")``.

    Attributes
    ----------
    domain : str
        ``"tracker"``, ``"game"`` or ``"cloth"``.
    id : str
        The tracker / game / cloth id.
    leaf : str
        ``"pose"``, ``"body"``, ``"status"``, ``"alive"``, ``"preview"``, ``"event"``, ``"state"`` or
        ``"mesh"``.
    """

    domain: str
    id: str
    leaf: str


def split_key(key: str) -> KeyParts:
    """Parse a concrete key such as a received sample's ``str(sample.key_expr)``.

    Parameters
    ----------
    key : str
        ``mocap/<domain>/<id>/<leaf>`` with a valid id (no wildcards).

    Returns
    -------
    KeyParts

    Raises
    ------
    ValueError
        If the key is not one of the layouts listed in this module.
    """
    chunks = str(key).split("/")
    if len(chunks) != 4 or chunks[0] != PREFIX or chunks[1] not in _DOMAINS:
        raise ValueError(f"not a {PREFIX} key: {key!r}")
    _, domain, ident, leaf = chunks
    if leaf not in _DOMAINS[domain]:
        raise ValueError(f"unknown {domain} key leaf {leaf!r} in {key!r}")
    validate_id(ident)
    return KeyParts(domain=domain, id=ident, leaf=leaf)
