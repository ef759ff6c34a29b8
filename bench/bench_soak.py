"""A soak under hostile input: a replayed tracker, the game and the cloth client on one router for
minutes, with bursts of malformed and absurd messages on the tracker's keys; memory, rates and
recovery measured from outside.

Usage::

    .venv/bin/python bench/bench_soak.py [--minutes 10] [--burst-every 60] [--burst-s 5]
        [--fuzz-session new|one] [--out DIR]

Processes (the product's own commands, all clients of one ``mocap-router`` on loopback):
``mocap-tracker replay --loop`` of the game's winning round (``game_client/scripts/round_win.toml``),
``mocap-game run`` and ``mocap-cloth run --publish-mesh`` following it, and every ``--burst-every``
seconds ``python -m protocol fuzz`` for ``--burst-s`` seconds at 100 payloads a second, on the pose
key and the body key in turn (``--fuzz-session new``: a new Zenoh session each burst, as a stranger
reconnecting would; ``one``: the same payloads from the bench's own long-lived session, as a
connected client gone hostile would). The bench subscribes to the game's state and events and the cloth's
mesh, counts them per second and samples every process's resident memory (``VmRSS``) every 10 s.

Reported: per process the memory after the first minute and at the end and its slope (MB per
minute, least squares from the first minute on, and from 15 s after the first burst on: a session's
first large messages cost Zenoh a one-time step); the game's state rate and the cloth's mesh rate
outside bursts, their lowest one-second rate during bursts and the slowest return to 90 % of the
usual rate after a burst ends; the game's events inside and outside bursts (a fake gesture shows as
an event rate that rises in bursts); every process still running at the end. Writes ``soak.md`` and
``soak.json`` to ``--out`` (default ``out/bench_soak``). Not a test: it takes ``--minutes``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from _host import bench_meta  # bench/ is the script's folder

from protocol.formats.load import load_motion
from protocol.net.session import build_config, free_tcp_endpoint, open_session, undeclare_quietly
from protocol.wire.codec import ProtocolError, decode
from protocol.wire.game_messages import GameEvent, GameEventKind
from protocol.wire.keys import body_key, cloth_mesh_key, game_event_key, game_state_key, pose_key

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
ROUND = ROOT / "game_client" / "scripts" / "round_win.toml"
TID = "soak"


def _rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def _slope(t_min: list[float], mb: list[float], start_min: float = 1.0) -> float:
    t, m = np.asarray(t_min), np.asarray(mb)
    keep = (t >= start_min) & np.isfinite(m)
    if keep.sum() < 3:
        return float("nan")
    return float(np.polyfit(t[keep], m[keep], 1)[0])


def _burst_from(session: zenoh.Session, key: str, seconds: float, seed: int, rate: float = 100.0) -> None:
    """``python -m protocol fuzz``'s payloads, published from ``session`` (already open)."""
    from protocol.__main__ import fuzz_template
    from protocol.wire.fuzz import hostile_stream

    stream = hostile_stream(fuzz_template(key), np.random.default_rng(seed), last_seq=1, clock=0.0)
    pub = session.declare_publisher(key)
    try:
        t0 = time.monotonic()
        k = 0
        while time.monotonic() - t0 < seconds:
            pub.put(next(stream)[1])
            k += 1
            time.sleep(max(0.0, t0 + k / rate - time.monotonic()))
    finally:
        undeclare_quietly(pub)


def _recovery_sliding(at: list[float], b1: float, usual_hz: float, step_s: float = 0.01,
                      horizon_s: float = 60.0) -> float:
    """Seconds from a burst's end ``b1`` to the first message of the first second that holds at
    least 90 % of the usual rate's messages (``[t, t + 1)``, ``t`` on a ``step_s`` grid): the
    per-second count without the bins' alignment (a bin starts on a whole second, so the count
    could not read less than the time to the next whole second, and one late message of a 5 Hz
    stream cost a whole second)."""
    if not (np.isfinite(usual_hz) and usual_hz > 0):
        return float("nan")
    t = np.sort(np.asarray(at, np.float64))
    need = 0.9 * usual_hz
    for start in b1 + np.arange(0.0, horizon_s, step_s):
        k = int(np.searchsorted(t, start))
        if np.searchsorted(t, start + 1.0) - k >= need:
            return float(t[k] - b1)  # that second's first message
    return float("inf")


def _finite(x: float) -> float | None:
    """``x`` rounded to 10 ms; None where the stream never came back (JSON has no infinity)."""
    return round(float(x), 2) if np.isfinite(x) else None


