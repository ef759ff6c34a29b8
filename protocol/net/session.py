"""Build a ``zenoh.Config`` from command-line options and open sessions safely.

Defaults (no options given)
---------------------------
* ``mode`` = ``peer``;
* multicast scouting **off** (``scouting/multicast/enabled = false``), so nothing is discovered on
  the LAN by accident;
* shared memory **off** (``transport/shared_memory/enabled = false``): in eclipse-zenoh 1.6.2-1.10.2
  a process keeps every shared-memory pool a peer on the same host ever sent through, mapped and
  locked, after that peer is gone (16 MiB + 1.25 MiB for each new session sending messages of
  3 KB or more: +19 MB a session, upstream eclipse-zenoh/zenoh#2787), and where it may not lock
  that much memory (a user's default 8 MiB limit) it drops those messages without a word. Loopback
  TCP carries them instead;
* loopback only: a *publisher* listens on :data:`protocol.wire.keys.DEFAULT_ENDPOINT`
  (``tcp/127.0.0.1:7447``); a *subscriber* connects to it and listens on ``tcp/127.0.0.1:0``
  (an ephemeral loopback port, so peers can still reach each other via gossip).

In ``client`` mode (a LAN with a router, see ``docs/DEPLOY.md``) both roles get the subscriber's
defaults: connect to ``DEFAULT_ENDPOINT`` and listen on ``tcp/127.0.0.1:0``, so a publisher in client
mode never takes the router's port.

``--listen`` / ``--connect`` replace the role's default endpoints (both may be repeated).
``--config FILE`` loads a zenoh JSON5 configuration first; whatever the file sets wins over the
defaults above, and explicit ``--mode/--connect/--listen`` options win over the file.

Zenoh trap (eclipse-zenoh 1.10, measured)
-----------------------------------------
A process that still has a *callback* subscriber or queryable declared when the interpreter exits
hangs forever (a non-daemon thread holds the Python closure). Always use
``with open_session(...) as session:`` (or ``with zenoh.open(conf)``) and undeclare callback
entities in ``finally`` (:func:`undeclare_quietly`). Channel-handler subscribers (no callback) and
closed sessions do not hang.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import re
import signal
import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Final, Literal

import zenoh

from protocol.wire.keys import DEFAULT_ENDPOINT

__all__ = [
    "LOOPBACK_EPHEMERAL",
    "Role",
    "add_zenoh_args",
    "build_config",
    "config_from_args",
    "free_tcp_endpoint",
    "open_session",
    "stop_on_signals",
    "undeclare_quietly",
]

log = logging.getLogger(__name__)

Role = Literal["publisher", "subscriber"]
#: Listen endpoint of a subscriber by default: loopback, any free port.
LOOPBACK_EPHEMERAL: Final[str] = "tcp/127.0.0.1:0"
_MODES: Final[tuple[str, ...]] = ("peer", "client", "router")


def _insert(conf: zenoh.Config, key: str, value: Any) -> None:
    try:
        conf.insert_json5(key, json.dumps(value))
    except zenoh.ZError as exc:
        raise ValueError(f"invalid zenoh setting {key} = {json.dumps(value)}: {exc}") from exc


def _mentions(path: Path, name: str) -> bool:
    """True if the JSON5 file ``path`` names the key ``name`` outside its comments."""
    text = re.sub(r"/\*.*?\*/", "", path.read_text(errors="replace"), flags=re.S)
    return any(re.search(rf"\b{re.escape(name)}\b", line.split("//")[0]) for line in text.splitlines())


def _untouched(conf: zenoh.Config, key: str) -> bool:
    """True if ``key`` still holds zenoh's built-in default (i.e. no config file set it)."""
    return bool(conf.get_json(key) == zenoh.Config().get_json(key))


