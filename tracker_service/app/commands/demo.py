"""``mocap-tracker demo``: what ``make demo`` runs.

The whole system (default): this process opens a Zenoh router on a free loopback port and starts
three child processes that connect to it: the game client (``mocap-game run``) and the cloth client
(``mocap-cloth run``) first, then, once both have subscribed, the tracker daemon (``mocap-tracker
run``) on the built-in synthetic scene playing a whole game round. It listens to the poses, the
tracker's status and the game's events itself (latency, fps, the gestures as they fire), stops the
clients when the tracker's script is over, composes ``out/demo/demo.mp4`` from the tracker's overlay
video and the clients' frames (:mod:`tracker_service.app.demo_mosaic`) and prints one JSON summary
as its last line on stdout.

With ``--replay`` it replays a real recording's ground truth in a child process instead, subscribes
to it here, prints every received pose and checks that all frames arrived in order (seconds)."""

from __future__ import annotations

import argparse
import json
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from protocol.net.cli_args import positive_float
from tracker_service.app.children import child_env, stop_child
from tracker_service.app.demo_replay import DEMO_RECORDINGS, run_replay_demo
from tracker_service.app.options import DemoOptions
from tracker_service.paths import REPO_ROOT

if TYPE_CHECKING:
    pass

__all__ = ["CLEAN_STOP", "DEFAULT_OUT", "DEFAULT_ROUND", "DEMO_RECORDINGS", "NAME", "SystemDemoOptions",
           "add_parser", "main", "options_from_args"]

NAME = "demo"
CLEAN_STOP = True
PROG = "mocap-tracker"
#: The script the synthetic person plays in the whole-system demo: a won round, all five gestures.
DEFAULT_ROUND = REPO_ROOT / "game_client" / "scripts" / "round_win.toml"
#: Where the whole-system demo writes its video, the clients' frames and the processes' logs.
DEFAULT_OUT = REPO_ROOT / "out" / "demo"