def _longest_gap(at: list[float], b1: float, window_s: float) -> float:
    """The longest gap between arrivals in the ``window_s`` after ``b1`` (the last one before it
    counting from ``b1``)."""
    t = np.asarray([b1, *[a for a in at if b1 <= a <= b1 + window_s], b1 + window_s], np.float64)
    return float(np.diff(t).max())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--burst-every", type=float, default=60.0, metavar="S")
    ap.add_argument("--burst-s", type=float, default=5.0, metavar="S")
    ap.add_argument("--fuzz-session", choices=("new", "one"), default="new",
                    help="each burst from a new session (python -m protocol fuzz) or all from one session")
    ap.add_argument("--out", default=str(ROOT / "out" / "bench_soak"))
    args = ap.parse_args()
    duration = args.minutes * 60.0
    ep = free_tcp_endpoint()
    net = ["--mode", "client", "--connect", ep]
    t0 = time.time()
    procs: dict[str, subprocess.Popen[bytes]] = {}
    logs = Path(args.out)
    logs.mkdir(parents=True, exist_ok=True)

    def start(name: str, cmd: list[str]) -> None:
        with open(logs / f"{name}.log", "wb") as err:
            procs[name] = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=err)

    start("router", [str(BIN / "mocap-router"), "--listen", ep, "-q"])
    time.sleep(1.0)
    run_s = str(int(duration + 30))
    start("replay", [str(BIN / "mocap-tracker"), "replay", "--script", str(ROUND), "--loop", "--id", TID, "-q", *net])
    start("game", [str(BIN / "mocap-game"), "run", "--tracker", TID, "--duration", run_s, "--json", "-q", *net])
    start("cloth", [str(BIN / "mocap-cloth"), "run", "--id", TID, "--publish-mesh", "--duration", run_s, "--json",
                    "--log-level", "WARNING", *net])
    counts: dict[str, Counter[int]] = {"state": Counter(), "mesh": Counter(), "event": Counter()}
    arrivals: dict[str, list[float]] = {"state": [], "mesh": []}
    events: list[tuple[float, str]] = []
    lock = threading.Lock()
    t_start = time.monotonic()

    def on(kind: str) -> Any:
        def cb(sample: zenoh.Sample) -> None:
            at = time.monotonic() - t_start
            s = int(at)
            with lock:
                counts[kind][s] += 1
                if kind in arrivals:
                    arrivals[kind].append(at)
                if kind == "event":
                    try:
                        ev = decode(sample.payload.to_bytes(), GameEvent)
                        name = ev.gesture if ev.kind == GameEventKind.GESTURE else ev.kind.value
                    except ProtocolError:
                        name = "undecodable"
                    events.append((time.monotonic() - t_start, name))
        return cb

    bursts: list[tuple[float, float, str]] = []
    rss: dict[str, list[float]] = {k: [] for k in procs}
    rss_t: list[float] = []
    subs = []
    try:
        with open_session(build_config(mode="client", connect=[ep])) as session:
            subs = [session.declare_subscriber(game_state_key("default"), on("state")),
                    session.declare_subscriber(cloth_mesh_key(TID), on("mesh")),
                    session.declare_subscriber(game_event_key("default"), on("event"))]
            next_burst, next_rss, n_burst = args.burst_every, 0.0, 0
            while (now := time.monotonic() - t_start) < duration:
                if now >= next_rss:
                    rss_t.append(now / 60.0)
                    for k, p in procs.items():
                        rss[k].append(_rss_mb(p.pid) if p.poll() is None else float("nan"))
                    next_rss += 10.0
                if now >= next_burst and now + args.burst_s < duration - 5.0:
                    key = pose_key(TID) if n_burst % 2 == 0 else body_key(TID)
                    cmd = [sys.executable, "-m", "protocol", "fuzz", "--key", key, "--rate", "100", "--duration",
                           str(args.burst_s), "--seed", str(n_burst), "-q", *net]
                    b0 = time.monotonic() - t_start
                    if args.fuzz_session == "new":
                        subprocess.run(cmd, cwd=ROOT, capture_output=True, check=False, timeout=args.burst_s + 60)
                    else:
                        _burst_from(session, key, args.burst_s, n_burst)
                    bursts.append((b0, time.monotonic() - t_start, key.rsplit("/", 1)[-1]))
                    next_burst += args.burst_every
                    n_burst += 1
                time.sleep(0.2)
            for sub in subs:
                undeclare_quietly(sub)
            subs = []
    finally:
        alive = {k: p.poll() is None for k, p in procs.items()}
        summaries: dict[str, Any] = {}
        for k in ("game", "cloth", "replay", "router"):
            p = procs[k]
            if p.poll() is None:
                p.terminate()
            try:
                out, _ = p.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
                out, _ = p.communicate()
            if k in ("game", "cloth") and out.strip():
                try:
                    summaries[k] = json.loads(out.decode().strip().splitlines()[-1])
                except (ValueError, IndexError):
                    summaries[k] = {"unparsed": out.decode()[-300:]}
    secs = int(duration)

    def in_burst(s: float, pad: float = 0.0) -> bool:
        return any(b0 - pad <= s < b1 + pad for b0, b1, _ in bursts)

    report: dict[str, Any] = {"alive_at_end": alive, "bursts": len(bursts), "summaries": summaries}
    for kind in ("state", "mesh"):
        rate = np.array([counts[kind][s] for s in range(secs)], np.float64)
        quiet = np.array([not in_burst(s, 2.0) for s in range(secs)]) & (np.arange(secs) >= 30)
        usual = float(np.median(rate[quiet])) if quiet.any() else float("nan")
        during = [rate[int(b0):int(b1) + 1].min() for b0, b1, _ in bursts if int(b1) + 1 <= secs]
        back = []
        for _, b1, _ in bursts:
            s = int(np.ceil(b1))
            while s < secs and rate[s] < 0.9 * usual:
                s += 1
            back.append(s - b1)
        back_slide = [_recovery_sliding(arrivals[kind], b1, usual) for _, b1, _ in bursts]
        report[kind] = {"usual_hz": usual, "lowest_in_bursts_hz": float(min(during)) if during else None,
                        "slowest_recovery_s": round(float(max(back)), 2) if back else None,
                        "slowest_recovery_sliding_s": _finite(max(back_slide)) if back_slide else None,
                        "recovery_sliding_s": [_finite(b) for b in back_slide],
                        "longest_gap_after_burst_s": [round(_longest_gap(arrivals[kind], b1, 3.0), 2)
                                                      for _, b1, _ in bursts]}
    ev_in = sum(1 for t, _ in events if in_burst(t))
    burst_s = sum(b1 - b0 for b0, b1, _ in bursts)
    report["events"] = {"outside_bursts": dict(Counter(n for t, n in events if not in_burst(t))),
                        "in_bursts": dict(Counter(n for t, n in events if in_burst(t)))}
    quiet_min = max(duration - burst_s, 1.0) / 60.0
    report["events_per_min"] = {"outside_bursts": round((len(events) - ev_in) / quiet_min, 2),
                                "in_bursts": round(60.0 * ev_in / max(burst_s, 1e-9), 2) if bursts else None}
    report["rss_series_mb"] = {"t_min": [round(t, 3) for t in rss_t],
                               **{k: [round(x, 1) for x in v] for k, v in rss.items()}}
    # after the first burst's end: a session's first large messages cost Zenoh a one-time step
    second = (bursts[0][1] / 60.0 + 0.25) if bursts else 1.0
    report["rss_mb"] = {k: {"after_1_min": round(float(np.interp(1.0, rss_t, v)), 1),
                            "end": round(float(v[-1]), 1), "slope_mb_per_min": round(_slope(rss_t, v), 3),
                            "slope_after_first_burst_mb_per_min": round(_slope(rss_t, v, second), 3)}
                        for k, v in rss.items() if v}
    lines = ["| process | memory after 1 min | at the end | slope MB/min | slope after the first burst "
             "| running at the end |", "|---|---|---|---|---|---|"]
    for k, v in report["rss_mb"].items():
        lines.append(f"| {k} | {v['after_1_min']} MB | {v['end']} MB | {v['slope_mb_per_min']:+.3f} | "
                     f"{v['slope_after_first_burst_mb_per_min']:+.3f} | {'yes' if alive[k] else 'NO'} |")
    lines += ["", "| stream | usual rate | lowest 1 s during bursts | slowest recovery after a burst: whole "
              "seconds / sliding second | longest gap in the 3 s after a burst |", "|---|---|---|---|---|"]
    for kind, name in (("state", "game state"), ("mesh", "cloth mesh")):
        r = report[kind]
        lines.append(f"| {name} | {r['usual_hz']:.0f} Hz | {r['lowest_in_bursts_hz']} Hz | "
                     f"{r['slowest_recovery_s']} s / {r['slowest_recovery_sliding_s']} s | "
                     f"{max(r['longest_gap_after_burst_s'], default=float('nan'))} s |")
    loop_s = load_motion(ROUND, fps=30.0).n_frames / 30.0
    loops = duration / loop_s
    per_loop = {k: round(v / loops, 2) for k, v in sorted(Counter(n for _, n in events).items())}
    report["events_per_loop"] = per_loop
    lines += ["", f"game events per loop of the {loop_s:.1f} s round script ({loops:.1f} loops; the script "
              "performs transform, crouch, strike, side_step and fire_ring once, and the loop's jump back to "
              "the start reads as one more side_step): " + ", ".join(f"{k} {v}" for k, v in per_loop.items())]
    lines += ["", f"{len(bursts)} bursts; game events per minute outside bursts "
              f"{report['events_per_min']['outside_bursts']}, in bursts {report['events_per_min']['in_bursts']}"]
    meta = bench_meta("bench_soak.py", t0, minutes=args.minutes, burst_every_s=args.burst_every,
                      burst_s=args.burst_s, fuzz_session=args.fuzz_session)
    (logs / "soak.json").write_text(json.dumps({"meta": meta, **report}, indent=1, default=str))
    (logs / "soak.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0 if all(alive.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
