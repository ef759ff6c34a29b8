"""``mocap-router``: a Zenoh router for running the tracker, the game and the cloth client on several
machines (see ``docs/DEPLOY.md``).

There is no ``zenohd`` on PyPI, so this is a Python session in ``router`` mode: it accepts client
sessions on its listen endpoints and routes every put, query and liveliness token between them.
Multicast scouting is off (nothing is discovered or announced on the LAN by accident) and, unless
told otherwise, it listens on loopback only (``tcp/127.0.0.1:7447``).

``--config FILE`` loads a Zenoh JSON5 configuration first (TLS, user/password authentication,
access control: samples in ``deploy/``); ``--listen`` replaces the file's listen endpoints; the mode
is always ``router``. The process runs until SIGINT or SIGTERM and then closes its session (exit
status 0). Exit status 1: the session could not be opened (bad config file, port in use, missing
certificate); 2: bad command line.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import threading
from importlib import metadata
from typing import Any

import zenoh

from protocol.net.session import build_config, open_session, stop_on_signals
from protocol.wire.keys import DEFAULT_ENDPOINT

__all__ = ["build_parser", "describe_security", "main", "router_config", "run_router"]

PROG = "mocap-router"
log = logging.getLogger("mocap-router")

_EPILOG = f"""\
Listening on the LAN: the default ({DEFAULT_ENDPOINT}) accepts this machine only. To accept
the other machines, listen on all interfaces or on the LAN address, e.g.
  {PROG} --listen tcp/0.0.0.0:7447
  {PROG} --listen tcp/192.168.1.20:7447
then open TCP port 7447 on this machine's firewall (only here: clients do not listen) and start the
tracker, the game and the cloth client with --mode client --connect tcp/ROUTER_IP:7447.
TLS, user/password authentication and access control: --config FILE with the samples in deploy/
(see docs/DEPLOY.md).
"""


def _version() -> str:
    def of(dist: str) -> str:
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return "unknown"

    return f"{PROG} {of('mocap-service')} (eclipse-zenoh {of('eclipse-zenoh')})"


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``mocap-router``."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Run a Zenoh router (router mode, multicast scouting off) that connects the tracker, "
                    "the game and the cloth client running on several machines in client mode. "
                    "Stops on Ctrl-C or SIGTERM.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--listen", metavar="ENDPOINT", action="append", default=None,
                        help=f"endpoint to accept sessions on (repeatable; default {DEFAULT_ENDPOINT}, "
                             "loopback only; tcp/0.0.0.0:7447 accepts the LAN; tls/... with a TLS "
                             "config file); replaces the config file's listen endpoints")
    parser.add_argument("--config", metavar="FILE", default=None,
                        help="zenoh JSON5 config file (TLS, authentication, access control: see deploy/); "
                             "its settings win over the defaults, --listen wins over it, mode is always router")
    verbosity = parser.add_mutually_exclusive_group()
    verbosity.add_argument("-v", "--verbose", action="store_true",
                           help="debug output, and zenoh's own info messages (RUST_LOG overrides)")
    verbosity.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors on stderr")
    parser.add_argument("--version", action="version", version=_version())
    return parser


def router_config(listen: list[str] | None = None, config_file: str | None = None) -> zenoh.Config:
    """The router's configuration: ``config_file`` (if any), then mode ``router``, multicast scouting
    off unless the file turns it on, ``listen`` (default: the file's endpoints, else
    :data:`~protocol.wire.keys.DEFAULT_ENDPOINT`), and no outgoing connection unless the file has one.

    Raises
    ------
    FileNotFoundError, ValueError
        As :func:`protocol.net.session.build_config`.
    """
    return build_config("publisher", mode="router", listen=listen, config_file=config_file)


def _get(conf: zenoh.Config, key: str) -> Any:
    try:
        return json.loads(conf.get_json(key))
    except (zenoh.ZError, ValueError):
        return None


def describe_security(conf: zenoh.Config) -> list[str]:
    """One line each on the TLS, authentication and access-control settings of ``conf`` (for the log)."""
    lines: list[str] = []
    tls = _get(conf, "transport/link/tls") or {}
    if tls.get("listen_certificate"):
        mtls = "mutual TLS: clients must present a certificate signed by the root CA" if tls.get("enable_mtls") \
            else "server certificate only (no client certificates asked)"
        lines.append(f"TLS: {mtls}")
    usrpwd = (_get(conf, "transport/auth/usrpwd") or {})
    if usrpwd.get("dictionary_file"):
        lines.append(f"user/password authentication: credentials from {usrpwd['dictionary_file']}")
    acl = _get(conf, "access_control") or {}
    if acl.get("enabled"):
        lines.append(f"access control: {len(acl.get('rules') or [])} rules, {len(acl.get('subjects') or [])} "
                     f"subjects, {len(acl.get('policies') or [])} policies, default {acl.get('default_permission')}")
    return lines


def run_router(conf: zenoh.Config, stop: threading.Event) -> None:
    """Open a router session with ``conf``, log its endpoints and keep it open until ``stop`` is set.

    Raises
    ------
    ConnectionError
        If zenoh cannot open the session (port in use, unreadable certificate, ...).
    """
    listen = _get(conf, "listen/endpoints") or []
    with open_session(conf) as session:
        for line in describe_security(conf):
            log.info("%s", line)
        log.info("router %s listening on %s", session.info.zid(), ", ".join(map(str, listen)) or "(nothing)")
        if any(str(ep).split("/", 1)[-1].startswith(("127.", "localhost", "[::1]")) for ep in listen):
            log.info("loopback only: other machines cannot connect (see --help: --listen tcp/0.0.0.0:7447)")
        stop.wait()
        log.info("closing the router session")
    log.info("stopped")


def _init_zenoh_log(level: str) -> None:
    try:
        zenoh.init_log_from_env_or(level)
    except Exception as exc:  # already initialised (e.g. main() called twice in one process)
        log.debug("zenoh logging not initialised: %s", exc)


def main(argv: list[str] | None = None) -> int:
    """Run ``mocap-router`` with ``argv`` (default ``sys.argv[1:]``) and return the exit status."""
    args = build_parser().parse_args(argv)
    level = logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO
    logging.basicConfig(level=level, format=f"{PROG}: %(message)s", stream=sys.stderr)
    _init_zenoh_log("info" if args.verbose else "error" if args.quiet else "warn")
    try:
        conf = router_config(args.listen, args.config)
        with stop_on_signals(threading.Event()) as stop:
            run_router(conf, stop)
    except (OSError, ValueError, ConnectionError) as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
