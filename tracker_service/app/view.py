"""``mocap-view``: a live page on 127.0.0.1 showing every tracker, game and cloth client on the
Zenoh network -- the camera frame with the tracker's overlay, the 3D skeleton, the cloth mesh, the
game state and each process's status (fps, latency, per-stage milliseconds).

The page is viser's web viewer (a maintained three.js client shipped in the ``viser`` wheel: no
hand-written WebGL); this module subscribes to ``mocap/**`` and pushes what
:class:`~tracker_service.viz.live_state.LiveState` holds at most ``--rate`` times a second. The
tracker draws and sends its preview frames only while a viewer subscribes (``PREVIEW_HZ`` a
second), so an unwatched tracker pays nothing.

Usage::

    mocap-view [--port 8080] [--host 127.0.0.1] [--duration S] [--mode/--connect/--listen/--config]

Open the printed address in a browser. Stops on Ctrl-C / SIGTERM or after ``--duration``.
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading
import time
from importlib import metadata
from typing import Any

import cv2
import numpy as np

from protocol.net.session import add_zenoh_args, config_from_args, open_session, stop_on_signals, undeclare_quietly
from protocol.wire.keys import PREFIX
from tracker_service.viz.live_state import LiveState, skeleton_segments

__all__ = ["build_parser", "main", "run_view"]

PROG = "mocap-view"
log = logging.getLogger("tracker_service.view")


def build_parser() -> argparse.ArgumentParser:
    """The command line of ``mocap-view``."""
    p = argparse.ArgumentParser(prog=PROG, description="Serve a live page (viser) showing the trackers, games and "
                                "cloth clients on the Zenoh network: camera frame with the overlay, 3D skeleton, "
                                "cloth mesh, game state and status. Stops on Ctrl-C / SIGTERM.")
    p.add_argument("--host", default="127.0.0.1", help="address the page is served on (default 127.0.0.1: "
                   "this machine only)")
    p.add_argument("--port", type=int, default=8080, help="port of the page (default 8080)")
    p.add_argument("--rate", type=float, default=30.0, help="page updates a second at most (default 30)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    verbosity = p.add_mutually_exclusive_group()
    verbosity.add_argument("-v", "--verbose", action="store_true", help="more log output on stderr")
    verbosity.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors on stderr")
    try:
        version = metadata.version("mocap-service")
    except metadata.PackageNotFoundError:
        version = "unknown"
    p.add_argument("--version", action="version", version=f"{PROG} {version}")
    add_zenoh_args(p, "subscriber")
    return p


class _Page:
    """The viser scene and panels, updated from a :class:`LiveState`."""

    def __init__(self, server: Any) -> None:
        self.server = server
        server.scene.set_up_direction("+y")
        server.scene.add_grid("/floor", width=6.0, height=6.0, plane="xz", cell_size=0.5)
        server.initial_camera.position = (0.0, 1.4, 4.2)
        server.initial_camera.look_at = (0.0, 1.0, 0.0)
        self.images: dict[str, Any] = {}
        self.texts: dict[str, Any] = {}
        self.shown: dict[str, object] = {}  # node -> the message last drawn there (a new one redraws it)
        self.pictures: dict[str, bytes] = {}  # node -> the camera picture last drawn there
        self.summary = server.gui.add_markdown("waiting for trackers, games and cloth clients ...")

    def _text(self, name: str, lines: list[str]) -> None:
        body = "  \n".join(lines)
        if name not in self.texts:
            self.texts[name] = self.server.gui.add_markdown(body)
        elif self.texts[name].content != body:
            self.texts[name].content = body

    def _new(self, node: str, msg: object) -> bool:
        """Whether ``msg`` is not what ``node`` shows yet (and remember it as shown)."""
        if msg is None or self.shown.get(node) is msg:
            return False
        self.shown[node] = msg
        return True

    def _new_picture(self, node: str, jpeg: bytes) -> bool:
        """Whether the picture ``jpeg`` differs from what ``node`` shows (a repeated frame is not
        sent to the browser again: it would redraw the image for nothing)."""
        if self.pictures.get(node) == jpeg:
            return False
        self.pictures[node] = jpeg
        return True

    def draw(self, state: LiveState) -> None:
        """Redraw what changed: a skeleton, camera frame or mesh only when its message is new."""
        now = time.monotonic()
        for sid, v in state.trackers.items():
            if v.pose is not None and self._new(f"/trackers/{sid}/skeleton", v.pose):
                pts, col = skeleton_segments(v.pose.joints)
                self.server.scene.add_line_segments(f"/trackers/{sid}/skeleton", points=pts, colors=col,
                                                    line_width=5.0)
                joints = np.asarray(v.pose.joints, np.float32)
                self.server.scene.add_point_cloud(f"/trackers/{sid}/joints", points=joints, colors=(255, 220, 90),
                                                  point_size=0.03)
            if v.preview is not None and self._new_picture(f"camera/{sid}", v.preview.jpeg):
                bgr = cv2.imdecode(np.frombuffer(v.preview.jpeg, np.uint8), cv2.IMREAD_COLOR)
                if bgr is not None:
                    rgb = np.ascontiguousarray(bgr[..., ::-1])
                    if sid not in self.images:
                        self.images[sid] = self.server.gui.add_image(rgb, label=f"camera {sid}", format="jpeg")
                    else:
                        self.images[sid].image = rgb
            self._text(f"tracker/{sid}", state.tracker_lines(sid, now))
        for gid in state.games:
            self._text(f"game/{gid}", [*state.game_lines(gid), *list(state.events)[-3:]])
        for cid, cv in state.cloths.items():
            if cv.mesh is not None and cv.triangles is not None and self._new(f"/cloth/{cid}", cv.mesh):
                self.server.scene.add_mesh_simple(f"/cloth/{cid}", np.asarray(cv.mesh.vertices, np.float32),
                                                  np.asarray(cv.triangles, np.int32), color=(200, 80, 90),
                                                  side="double")
                self._text(f"cloth/{cid}", [f"**cloth `{cid}`** {cv.mesh.garment} · {len(cv.mesh.vertices)} "
                                            f"vertices · frame {cv.mesh.seq}"])
        dropped = sum(state.dropped.values())
        summary = (f"{len(state.trackers)} tracker(s), {len(state.games)} game(s), {len(state.cloths)} cloth "
                   f"client(s)" + (f" · {dropped} bad messages ignored" if dropped else ""))
        if self.summary.content != summary:
            self.summary.content = summary


def run_view(args: argparse.Namespace, stop: threading.Event) -> LiveState:
    """Serve the page and follow the network until ``stop`` or ``--duration``; the final state."""
    import viser

    state = LiveState()
    server = viser.ViserServer(host=args.host, port=args.port, verbose=False)
    try:
        page = _Page(server)
        log.info("open http://%s:%d/ in a browser", args.host, server.get_port())
        print(f"{PROG}: serving http://{args.host}:{server.get_port()}/", file=sys.stderr, flush=True)
        t0, shown, period = time.monotonic(), -1, 1.0 / max(args.rate, 1.0)
        with open_session(config_from_args(args, role="subscriber")) as session:
            sub: Any = None
            try:
                sub = session.declare_subscriber(f"{PREFIX}/**")
                while not stop.is_set():
                    if args.duration is not None and time.monotonic() - t0 >= args.duration:
                        break
                    while (s := sub.try_recv()) is not None:
                        state.on_sample(str(s.key_expr), s.payload.to_bytes())
                    if state.version != shown:
                        shown = state.version
                        page.draw(state)
                    stop.wait(period)
            finally:
                undeclare_quietly(sub)
    finally:
        server.stop()
    return state


def main(argv: list[str] | None = None) -> int:
    """Run ``mocap-view``; the exit status."""
    args = build_parser().parse_args(argv)
    level = logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO
    logging.basicConfig(level=level, format=f"{PROG}: %(message)s", stream=sys.stderr)
    if not 0 < args.port < 65536:
        print(f"{PROG}: --port must be 1..65535", file=sys.stderr)
        return 2
    try:
        with stop_on_signals(threading.Event()) as stop:
            state = run_view(args, stop)
    except (OSError, ValueError, ConnectionError) as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 1
    log.info("stopped: %d tracker(s), %d game(s), %d cloth client(s), %d bad messages ignored",
             len(state.trackers), len(state.games), len(state.cloths), sum(state.dropped.values()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
