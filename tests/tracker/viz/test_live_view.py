"""``mocap-view``: its state follows every kind of message and ignores bad ones; the page, loaded
in a real browser (Debian's headless Chromium), shows the skeleton and the tracker's camera frame."""

from __future__ import annotations

import base64
import json
import shutil
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from protocol import fk
from protocol.net.session import build_config, free_tcp_endpoint, open_session, undeclare_quietly
from protocol.skeleton import N_PARTS, default_body, standing_pose
from protocol.wire.codec import encode
from protocol.wire.game_messages import GameEvent, GameEventKind, GamePhase, GameState, encode_game
from protocol.wire.keys import (
    body_key,
    cloth_mesh_key,
    game_event_key,
    game_state_key,
    pose_key,
    preview_key,
    status_key,
)
from protocol.wire.media import ClothMesh, PreviewFrame, encode_cloth_mesh, encode_preview
from protocol.wire.messages import PoseFrame, TrackerState, TrackerStatus, body_info_from_body
from tracker_service.viz.live_state import LiveState, skeleton_segments

REPO = Path(__file__).resolve().parents[3]
BODY = default_body()
POSE = standing_pose(BODY)
JOINTS = fk(POSE, BODY)


def _pose(seq: int) -> PoseFrame:
    now = time.time()
    return PoseFrame(tracker_id="v1", seq=seq, capture_ts=seq / 30, publish_ts=now, capture_wall_ts=now - 0.02,
                     pose=POSE.astype(np.float32), joints=JOINTS.astype(np.float32),
                     visibility=np.ones(N_PARTS, np.float32), confidence=0.8, estimator="tree", body_model="mMA")


def _preview(colour: tuple[int, int, int]) -> bytes:
    """A JPEG preview of one BGR colour."""
    img = np.zeros((240, 320, 3), np.uint8)
    img[:] = colour
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    return encode_preview(PreviewFrame("v1", 3, 0.1, 320, 240, buf.tobytes()))


def _messages() -> list[tuple[str, bytes]]:
    status = TrackerStatus(tracker_id="v1", state=TrackerState.TRACKING, ts=time.time(), uptime_s=3.0, fps=29.5,
                           frames=90, counters={"published": 88}, stage_ms={"estimate": 4.2}, estimator="tree",
                           body_model="mMA")
    game = GameState(game_id="g1", seq=1, t=1.0, stream_ts=1.0, tick=30, phase=GamePhase.FIGHTING, round_left_s=40.0,
                     player_health=0.8, opponent_health=0.5, player_x=0.0, player_lane=0, player_stance="ready",
                     opponent_x=3.0)
    event = GameEvent(game_id="g1", seq=2, t=1.0, stream_ts=1.0, kind=GameEventKind.GESTURE, gesture="strike")
    verts = np.array([[0, 1, 0], [0.5, 1, 0], [0, 1.5, 0]], np.float32)
    mesh = ClothMesh("v1", 0, time.time(), 0.1, "cape", verts, np.array([[0, 1, 2]], np.uint32))
    return [(pose_key("v1"), encode(_pose(1))), (body_key("v1"), encode(body_info_from_body(BODY, "v1"))),
            (status_key("v1"), encode(status)), (preview_key("v1"), _preview((200, 30, 30))),
            (game_state_key("g1"), encode_game(game)), (game_event_key("g1"), encode_game(event)),
            (cloth_mesh_key("v1"), encode_cloth_mesh(mesh))]


def test_state_follows_every_message_and_ignores_bad_ones() -> None:
    state = LiveState()
    for key, payload in _messages():
        assert state.on_sample(key, payload, now=1.0, wall=time.time()), key
    v = state.trackers["v1"]
    assert v.pose is not None and v.body is not None and v.status is not None and v.preview is not None
    assert state.games["g1"].player_health == pytest.approx(0.8) and any("strike" in e for e in state.events)
    assert state.cloths["v1"].triangles is not None
    lines = "\n".join(state.tracker_lines("v1", now=1.5) + state.game_lines("g1"))
    assert "fps 29.5" in lines and "confidence 0.80" in lines and "estimate 4.2" in lines and "█" in lines
    assert "(silent)" in state.tracker_lines("v1", now=10.0)[0]
    version = state.version
    bad = [(pose_key("v1"), b"\x00garbage"), ("not/a/mocap/key", b"x"), (preview_key("v1"), b"\x81\xa4type\xa7preview"),
           (cloth_mesh_key("v1"), encode_cloth_mesh(ClothMesh("v1", 1, 0.0, 0.0, "cape",
                                                              np.full((3, 3), 1e6, np.float32))))]
    for key, payload in bad:
        assert not state.on_sample(key, payload)
    assert state.version == version and sum(state.dropped.values()) == len(bad)
    pts, col = skeleton_segments(JOINTS)
    assert pts.shape == (len(JOINTS) - 1, 2, 3) and col.shape == pts.shape


def _browser() -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("Debian's chromium is not installed (make test installs it)")
    return exe


def _page_shows(png: bytes) -> tuple[bool, str]:
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        return False, "no screenshot"
    b, g, r = (img[..., k].astype(int) for k in range(3))
    right = int(((r > 200) & (g < 110) & (b < 110)).sum())  # the right side's red bones
    left = int(((b > 200) & (r < 120) & (g > 90) & (g < 170)).sum())  # the left side's blue bones
    camera = int(((b > 170) & (g < 60) & (r < 60)).sum())  # the preview: a deep blue picture
    found = f"left bones {left} px, right bones {right} px, camera {camera} px"
    return left > 30 and right > 30 and camera > 2000, found