def add_parser(sub: Any, parents: Sequence[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    """Add ``demo`` to the ``mocap-tracker`` subparsers."""
    dp = sub.add_parser(
        NAME, parents=list(parents), help="the whole system: tracker, game and cloth over Zenoh, as a mosaic video",
        description="The paper's system end to end: the tracker daemon on the built-in synthetic scene playing a "
                    "whole game round (game_client/scripts/round_win.toml: all five gestures), the game client "
                    "and the cloth client, three processes joined over Zenoh through a router on a free "
                    "loopback port (this process). Writes out/demo/demo.mp4 (camera + silhouette + skeleton, "
                    "3D skeleton, game view, cloth view, HUD) and prints one JSON summary as its last line. "
                    "The first run builds the default template database (a few minutes, once). With --replay "
                    "it instead replays a real recording's ground truth to a printing subscriber (seconds).",
    )
    dp.add_argument("--duration", type=positive_float, default=None, metavar="S",
                    help="seconds to run (default: the whole script; 6 with --replay)")
    dp.add_argument("--json", action="store_true", help="print only the JSON summary on stdout")
    dp.add_argument("--replay", action="store_true",
                    help="replay a recording's ground truth to a printing subscriber instead (a quick check)")
    dp.add_argument("--script", type=Path, default=DEFAULT_ROUND, metavar="FILE",
                    help="gesture script the synthetic person plays (default: game_client/scripts/round_win.toml)")
    dp.add_argument("--out", type=Path, default=DEFAULT_OUT, metavar="DIR",
                    help="output folder (default: out/demo); the mosaic is DIR/demo.mp4")
    dp.add_argument("--no-video", action="store_true",
                    help="no mosaic video (the clients write no frames either): the JSON summary only")
    dp.add_argument("--seed", type=int, default=0, help="synthetic scene seed (default 0)")
    dp.add_argument("--db", metavar="PATH", help="template database folder (default: out/db/mMA, built on first use)")
    dp.add_argument("--view", type=int, nargs="?", const=8080, default=None, metavar="PORT",
                    help="also start mocap-view: watch the round live at http://127.0.0.1:PORT/ (default 8080)")
    return dp


@dataclass(frozen=True)
class SystemDemoOptions(DemoOptions):
    """``mocap-tracker demo`` without ``--replay``: the whole system (``duration`` None: the whole
    script)."""

    script: Path = field(default_factory=lambda: DEFAULT_ROUND)
    out: Path = field(default_factory=lambda: DEFAULT_OUT)
    video: bool = True
    seed: int = 0
    system_duration: float | None = None
    db: str | None = None
    view_port: int | None = None


def options_from_args(args: argparse.Namespace) -> DemoOptions:
    if args.replay:
        return DemoOptions(duration=args.duration or 6.0, json=args.json, replay=True)
    return SystemDemoOptions(json=args.json, script=args.script, out=args.out, video=not args.no_video,
                             seed=args.seed, system_duration=args.duration, db=args.db, view_port=args.view)


def main(options: DemoOptions) -> int:
    """Run the demo; exit status 0 only if it worked (see the description)."""
    from protocol.net.session import stop_on_signals

    with stop_on_signals(threading.Event()) as stop:
        if options.replay:
            return run_replay_demo(options, stop)
        sys_opts = options if isinstance(options, SystemDemoOptions) else SystemDemoOptions(json=options.json)
        return run_system_demo(sys_opts, stop)


# ------------------------------------------------------------------------------------ the child


_TID = "demo"  # tracker id and game id of the whole-system demo
#: Seconds a child may take to stop after SIGINT (the game client encodes its GIF and MP4 then).
_CLIENT_STOP_S = 60.0


@dataclass
class _Child:
    """A child process of the demo: its stderr goes to a log file and a queue of lines, its stdout
    is kept (the clients print their JSON summary there)."""

    name: str
    proc: subprocess.Popen[str]
    log: Path
    lines: queue.Queue[str] = field(default_factory=queue.Queue)
    stdout: list[str] = field(default_factory=list)
    pumps: list[threading.Thread] = field(default_factory=list)

    @classmethod
    def start(cls, name: str, cmd: list[str], log_dir: Path) -> _Child:
        log = log_dir / f"{name}.log"
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=child_env())
        child = cls(name, proc, log)
        fh = log.open("w", encoding="utf-8")
        fh.write(" ".join(cmd) + "\n")

        def pump_err() -> None:
            assert proc.stderr is not None
            with fh:
                for line in proc.stderr:
                    fh.write(line)
                    fh.flush()
                    child.lines.put(line)

        def pump_out() -> None:
            assert proc.stdout is not None
            child.stdout.extend(proc.stdout)

        child.pumps = [threading.Thread(target=pump_err, daemon=True), threading.Thread(target=pump_out, daemon=True)]
        for t in child.pumps:
            t.start()
        return child

    def drained(self, timeout: float = 5.0) -> None:
        """Wait (bounded) until the exited child's output has been read."""
        for t in self.pumps:
            t.join(timeout)

    def wait_for(self, needle: str, timeout: float, stop: threading.Event) -> bool:
        """True once a stderr line contains ``needle``; False on exit, timeout or ``stop``."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not stop.is_set():
            try:
                if needle in self.lines.get(timeout=0.05):
                    return True
            except queue.Empty:
                if self.proc.poll() is not None:
                    return False
        return False

    def json_out(self) -> dict[str, Any] | None:
        """The last JSON object the child printed on stdout (after it exited)."""
        for line in reversed(self.stdout):
            if line.strip().startswith("{"):
                try:
                    value = json.loads(line)
                except ValueError:
                    continue
                return value if isinstance(value, dict) else None
        return None

    def tail(self, n: int = 15) -> str:
        try:
            return "".join(self.log.read_text(encoding="utf-8", errors="replace").splitlines(True)[-n:])
        except OSError:
            return ""


@dataclass
class _Listener:
    """What the demo hears on the router: poses (with their latency), the tracker's status and the
    game's gesture events."""

    say: Callable[[str], None]
    poses: list[Any] = field(default_factory=list)
    gestures: list[Any] = field(default_factory=list)
    process_ms: float = 0.0  # the tracker's mean per-frame pipeline time (its latest status)
    statuses: int = 0
    malformed: int = 0
    last_status_print: float = 0.0

    def pose(self, payload: bytes) -> None:
        from protocol.wire.codec import ProtocolError, decode
        from protocol.wire.messages import PoseFrame
        from tracker_service.app.demo_mosaic import PoseSeen

        now = time.time()
        try:
            f = decode(payload, PoseFrame)
        except ProtocolError:
            self.malformed += 1
            return
        latency = 1000.0 * (now - f.capture_wall_ts)  # capture to receipt, this very frame
        self.poses.append(PoseSeen(f.seq, float(f.capture_ts), float(f.publish_ts), now, f.joints, latency))

    def status(self, payload: bytes) -> None:
        from protocol.wire.codec import ProtocolError, decode
        from protocol.wire.messages import TrackerStatus

        try:
            st = decode(payload, TrackerStatus)
        except ProtocolError:
            self.malformed += 1
            return
        self.statuses += 1
        self.process_ms = float(st.stage_ms.get("total", self.process_ms))
        if time.monotonic() - self.last_status_print >= 2.0 or st.state.value == "stopped":
            self.last_status_print = time.monotonic()
            self.say(f"demo: tracker {st.state.value}, {st.frames} poses, {st.fps:.1f} fps, "
                     f"{self.process_ms:.1f} ms a frame")

    def game_event(self, payload: bytes) -> None:
        from protocol.wire.codec import ProtocolError
        from protocol.wire.game_messages import GameEvent, GameEventKind, decode_game
        from tracker_service.app.demo_mosaic import GestureSeen

        try:
            ev = decode_game(payload, GameEvent)
        except ProtocolError:
            self.malformed += 1
            return
        if ev.kind == GameEventKind.GESTURE:
            self.gestures.append(GestureSeen(ev.gesture, ev.direction, float(ev.end_s), float(ev.stream_ts),
                                             float(ev.confidence)))
            side = f" {ev.direction}" if ev.direction else ""
            self.say(f"demo: gesture {ev.gesture}{side} at t={ev.end_s:.2f} s "
                     f"(confidence {ev.confidence:.2f}, recognised {ev.latency_ms:.0f} ms after its end)")
        elif ev.kind in (GameEventKind.HIT, GameEventKind.ROUND_END, GameEventKind.TRANSFORM):
            self.say(f"demo: game {ev.kind.value} {ev.actor} {ev.detail}".rstrip())


def _system_commands(o: SystemDemoOptions, db: Path, endpoint: str, out: Path) -> dict[str, list[str]]:
    py = sys.executable
    zenoh_args = ["--connect", endpoint, "--listen", "tcp/127.0.0.1:0"]
    tracker = [py, "-m", "tracker_service", "run", "--source", f"synthetic:{o.script}", "--db", str(db),
               "--id", _TID, "--seed", str(o.seed), "--max-heading", "35", "--wait-for-subscriber", "10",
               "--prerender", *zenoh_args]  # the camera's frames cost the tracker nothing, as a real camera's
    game = [py, "-m", "game_client", "run", "-v", "--tracker", _TID, "--id", _TID, "--json",
            "--log", str(out / "game.jsonl"), *zenoh_args]
    cloth = [py, "-m", "cloth_client", "run", "--id", _TID, "--garment", "cape", "--json", "--log-level", "INFO",
             *zenoh_args]
    if o.system_duration is not None:
        tracker += ["--duration", str(o.system_duration)]
    if o.video:
        tracker += ["--video", str(out / "tracker_overlay.mp4")]
        game += ["--frames-out", str(out / "game"), "--fps", "30"]
        cloth += ["--frames-out", str(out / "cloth"), "--video-fps", "30", "--size", "360x360"]
    cmds = {"tracker": tracker, "game": game, "cloth": cloth}
    if o.view_port is not None:
        cmds["view"] = [py, "-m", "tracker_service.app.view", "--port", str(o.view_port), *zenoh_args]
    return cmds


def _display(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def _round_text(game: dict[str, Any] | None) -> str:
    if not game or not game.get("summaries"):
        return "no round played" if game else "unknown (no summary from the game client)"
    s = game["summaries"][0]
    if s.get("winner"):
        return f"{s['winner']} wins by {s.get('reason') or '?'}"
    return (f"not finished (player {s.get('player_health', 0):.0f} HP, "
            f"opponent {s.get('opponent_health', 0):.0f} HP after {s.get('t', 0):.1f} s)")


def run_system_demo(o: SystemDemoOptions, stop: threading.Event) -> int:
    """The whole-system demo (see the module docstring); exit status 0 only if every process ended
    cleanly, poses arrived and (unless ``o.video`` is off) the video was written."""
    import shutil

    from protocol.net.session import build_config, free_tcp_endpoint, open_session, undeclare_quietly
    from protocol.wire.keys import game_event_key, pose_key, status_key
    from tracker_service.app.resources import ensure_db

    def say(line: str) -> None:
        if not o.json:
            print(line, flush=True)

    t0 = time.monotonic()
    script = Path(o.script)
    if not script.is_file():
        print(f"{PROG} demo: script not found: {script}", file=sys.stderr)
        return 1
    out = Path(o.out)
    for sub in ("game", "cloth"):  # frames of an earlier run would be taken for this one's
        shutil.rmtree(out / sub, ignore_errors=True)
    (out / "logs").mkdir(parents=True, exist_ok=True)
    say("demo: loading the template database (the first run builds it: a few minutes, once)")
    loaded = ensure_db(o.db)
    endpoint = free_tcp_endpoint()
    cmds = _system_commands(o, loaded.path, endpoint, out)
    heard = _Listener(say)
    children: dict[str, _Child] = {}
    failed: str | None = None
    t_setup = t_run = time.monotonic()
    t_end = t_run
    with open_session(build_config("publisher", mode="router", listen=[endpoint])) as session:
        subs: list[Any] = []
        try:
            pose_sub = session.declare_subscriber(pose_key(_TID))
            status_sub = session.declare_subscriber(status_key(_TID))
            event_sub = session.declare_subscriber(game_event_key(_TID))
            subs += [pose_sub, status_sub, event_sub]
            say(f"demo: Zenoh router on {endpoint}; starting the game and cloth clients")
            starting: list[str] = [n for n in ("game", "cloth", "view") if n in cmds]
            for name in starting:
                children[name] = _Child.start(name, cmds[name], out / "logs")
            needles = {"game": "listening on", "cloth": "cloth client:", "view": "serving http"}
            for name, needle in ((n, needles[n]) for n in starting):
                if not children[name].wait_for(needle, 180.0, stop):
                    failed = f"the {name} client did not start"
                    break
            if failed is None and "view" in cmds:
                say(f"demo: watch it live at http://127.0.0.1:{o.view_port}/")
            if failed is None:
                say(f"demo: clients subscribed; starting the tracker on the synthetic scene playing {script.name}")
                children["tracker"] = tracker = _Child.start("tracker", cmds["tracker"], out / "logs")
                if not tracker.wait_for("publishing", 300.0, stop):
                    failed = "the tracker did not start"
            if failed is None and not stop.is_set():
                t_setup = time.monotonic()
                say(f"demo: setup took {t_setup - t0:.1f} s; the round is on")
                failed = _listen(children["tracker"].proc, pose_sub, status_sub, event_sub, heard, stop, o, script)
                t_end = time.monotonic()
        finally:
            for child in children.values():  # all at once: the game writes its GIF and MP4 on the way out
                if child.proc.poll() is None:
                    child.proc.send_signal(signal.SIGINT)
            for who, child in children.items():
                rc = stop_child(child.proc, 1.0 if stop.is_set() else _CLIENT_STOP_S, signalled=True)
                if rc != 0 and failed is None:
                    failed = f"the {who} process exited with status {rc}"
            undeclare_quietly(*reversed(subs))
    for child in children.values():
        child.drained()
    if failed is not None:
        print(f"{PROG} demo: {failed}", file=sys.stderr)
        for child in children.values():
            print(f"--- {child.log}:\n{child.tail()}", file=sys.stderr)
    summary = _summarise(o, script, out, heard, children, t0, t_setup, t_end, say, quick=stop.is_set())
    ok = failed is None and summary["frames"]["tracker"] > 0 and (not o.video or summary["video"] is not None)
    summary["ok"] = ok
    print(json.dumps(summary), flush=True)
    return 0 if ok else 1


def _listen(tracker: subprocess.Popen[str], pose_sub: Any, status_sub: Any, event_sub: Any, heard: _Listener,
            stop: threading.Event, o: SystemDemoOptions, script: Path) -> str | None:
    """Hear the round until the tracker has exited (and the clients had a moment to catch up), a
    deadline or ``stop``; None, or why it had to be cut short."""
    from protocol.formats.load import load_motion

    motion_s = load_motion(script).duration + 1.0
    expected = o.system_duration if o.system_duration is not None else motion_s
    limit = 30.0 + 6.0 * expected  # a loaded machine tracks slower than real time
    deadline = time.monotonic() + limit
    exited_at: float | None = None
    why: str | None = None
    while not stop.is_set():
        busy = False
        for sub, handle in ((pose_sub, heard.pose), (status_sub, heard.status), (event_sub, heard.game_event)):
            while (sample := sub.try_recv()) is not None:
                busy = True
                handle(bytes(sample.payload.to_bytes()))
        now = time.monotonic()
        if exited_at is None and tracker.poll() is not None:
            exited_at = now
        if exited_at is not None and now - exited_at > 1.5 and not busy:  # the clients catch up
            break
        if exited_at is None and now > deadline:
            why = f"the tracker had not finished after {limit:.0f} s"
            tracker.send_signal(signal.SIGINT)
            exited_at = now
        if not busy:
            stop.wait(0.005)
    return "interrupted" if stop.is_set() else why


def _summarise(o: SystemDemoOptions, script: Path, out: Path, heard: _Listener, children: dict[str, _Child],
               t0: float, t_setup: float, t_end: float, say: Callable[[str], None], quick: bool) -> dict[str, Any]:
    """The JSON summary (and, unless ``quick`` after an interruption, the mosaic and the joint error)."""
    from tracker_service.app.demo_mosaic import (
        EMPTY_PREFIX,
        ClientFrames,
        MosaicInputs,
        ground_truth,
        match_gestures,
        mpjpe_cm,
        percentile,
        performed_gestures,
        write_mosaic,
    )

    poses = heard.poses
    game = children["game"].json_out() if "game" in children else None
    cloth = children["cloth"].json_out() if "cloth" in children else None
    span = poses[-1].publish_ts - poses[0].publish_ts if len(poses) > 1 else 0.0
    stream_span = poses[-1].capture_ts - poses[0].capture_ts if len(poses) > 1 else 0.0
    n_game = int(game["frames"]) if game else 0
    n_cloth = int(cloth["frames"]) if cloth else 0
    fps, truth, mpjpe = 30.0, None, None
    if not quick:
        try:
            fps, truth = ground_truth(script, o.seed)
            mpjpe = mpjpe_cm(poses, fps, truth)
        except (OSError, ValueError) as exc:  # an unreadable script: no truth to score against
            say(f"demo: no ground truth ({exc})")
    offset = EMPTY_PREFIX / fps
    labels = performed_gestures(script)
    if labels is not None:
        last_t = poses[-1].capture_ts if poses else 0.0
        performed = [lab for lab in labels if float(lab["end_s"]) + offset <= last_t]
        recognised: int = sum(match_gestures(performed, heard.gestures, offset))
    else:  # an unlabelled script: every recognised gesture counts, none is known to be performed
        performed, recognised = [], len(heard.gestures)
    video: str | None = None
    t_mosaic = time.monotonic()
    overlay = out / "tracker_overlay.mp4"
    if o.video and overlay.is_file() and poses and not quick:
        say("demo: composing the mosaic video")
        inputs = MosaicInputs(overlay=overlay, fps=fps, poses=poses, gestures=heard.gestures,
                              game=ClientFrames(out / "game"), cloth=ClientFrames(out / "cloth"), truth=truth)
        try:
            n = write_mosaic(inputs, out / "demo.mp4")
        except (OSError, ValueError) as exc:
            say(f"demo: the mosaic could not be written: {exc}")
        else:
            video = _display(out / "demo.mp4")
            say(f"demo: wrote {video} ({n} frames; game view {len(inputs.game)} frames, "
                f"cloth view {len(inputs.cloth)} frames)")
    sim_wall = float(cloth.get("sim_wall_s", 0.0)) if cloth else 0.0
    return {
        "gestures_performed": len(performed) if labels is not None else None,
        "gestures_recognised": recognised,
        "round": _round_text(game),
        "latency_ms": {"p50": percentile([p.latency_ms for p in poses], 50),
                       "p99": percentile([p.latency_ms for p in poses], 99)},
        "fps": {"tracker": round((len(poses) - 1) / span, 1) if span > 0 else 0.0,
                "game": round(n_game / span, 1) if span > 0 else 0.0,
                "cloth": round(n_cloth / span, 1) if span > 0 else 0.0},
        "cloth_realtime_factor": round(stream_span / sim_wall, 2) if sim_wall > 0 else None,
        "mpjpe_cm": mpjpe,
        "video": video,
        "script": script.name,
        "gestures": [g.gesture + (f" {g.direction}" if g.direction else "") for g in heard.gestures],
        "frames": {"tracker": len(poses), "game": n_game, "cloth": n_cloth},
        "wall_s": {"setup": round(t_setup - t0, 1), "round": round(t_end - t_setup, 1),
                   "mosaic": round(time.monotonic() - t_mosaic, 1)},
    }