def build_config(
    role: Role = "subscriber",
    *,
    mode: str | None = None,
    connect: list[str] | None = None,
    listen: list[str] | None = None,
    config_file: str | Path | None = None,
) -> zenoh.Config:
    """Make the session configuration for one process.

    Parameters
    ----------
    role : {"publisher", "subscriber"}
        Chooses the default endpoints: a publisher listens on ``DEFAULT_ENDPOINT``, a subscriber
        connects to it (and listens on ``tcp/127.0.0.1:0``). In ``client`` mode a publisher gets the
        subscriber's defaults.
    mode : {"peer", "client", "router"}, optional
        Zenoh session mode; default ``peer`` (unless the config file sets one).
    connect, listen : list of str, optional
        Endpoints such as ``tcp/127.0.0.1:7447``; each replaces the role's default when given.
    config_file : str or Path, optional
        Zenoh JSON5 configuration file applied before everything else.

    Returns
    -------
    zenoh.Config

    Raises
    ------
    FileNotFoundError
        If ``config_file`` does not exist.
    ValueError
        On an unknown role or mode, a malformed endpoint, or a config file zenoh rejects.
    """
    if role not in ("publisher", "subscriber"):
        raise ValueError(f"role must be 'publisher' or 'subscriber', got {role!r}")
    if mode is not None and mode not in _MODES:
        raise ValueError(f"mode must be one of {', '.join(_MODES)}, got {mode!r}")
    if config_file is not None:
        path = Path(config_file)
        if not path.is_file():
            raise FileNotFoundError(f"zenoh config file not found: {path}")
        try:
            conf = zenoh.Config.from_file(str(path))
        except zenoh.ZError as exc:
            raise ValueError(f"zenoh rejected config file {path}: {exc}") from exc
    else:
        conf = zenoh.Config()

    if mode is not None or _untouched(conf, "mode"):
        _insert(conf, "mode", mode or "peer")
    if _untouched(conf, "scouting/multicast/enabled"):
        _insert(conf, "scouting/multicast/enabled", False)
    # zenoh's default is an explicit true, so whether the file sets it is read from the file itself
    if config_file is None or not _mentions(Path(config_file), "shared_memory"):  # see the module docstring
        _insert(conf, "transport/shared_memory/enabled", False)

    # A client never serves others: whatever its role, it connects (to a router) and listens only on an
    # ephemeral loopback port, so a tracker in client mode does not take the router's port 7447.
    serves = role == "publisher" and json.loads(conf.get_json("mode")) != "client"
    default_listen = [DEFAULT_ENDPOINT] if serves else [LOOPBACK_EPHEMERAL]
    default_connect = [] if serves else [DEFAULT_ENDPOINT]
    if listen is not None:
        _insert(conf, "listen/endpoints", list(listen))
    elif _untouched(conf, "listen/endpoints"):
        _insert(conf, "listen/endpoints", default_listen)
    if connect is not None:
        _insert(conf, "connect/endpoints", list(connect))
    elif _untouched(conf, "connect/endpoints"):
        _insert(conf, "connect/endpoints", default_connect)
    log.debug(
        "zenoh config (%s): mode=%s listen=%s connect=%s multicast=%s",
        role,
        conf.get_json("mode"),
        conf.get_json("listen/endpoints"),
        conf.get_json("connect/endpoints"),
        conf.get_json("scouting/multicast/enabled"),
    )
    return conf


def add_zenoh_args(parser: argparse.ArgumentParser, role: Role) -> None:
    """Add ``--mode``, ``--connect``, ``--listen`` and ``--config`` to ``parser``.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        Parser (or sub-parser) to extend; the role is stored as ``args.zenoh_role``.
    role : {"publisher", "subscriber"}
        Which default endpoints :func:`config_from_args` applies.
    """
    if role == "publisher":
        where = f"by default listens on {DEFAULT_ENDPOINT} (loopback only)"
    else:
        where = f"by default connects to {DEFAULT_ENDPOINT} (loopback only)"
    group = parser.add_argument_group(
        "zenoh network", f"Peer mode, multicast scouting off; this process {where}."
    )
    group.add_argument("--mode", choices=_MODES, default=None,
                       help="zenoh session mode (default: peer)")
    group.add_argument("--connect", metavar="ENDPOINT", action="append", default=None,
                       help="endpoint to connect to, e.g. tcp/192.168.1.20:7447 (repeatable; "
                            "replaces the default)")
    group.add_argument("--listen", metavar="ENDPOINT", action="append", default=None,
                       help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 to accept other machines "
                            "(repeatable; replaces the default)")
    group.add_argument("--config", metavar="FILE", default=None,
                       help="zenoh JSON5 config file; its settings win over the defaults, "
                            "--mode/--connect/--listen win over it")
    parser.set_defaults(zenoh_role=role)


