"""Deployment benchmarks on loopback: PoseFrame latency through a router (plain TCP, TLS, mutual
TLS) at 30 and 60 Hz against peer to peer, and one tracker fanned out to many clients.

Usage::

    .venv/bin/python bench/bench_deploy.py [--frames N] [--tracker-frames 300] [--clients 100] [--procs 10] [--json]

* **Latency**: a publisher and a subscriber session in one process (``time.perf_counter`` on both
  sides), each a client of ``mocap-router`` started with the sample configs of ``deploy/`` filled in
  (certificates from ``deploy/make-certs.sh`` in a temporary folder); ``N`` encoded PoseFrames
  (933 bytes) at 30 and 60 Hz. The tracker's own time from capture to publishing is its frame time
  (``docs/BENCHMARKS.md``, tracker speed); this measures publish -> client.
* **End to end**: the real tracker (``mocap-tracker run``, the synthetic scene of the game's winning
  round rendered at 30 and 60 Hz, ``--tracker-frames`` frames) a TLS client of the router, a TLS
  subscriber receiving: capture -> client from each pose's ``capture_wall_ts``.
* **Fan-out**: ``--clients`` subscriber sessions in ``--procs`` processes, all clients of one TLS
  router, receiving one publisher at 30 Hz; per client the fraction received and the latency
  (wall clock, the same machine), and the publisher's ``put`` time with and without them (what
  the tracker's frame loop pays).

Needs the ``openssl`` command line. Not a test: it takes a minute or two.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from _host import host_probe  # bench/ is the script's folder

from protocol.net.session import build_config, free_tcp_endpoint, open_session, undeclare_quietly
from protocol.skeleton import N_JOINTS, N_PARTS, POSE_SIZE
from protocol.wire.codec import decode, encode
from protocol.wire.keys import pose_key
from protocol.wire.messages import PoseFrame
from tracker_service.app.replay_daemon import has_subscriber

ROOT = Path(__file__).resolve().parent.parent
DEPLOY = ROOT / "deploy"
KEY = pose_key("cam0")
#: The tracked motion of the end-to-end rows: the game's winning round (all five gestures).
SCRIPT = ROOT / "game_client" / "scripts" / "round_win.toml"


def pose_frame(seq: int) -> PoseFrame:
    """A PoseFrame of the usual size, stamped now."""
    now = time.time()
    return PoseFrame(tracker_id="cam0", seq=seq, capture_ts=seq / 30.0, publish_ts=now, capture_wall_ts=now,
                     pose=np.linspace(-1.0, 1.0, POSE_SIZE, dtype=np.float32),
                     joints=(np.arange(N_JOINTS * 3).reshape(N_JOINTS, 3) * 0.01).astype(np.float32),
                     visibility=np.linspace(0.0, 1.0, N_PARTS, dtype=np.float32), confidence=0.75, estimator="tree",
                     body_model="mMA")


def fill(sample: str, out: Path, **values: str) -> Path:
    """``deploy/SAMPLE`` with ``@KEY@`` replaced by ``values[key]``."""
    text = (DEPLOY / sample).read_text()
    for key, value in values.items():
        text = text.replace(f"@{key.upper()}@", value)
    out.write_text(text)
    return out


class Router:
    """``mocap-router`` in a child process, ready once it logs its endpoint."""

    def __init__(self, endpoint: str, config: Path | None) -> None:
        argv = [sys.executable, "-m", "protocol.net.router", "--listen", endpoint]
        if config is not None:
            argv += ["--config", str(config)]
        self.proc = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True, cwd=ROOT)
        deadline = time.monotonic() + 20
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            if "listening on" in line or time.monotonic() > deadline:
                break

    def close(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def latencies(pub_conf: zenoh.Config, sub_conf: zenoh.Config, n: int, rate: float) -> dict[str, Any]:
    """``n`` PoseFrames at ``rate`` Hz from one session to another: latency percentiles (ms)."""
    sent: dict[int, float] = {}
    got: list[tuple[float, bytes]] = []

    def on_sample(sample: zenoh.Sample) -> None:
        got.append((time.perf_counter(), sample.payload.to_bytes()))

    with open_session(sub_conf) as sub_s, open_session(pub_conf) as pub_s, ExitStack() as undo:
        sub = sub_s.declare_subscriber(KEY, on_sample)
        undo.callback(undeclare_quietly, sub)
        pub = pub_s.declare_publisher(KEY)
        undo.callback(undeclare_quietly, pub)
        deadline = time.monotonic() + 5.0
        while not has_subscriber(pub) and time.monotonic() < deadline:
            time.sleep(0.01)
        nxt = time.perf_counter()
        for i in range(n):
            time.sleep(max(0.0, nxt - time.perf_counter()))
            payload = encode(pose_frame(i))
            sent[i] = time.perf_counter()
            pub.put(payload)
            nxt += 1.0 / rate
        deadline = time.monotonic() + 3.0
        while len(got) < n and time.monotonic() < deadline:
            time.sleep(0.01)
        undeclare_quietly(sub)
    lat = np.array([(t - sent[decode(p, PoseFrame).seq]) * 1e3 for t, p in list(got)])
    return {"received": len(got), "sent": n, **_pct(lat)}


def end_to_end(endpoint: str, pub_config: Path | None, sub_conf: zenoh.Config, rate: float,
               frames: int) -> dict[str, Any]:
    """The real tracker (``mocap-tracker run`` in a child process, the synthetic scene rendered at
    ``rate`` Hz, ``frames`` frames) as a client of the router: capture -> client latency of every
    pose received, from ``PoseFrame.capture_wall_ts`` (the same machine's wall clock), and the
    rate the poses arrived at."""
    tid = f"e2e{rate:.0f}"
    got: list[tuple[float, float]] = []

    def on_sample(sample: zenoh.Sample) -> None:
        now = time.time()
        f = decode(sample.payload.to_bytes(), PoseFrame)
        got.append((now, (now - f.capture_wall_ts) * 1e3))

    cmd = [sys.executable, "-m", "tracker_service", "run", "--source", f"synthetic:{SCRIPT}", "--fps", str(rate),
           "--frames", str(frames), "--id", tid, "--mode", "client", "--connect", endpoint,
           "--wait-for-subscriber", "120", "-q"] + (["--config", str(pub_config)] if pub_config else [])
    with open_session(sub_conf) as s:
        sub = s.declare_subscriber(pose_key(tid), on_sample)
        try:
            proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
            time.sleep(0.5)
        finally:
            undeclare_quietly(sub)
    if proc.returncode != 0:
        raise RuntimeError(f"the tracker failed: {proc.stderr[-2000:]}")
    lat = np.array([ms for _, ms in got])
    span = got[-1][0] - got[0][0] if len(got) > 1 else float("nan")
    return {"received": len(got), "sent": frames, "poses_per_s": round((len(got) - 1) / span, 1), **_pct(lat)}


def _pct(ms: np.ndarray) -> dict[str, float]:
    if not len(ms):
        return {"p50_ms": float("nan"), "p99_ms": float("nan"), "max_ms": float("nan")}
    return {"p50_ms": round(float(np.percentile(ms, 50)), 3), "p99_ms": round(float(np.percentile(ms, 99)), 3),
            "max_ms": round(float(ms.max()), 3)}


_CLIENT = r'''
import json, sys, time, zenoh, numpy as np
sys.path.insert(0, sys.argv[1])
from protocol.net.session import build_config, open_session, undeclare_quietly
from protocol.wire.codec import decode
from protocol.wire.messages import PoseFrame
ep, cfg, n_sessions, seconds, key = sys.argv[2], sys.argv[3] or None, int(sys.argv[4]), float(sys.argv[5]), sys.argv[6]
stats = []
sessions, subs = [], []
for _ in range(n_sessions):
    s = zenoh.open(build_config("subscriber", mode="client", connect=[ep], config_file=cfg))
    rec = {"n": 0, "lat": []}
    def cb(sample, rec=rec):
        f = decode(sample.payload.to_bytes(), PoseFrame)
        rec["n"] += 1
        rec["lat"].append((time.time() - f.publish_ts) * 1e3)
    sessions.append(s); subs.append(s.declare_subscriber(key, cb)); stats.append(rec)
print("ready", flush=True)
time.sleep(seconds)
undeclare_quietly(*subs)
for s in sessions:
    s.close()
print(json.dumps([{"n": r["n"], "lat": r["lat"]} for r in stats]), flush=True)
'''


def fan_out(endpoint: str, pub_conf: zenoh.Config, client_conf: Path | None, clients: int, procs: int,
            seconds: float, rate: float = 30.0) -> dict[str, Any]:
    """``clients`` subscribers in ``procs`` processes on one router; the publisher's put times."""

    def publish(n: int) -> np.ndarray:
        with open_session(pub_conf) as s:
            pub = s.declare_publisher(KEY)
            try:
                time.sleep(1.0)
                put_ms = []
                nxt = time.perf_counter()
                for i in range(n):
                    time.sleep(max(0.0, nxt - time.perf_counter()))
                    payload = encode(pose_frame(i))
                    t0 = time.perf_counter()
                    pub.put(payload)
                    put_ms.append((time.perf_counter() - t0) * 1e3)
                    nxt += 1.0 / rate
            finally:
                undeclare_quietly(pub)
        return np.asarray(put_ms)

    n = int(seconds * rate)
    alone = publish(n)
    per = max(1, clients // procs)
    children = [subprocess.Popen([sys.executable, "-c", _CLIENT, str(ROOT), endpoint, str(client_conf or ""), str(per),
                                  str(seconds + 6.0), KEY], stdout=subprocess.PIPE, text=True)
                for _ in range(procs)]
    for c in children:
        assert c.stdout is not None
        c.stdout.readline()  # "ready"
    time.sleep(1.0)
    loaded = publish(n)
    recs: list[dict[str, Any]] = []
    for c in children:
        out, _ = c.communicate(timeout=120)
        recs += json.loads(out.strip().splitlines()[-1])
    frac = np.array([r["n"] / n for r in recs])
    lat = np.concatenate([np.asarray(r["lat"]) for r in recs if r["lat"]]) if recs else np.zeros(0)
    return {"clients": len(recs), "frames": n, "received_min": round(float(frac.min()), 3) if len(frac) else 0.0,
            "received_mean": round(float(frac.mean()), 3) if len(frac) else 0.0, **_pct(lat),
            "put_ms_alone": _pct(alone), "put_ms_with_clients": _pct(loaded)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300, help="PoseFrames per latency run (default 300)")
    ap.add_argument("--clients", type=int, default=100)
    ap.add_argument("--procs", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=10.0, help="fan-out duration (default 10 s)")
    ap.add_argument("--tracker-frames", type=int, default=300,
                    help="frames of the real tracker's end-to-end rows (0: skip them)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    t0 = time.time()
    rows: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        secrets = Path(tmp) / "secrets"
        subprocess.run([str(DEPLOY / "make-certs.sh"), "-d", "2", str(secrets), "127.0.0.1"], check=True,
                       capture_output=True, timeout=60)
        s = str(secrets)
        router_cfg = {"tcp": None, "tls": fill("router-tls.json5", Path(tmp) / "router-tls.json5", secrets=s),
                      "mtls": fill("router-mtls.json5", Path(tmp) / "router-mtls.json5", secrets=s)}
        client_cfg = {"tcp": (None, None),
                      "tls": (fill("client-tls.json5", Path(tmp) / "c1.json5", secrets=s, router="127.0.0.1"),) * 2,
                      "mtls": (fill("client-mtls.json5", Path(tmp) / "c2.json5", secrets=s, router="127.0.0.1",
                                    name="tracker"),
                               fill("client-mtls.json5", Path(tmp) / "c3.json5", secrets=s, router="127.0.0.1",
                                    name="game"))}
        for link in ("tcp", "tls", "mtls"):
            ep = free_tcp_endpoint() if link == "tcp" else free_tcp_endpoint().replace("tcp/", "tls/")
            router = Router(ep, router_cfg[link])
            try:
                pc, sc = client_cfg[link]
                for rate in (30.0, 60.0):
                    rows[f"router {link} {rate:.0f} Hz"] = latencies(
                        build_config("publisher", mode="client", connect=[ep], config_file=pc),
                        build_config("subscriber", mode="client", connect=[ep], config_file=sc), args.frames, rate)
                if link == "tls" and args.tracker_frames > 0:
                    for rate in (30.0, 60.0):
                        rows[f"tracker -> router tls -> client {rate:.0f} Hz"] = end_to_end(
                            ep, pc, build_config("subscriber", mode="client", connect=[ep], config_file=sc), rate,
                            args.tracker_frames)
                if link == "tls":
                    rows["fan-out tls 30 Hz"] = fan_out(ep, build_config("publisher", mode="client", connect=[ep],
                                                                         config_file=pc), sc, args.clients,
                                                        args.procs, args.seconds)
            finally:
                router.close()
        for rate in (30.0, 60.0):
            direct = free_tcp_endpoint()
            rows[f"peer to peer tcp {rate:.0f} Hz"] = latencies(build_config("publisher", listen=[direct]),
                                                               build_config("subscriber", connect=[direct]),
                                                               args.frames, rate)
    meta = {"command": "bench/bench_deploy.py " + " ".join(sys.argv[1:]), "date": time.strftime("%Y-%m-%d"),
            "machine": platform.machine(), "host": host_probe(), "wall_s": round(time.time() - t0)}
    if args.json:
        print(json.dumps({"meta": meta, "rows": rows}))
        return 0
    print("| path | received | p50 ms | p99 ms | max ms | poses/s |\n|---|---|---|---|---|---|")
    for name, r in rows.items():
        if name.startswith("fan-out"):
            continue
        print(f"| {name} | {r['received']}/{r['sent']} | {r['p50_ms']} | {r['p99_ms']} | {r['max_ms']} "
              f"| {r.get('poses_per_s', '')} |")
    f = rows.get("fan-out tls 30 Hz")
    if f:
        print(f"\nfan-out: {f['clients']} TLS clients, {f['frames']} frames at 30 Hz: received min "
              f"{f['received_min']}, mean {f['received_mean']}; latency p50 {f['p50_ms']} ms, p99 {f['p99_ms']} ms; "
              f"publisher put() p50/p99 {f['put_ms_alone']['p50_ms']}/{f['put_ms_alone']['p99_ms']} ms alone, "
              f"{f['put_ms_with_clients']['p50_ms']}/{f['put_ms_with_clients']['p99_ms']} ms with the clients")
    print(json.dumps(meta))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