def _stop(proc: subprocess.Popen[bytes], timeout: float) -> None:
    """Terminate ``proc``; kill it if it has not ended within ``timeout`` seconds."""
    proc.terminate()
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()


def _watch_page(browser: str, url: str, profile: Path, seconds: float) -> tuple[bool, str]:
    """Open ``url`` in headless Chromium and screenshot it through the DevTools protocol every
    half second until the page shows what :func:`_page_shows` wants or ``seconds`` pass.

    A one-shot ``--screenshot`` with a virtual-time budget can fire before the page's websocket
    has brought the panels (the websocket runs in real time, the budget in virtual time)."""
    from websockets.sync.client import connect  # viser's own dependency

    chrome = subprocess.Popen([browser, "--headless=new", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
                               "--enable-unsafe-swiftshader", "--window-size=1000,700", "--hide-scrollbars",
                               f"--user-data-dir={profile}", "--remote-debugging-port=0", "--remote-allow-origins=*",
                               url], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    seen = (False, "the browser gave no screenshot")
    try:
        deadline = time.monotonic() + seconds
        port_file = profile / "DevToolsActivePort"
        while not port_file.exists() or not port_file.read_text().strip():
            if time.monotonic() > deadline:
                return False, "the browser opened no DevTools port"
            time.sleep(0.1)
        port = int(port_file.read_text().split()[0])
        pages: list[dict[str, Any]] = []
        while not pages and time.monotonic() < deadline:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=5) as reply:
                pages = [t for t in json.load(reply) if t.get("type") == "page"]
            time.sleep(0.1)
        if not pages:
            return False, "the browser showed no page"
        with connect(pages[0]["webSocketDebuggerUrl"], max_size=None, open_timeout=10) as ws:
            n = 0
            while time.monotonic() < deadline:
                n += 1
                ws.send(json.dumps({"id": n, "method": "Page.captureScreenshot", "params": {"format": "png"}}))
                while (reply := json.loads(ws.recv(timeout=20))).get("id") != n:
                    pass
                if "result" in reply:
                    seen = _page_shows(base64.b64decode(reply["result"]["data"]))
                    if seen[0]:
                        break
                time.sleep(0.5)
    finally:
        _stop(chrome, 10.0)
    return seen


def test_the_page_shows_the_skeleton_and_the_camera_frame_in_a_real_browser(tmp_path: Path) -> None:
    browser = _browser()
    ep = free_tcp_endpoint()
    port = int(free_tcp_endpoint().rsplit(":", 1)[1])
    view = subprocess.Popen([sys.executable, "-m", "tracker_service.app.view", "--port", str(port), "--listen", ep,
                             "--mode", "peer", "--duration", "90", "-q"], cwd=REPO, stderr=subprocess.PIPE)
    stop = threading.Event()
    seen = (False, "not tried")
    try:
        with open_session(build_config(mode="peer", connect=[ep], listen=[])) as session:
            pubs: dict[str, Any] = {}

            def publish() -> None:  # a tracker, a game and a cloth client at 10 Hz
                seq = 0
                while not stop.is_set():
                    for key, payload in [(pose_key("v1"), encode(_pose(seq))), *_messages()[1:]]:
                        pubs.setdefault(key, session.declare_publisher(key)).put(payload)
                    seq += 1
                    stop.wait(0.1)

            t = threading.Thread(target=publish)
            t.start()
            try:
                deadline = time.monotonic() + 30
                while time.monotonic() < deadline:
                    try:
                        urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=1).read(100)
                        break
                    except OSError:
                        time.sleep(0.2)
                seen = _watch_page(browser, f"http://127.0.0.1:{port}/", tmp_path / "profile", 40.0)
            finally:
                stop.set()
                t.join(10)
                undeclare_quietly(*pubs.values())
    finally:
        _stop(view, 20.0)
    assert seen[0], seen[1]


def test_the_daemons_preview_is_the_overlay_as_a_jpeg_preview_frame() -> None:
    from protocol.wire.media import decode_preview
    from tracker_service.app.daemon import preview_payload
    from tracker_service.camera import default_camera
    from tracker_service.pipeline.state import FrameResult

    cam = default_camera()
    body = default_body()
    frame = np.full((240, 320, 3), 90, np.uint8)
    sil = np.zeros((240, 320), bool)
    sil[60:220, 140:180] = True
    res = FrameResult("tracking", sil, standing_pose(body), fk(standing_pose(body), body), np.ones(N_PARTS, np.float32),
                      0.8, 0.1, (1, 2, 3), {})
    msg = decode_preview(preview_payload("cam0", 41, 1.5, frame, cam, res, 29.5) or b"")
    assert (msg.tracker_id, msg.seq, msg.capture_ts, msg.width, msg.height) == ("cam0", 41, 1.5, 320, 240)
    image = cv2.imdecode(np.frombuffer(msg.jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert image is not None
    assert image.shape == (240, 320, 3) and float(np.abs(image.astype(int) - 90).mean()) > 1.0  # drawn on