def config_from_args(args: argparse.Namespace, role: Role | None = None) -> zenoh.Config:
    """:func:`build_config` from options added by :func:`add_zenoh_args`.

    Parameters
    ----------
    args : argparse.Namespace
    role : {"publisher", "subscriber"}, optional
        Overrides the role recorded by :func:`add_zenoh_args`.

    Returns
    -------
    zenoh.Config
    """
    chosen = role or getattr(args, "zenoh_role", None) or "subscriber"
    if chosen not in ("publisher", "subscriber"):
        raise ValueError(f"role must be 'publisher' or 'subscriber', got {chosen!r}")
    return build_config(
        "publisher" if chosen == "publisher" else "subscriber",
        mode=getattr(args, "mode", None),
        connect=getattr(args, "connect", None),
        listen=getattr(args, "listen", None),
        config_file=getattr(args, "config", None),
    )


@contextmanager
def open_session(args_or_config: zenoh.Config | argparse.Namespace) -> Iterator[zenoh.Session]:
    """Open a zenoh session and close it on exit (which also undeclares its entities).

    Parameters
    ----------
    args_or_config : zenoh.Config or argparse.Namespace
        A ready configuration, or parsed options from :func:`add_zenoh_args`.

    Yields
    ------
    zenoh.Session

    Raises
    ------
    ConnectionError
        If zenoh cannot open the session (e.g. the listen port is already in use).
    """
    conf = args_or_config if isinstance(args_or_config, zenoh.Config) else config_from_args(args_or_config)
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        raise ConnectionError(f"cannot open zenoh session: {exc}") from exc
    with session:
        yield session


def undeclare_quietly(*entities: Any) -> None:
    """Undeclare zenoh subscribers, queryables, publishers or tokens; ``None`` entries are skipped.

    Errors (e.g. the session is already closed) are logged at debug level, never raised, so this is
    safe in ``finally`` blocks.
    """
    for entity in entities:
        if entity is None:
            continue
        try:
            entity.undeclare()
        except Exception as exc:  # zenoh raises ZError for already-closed sessions
            log.debug("undeclare %r failed: %s", entity, exc)


def free_tcp_endpoint(host: str = "127.0.0.1") -> str:
    """A ``tcp/<host>:<port>`` endpoint on a port that was free a moment ago.

    The port is found by binding port 0 and closing the socket, so another process could take it
    before zenoh binds it; good enough for tests and demos on loopback.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        port = sock.getsockname()[1]
    return f"tcp/{host}:{port}"


def _watch(read_fd: int, stop: threading.Event) -> None:
    """Turn bytes written by the signal handler into ``stop.set()`` on an ordinary thread."""
    while True:
        try:
            data = os.read(read_fd, 16)
        except OSError:
            return
        if not data:  # write end closed: the context has exited
            return
        for signum in data:
            log.info("received %s, shutting down", signal.Signals(signum).name)
        stop.set()


@contextmanager
def stop_on_signals(
    stop: threading.Event, signals: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM)
) -> Iterator[threading.Event]:
    """Set ``stop`` when one of ``signals`` arrives (instead of raising ``KeyboardInterrupt``).

    The Python-level handler only writes the signal number to a pipe; a daemon thread reads it,
    logs it and sets ``stop``. Calling ``Event.set()`` (or logging) inside the handler itself could
    deadlock: the handler runs on the main thread, which may at that moment hold the event's
    non-reentrant lock inside ``stop.wait()``. The previous handlers are restored on exit. Outside
    the main thread (where Python cannot install signal handlers) this only yields ``stop``.

    Parameters
    ----------
    stop : threading.Event
        Event the process's loops wait on.
    signals : tuple of signal.Signals
        Default SIGINT and SIGTERM.

    Yields
    ------
    threading.Event
        ``stop``.
    """
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)

    def handler(signum: int, _frame: object) -> None:
        try:
            os.write(write_fd, bytes([signum]))
        except OSError:  # pipe full (signal storm) or already closed: stop is on its way anyway
            pass

    watcher = threading.Thread(target=_watch, args=(read_fd, stop), name="stop-on-signals", daemon=True)
    watcher.start()
    previous = {sig: signal.signal(sig, handler) for sig in signals}
    try:
        yield stop
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
        os.close(write_fd)
        watcher.join(timeout=1.0)
        os.close(read_fd)
