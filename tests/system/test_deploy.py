"""Multi-host deployment (docs/DEPLOY.md, deploy/): ``mocap-router``, clients through it, and the sample
TLS / mutual-TLS / user-password / access-control configs, all on 127.0.0.1.

Certificates are made per module with ``deploy/make-certs.sh`` (the openssl command line): a CA, a
router certificate for localhost/127.0.0.1, client certificates "tracker", "game", "cloth", one
"intruder" signed by the same CA but unknown to the access-control rules, and a second, rogue CA
with its own "tracker" and "game". The sample files' placeholders (@SECRETS@, @NAME@, @ROUTER@,
@PASSWORD@) are filled in as docs/DEPLOY.md tells a user to.

Every router is a subprocess stopped with SIGINT (and killed in ``finally``); clients are in-process
client-mode sessions closed by ``with``; subscribers use channel handlers except the latency test's,
which is undeclared in ``finally``. Negative checks wait a bounded time, with a positive control in
the same window where one exists.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import zenoh
from child_process import Proc, child_env

from protocol.net.router import build_parser, router_config
from protocol.net.session import build_config, free_tcp_endpoint, undeclare_quietly
from protocol.wire.keys import DEFAULT_ENDPOINT, game_event_key, pose_key

pytestmark = pytest.mark.zenoh

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"
_BIN = Path(sys.executable).parent
ROUTER = [str(_BIN / "mocap-router")] if (_BIN / "mocap-router").is_file() else [
    sys.executable, "-m", "protocol.net.router"]
TRACKER = [str(_BIN / "mocap-tracker")] if (_BIN / "mocap-tracker").is_file() else [
    sys.executable, "-m", "tracker_service"]
ECHO = [sys.executable, "-m", "protocol", "echo"]
PASSWORDS = {"tracker": "tracker-secret-1", "game": "game-secret-2"}


# --- processes -------------------------------------------------------------------------------------


@contextmanager
def running_router(*args: str, endpoint: str) -> Iterator[Proc]:
    """``mocap-router ARGS --listen ENDPOINT``, ready (it logged its endpoint); SIGINT on exit, which
    must stop it with status 0 (within 2 s on an idle machine; the bound here allows a loaded one)."""
    proc = Proc([*ROUTER, *args, "--listen", endpoint])
    try:
        assert proc.wait_for(f"listening on {endpoint}"), "router did not start:\n" + "\n".join(proc.err)
        yield proc
        rc, took = proc.stop(signal.SIGINT, timeout=15.0)
        assert rc == 0, f"router stop: rc={rc} after {took:.2f} s\n" + "\n".join(proc.err)
    finally:
        proc.kill()


# --- certificates and sample configs ----------------------------------------------------------------


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """``{"good": folder, "rogue": folder}`` made by deploy/make-certs.sh, plus credentials.txt."""
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command line is not installed")
    root = tmp_path_factory.mktemp("pki")
    good, rogue = root / "secrets", root / "rogue"
    script = str(DEPLOY / "make-certs.sh")
    for argv in ([script, "-d", "2", str(good)], [script, "-d", "2", "-c", "intruder", str(good)],
                 [script, "-d", "2", "-c", "tracker game", str(rogue)]):
        subprocess.run(argv, check=True, capture_output=True, timeout=30)
    (good / "credentials.txt").write_text("".join(f"{u}:{p}\n" for u, p in PASSWORDS.items()))
    return {"good": good, "rogue": rogue}


def fill(sample: str, out: Path, **values: str) -> Path:
    """``deploy/SAMPLE`` with ``@KEY@`` replaced by ``values[key]`` (lower-case keys), written to ``out``."""
    text = (DEPLOY / sample).read_text()
    for key, value in values.items():
        text = text.replace(f"@{key.upper()}@", value)
    assert "@" not in "".join(line.split("//")[0] for line in text.splitlines()), f"unfilled placeholder in {out}"
    out.write_text(text)
    return out


def try_client(config_file: Path | None, endpoint: str, role: str = "subscriber") -> zenoh.Session | None:
    """A client-mode session on ``endpoint`` with ``config_file``, or None if it cannot connect."""
    conf = build_config("publisher" if role == "publisher" else "subscriber", mode="client", connect=[endpoint],
                        config_file=config_file)
    try:
        return zenoh.open(conf)
    except zenoh.ZError:
        return None


@contextmanager
def clients(*specs: tuple[Path | None, str]) -> Iterator[list[zenoh.Session | None]]:
    """Open one client per ``(config_file, endpoint)``; close the opened ones on exit."""
    opened: list[zenoh.Session | None] = []
    try:
        for config_file, endpoint in specs:
            opened.append(try_client(config_file, endpoint))
        yield opened
    finally:
        for session in opened:
            if session is not None:
                session.close()


def exchange(pairs: list[tuple[zenoh.Session | None, str, zenoh.Session | None, str]],
             n: int = 5, expect: int | None = None, timeout: float = 3.0) -> list[int]:
    """For each ``(publisher, key, subscriber, key_expr)``: subscribe, then put ``n`` messages, all pairs
    in the same time window; return how many each subscriber received. Waits until every pair whose
    count must reach ``expect`` has it (or ``timeout``), and at least 1 s in all."""
    subs = [s.declare_subscriber(ke, zenoh.handlers.FifoChannel(1000)) if s is not None else None
            for _, _, s, ke in pairs]
    try:
        time.sleep(0.6)  # declarations travel subscriber -> router -> publisher
        for i in range(n):
            for pub, key, _, _ in pairs:
                if pub is not None:
                    pub.put(key, b"msg %d" % i)
            time.sleep(0.005)
        counts = [0] * len(pairs)
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            for i, sub in enumerate(subs):
                while sub is not None and sub.try_recv() is not None:
                    counts[i] += 1
            if time.monotonic() - t0 >= 1.0 and (expect is None or expect in counts):
                break
            time.sleep(0.02)
        return counts
    finally:
        undeclare_quietly(*subs)


# --- mocap-router itself -----------------------------------------------------------------------------


def test_help_says_how_to_listen_on_the_lan_and_version() -> None:
    text = build_parser().format_help()
    assert DEFAULT_ENDPOINT in text and "tcp/0.0.0.0:7447" in text and "--mode client --connect" in text
    out = subprocess.run([*ROUTER, "--version"], capture_output=True, text=True, timeout=20, env=child_env(), cwd=REPO)
    assert out.returncode == 0 and out.stdout.startswith("mocap-router ") and "zenoh" in out.stdout


def test_console_script_is_declared() -> None:
    import tomllib

    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["mocap-router"] == "protocol.net.router:main"


def test_router_config_defaults_and_precedence(tmp_path: Path) -> None:
    conf = router_config()
    get = lambda c, k: json.loads(c.get_json(k))  # noqa: E731
    assert get(conf, "mode") == "router"
    assert get(conf, "listen/endpoints") == [DEFAULT_ENDPOINT]
    assert get(conf, "connect/endpoints") == []
    assert get(conf, "scouting/multicast/enabled") is False
    f = tmp_path / "r.json5"
    f.write_text('{ mode: "peer", listen: { endpoints: ["tcp/127.0.0.1:7999"] } }')
    assert get(router_config(config_file=str(f)), "listen/endpoints") == ["tcp/127.0.0.1:7999"]
    assert get(router_config(config_file=str(f)), "mode") == "router"
    assert get(router_config(["tcp/127.0.0.1:7998"], str(f)), "listen/endpoints") == ["tcp/127.0.0.1:7998"]


def test_client_mode_publisher_connects_and_does_not_take_the_router_port() -> None:
    conf = build_config("publisher", mode="client")
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:0"]
    assert json.loads(conf.get_json("connect/endpoints")) == [DEFAULT_ENDPOINT]
    assert json.loads(build_config("publisher").get_json("listen/endpoints")) == [DEFAULT_ENDPOINT]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_router_routes_between_clients_and_stops_cleanly(sig: signal.Signals) -> None:
    ep = free_tcp_endpoint()
    proc = Proc([*ROUTER, "--listen", ep])
    try:
        assert proc.wait_for(f"listening on {ep}"), "\n".join(proc.err)
        with clients((None, ep), (None, ep)) as (pub, sub):
            assert pub is not None and sub is not None
            assert exchange([(pub, "mocap/tracker/t/pose", sub, "mocap/**")], expect=5) == [5]
        rc, took = proc.stop(sig, timeout=15.0)
        assert rc == 0, "\n".join(proc.err)
        assert took < 15.0  # (about 0.1 s on an idle machine: a clean stop, not a kill)
        assert any("shutting down" in line for line in proc.err)
    finally:
        proc.kill()


@pytest.mark.slow
def test_router_errors_exit_1(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: 42 }")
    ep = free_tcp_endpoint()
    with running_router(endpoint=ep):
        for argv in (["--config", str(tmp_path / "missing.json5")], ["--config", str(bad)], ["--listen", ep]):
            out = subprocess.run([*ROUTER, *argv], capture_output=True, text=True, timeout=20, env=child_env(),
                                 cwd=REPO)
            assert out.returncode == 1, (argv, out.stderr)
            assert "mocap-router:" in out.stderr


# --- TLS, mutual TLS, user/password, access control --------------------------------------------------


def _tls_endpoint() -> str:
    return "tls/" + free_tcp_endpoint().split("/", 1)[1]


@pytest.mark.slow
def test_tls_router_admits_clients_that_trust_its_ca_only(pki: dict[str, Path], tmp_path: Path) -> None:
    good, rogue = str(pki["good"]), str(pki["rogue"])
    router = fill("router-tls.json5", tmp_path / "router.json5", secrets=good)
    client = fill("client-tls.json5", tmp_path / "client.json5", secrets=good, router="127.0.0.1")
    wrong_ca = fill("client-tls.json5", tmp_path / "wrong.json5", secrets=rogue, router="127.0.0.1")
    ep = _tls_endpoint()
    with running_router("--config", str(router), endpoint=ep) as proc:
        assert any("TLS: server certificate only" in line for line in proc.err)
        with clients((client, ep), (client, ep), (wrong_ca, ep), (None, "tcp/" + ep.split("/", 1)[1])) as (
                pub, sub, bad, plain):
            assert pub is not None and sub is not None
            assert bad is None, "a client that does not trust the router's CA connected"
            assert plain is None, "a plain tcp client connected to the TLS port"
            assert exchange([(pub, "mocap/tracker/t/pose", sub, "mocap/**")], expect=5) == [5]


@pytest.mark.slow
def test_mutual_tls_router_refuses_clients_without_a_certificate_from_its_ca(
        pki: dict[str, Path], tmp_path: Path) -> None:
    good, rogue = str(pki["good"]), str(pki["rogue"])
    router = fill("router-mtls.json5", tmp_path / "router.json5", secrets=good)
    tracker = fill("client-mtls.json5", tmp_path / "tracker.json5", secrets=good, name="tracker", router="127.0.0.1")
    game = fill("client-mtls.json5", tmp_path / "game.json5", secrets=good, name="game", router="127.0.0.1")
    no_cert = fill("client-tls.json5", tmp_path / "nocert.json5", secrets=good, router="127.0.0.1")
    # trusts the right CA but presents a certificate of the rogue CA
    rogue_cert = fill("client-mtls.json5", tmp_path / "rogue.json5", secrets=good, name="game", router="127.0.0.1")
    rogue_cert.write_text(rogue_cert.read_text().replace(f"{good}/game.", f"{rogue}/game."))
    ep = _tls_endpoint()
    with running_router("--config", str(router), endpoint=ep) as proc:
        assert any("mutual TLS" in line for line in proc.err)
        with clients((tracker, ep), (game, ep), (no_cert, ep), (rogue_cert, ep)) as (t, g, nc, rc):
            assert t is not None and g is not None
            assert nc is None and rc is None, "a client without a certificate signed by the CA connected"
            assert exchange([(t, "mocap/tracker/t/pose", g, "mocap/**")], expect=5) == [5]


@pytest.mark.slow
def test_user_password_router_refuses_unknown_credentials(pki: dict[str, Path], tmp_path: Path) -> None:
    router = fill("router-usrpwd.json5", tmp_path / "router.json5", secrets=str(pki["good"]))
    tracker = fill("client-usrpwd.json5", tmp_path / "tracker.json5", name="tracker",
                   password=PASSWORDS["tracker"], router="127.0.0.1")
    game = fill("client-usrpwd.json5", tmp_path / "game.json5", name="game", password=PASSWORDS["game"],
                router="127.0.0.1")
    wrong = fill("client-usrpwd.json5", tmp_path / "wrong.json5", name="game", password="guess",
                 router="127.0.0.1")
    ep = free_tcp_endpoint()
    with running_router("--config", str(router), endpoint=ep) as proc:
        assert any("user/password authentication" in line for line in proc.err)
        with clients((tracker, ep), (game, ep), (wrong, ep), (None, ep)) as (t, g, w, anonymous):
            assert t is not None and g is not None
            assert w is None, "a client with a wrong password connected"
            assert anonymous is None, "a client without credentials connected"
            assert exchange([(t, "mocap/tracker/t/pose", g, "mocap/**")], expect=5) == [5]


@pytest.mark.slow
def test_access_control_only_the_owner_publishes_and_strangers_get_nothing(
        pki: dict[str, Path], tmp_path: Path) -> None:
    good = str(pki["good"])
    router = fill("router-acl.json5", tmp_path / "router.json5", secrets=good)
    files = {name: fill("client-mtls.json5", tmp_path / f"{name}.json5", secrets=good, name=name,
                        router="127.0.0.1") for name in ("tracker", "game", "cloth", "intruder")}
    ep = _tls_endpoint()
    tk, gk = pose_key("cam0"), game_event_key("g1")
    with running_router("--config", str(router), endpoint=ep) as proc:
        assert any("access control: 8 rules, 3 subjects, 3 policies, default deny" in line for line in proc.err)
        with clients(*((files[n], ep) for n in ("tracker", "game", "cloth", "intruder"))) as (t, g, c, x):
            assert None not in (t, g, c, x)  # the intruder's certificate is valid: ACL, not TLS, stops it
            # owners publish; everyone known may read; the intruder receives nothing (nothing in)
            assert exchange([(t, tk, g, "mocap/tracker/**"), (g, gk, t, "mocap/game/**"),
                             (None, "", c, "mocap/**"), (None, "", x, "mocap/**")], expect=10) == [5, 5, 10, 0]
            # nobody but the owner publishes on its keys, the intruder nowhere (nothing out)
            # (the intruder's puts would land in the first, second and last subscriber)
            assert exchange([(g, pose_key("fake"), t, "mocap/tracker/**"),
                             (t, game_event_key("fake"), g, "mocap/game/**"),
                             (x, pose_key("x"), None, ""), (x, game_event_key("x"), None, ""),
                             (x, "mocap/cloth/x/mesh", None, ""),
                             (c, "mocap/cloth/c/mesh", g, "mocap/cloth/**")], expect=5) == [0, 0, 0, 0, 0, 5]


# --- end to end through the router: PoseFrames and the router hop's latency ------------------------


def _latencies(pub_conf: zenoh.Config, sub_conf: zenoh.Config, n: int, period: float) -> tuple[np.ndarray, int]:
    """``n`` PoseFrames every ``period`` s through ``bench/bench_deploy.py``'s measurement: (the
    latencies' percentiles as an array [p50, p99, max] in ms, frames received)."""
    if str(REPO / "bench") not in sys.path:
        sys.path.insert(0, str(REPO / "bench"))
    from bench_deploy import latencies

    r = latencies(pub_conf, sub_conf, n, 1.0 / period)
    return np.array([r["p50_ms"], r["p99_ms"], r["max_ms"]]), int(r["received"])


@pytest.mark.slow
def test_pose_frames_through_the_router_and_the_hop_latency(capsys: pytest.CaptureFixture[str]) -> None:
    n, period = 200, 0.005
    ep = free_tcp_endpoint()
    with running_router(endpoint=ep):
        routed, n_routed = _latencies(build_config("publisher", mode="client", connect=[ep]),
                                      build_config("subscriber", mode="client", connect=[ep]), n, period)
    direct_ep = free_tcp_endpoint()
    direct, n_direct = _latencies(build_config("publisher", listen=[direct_ep]),
                                  build_config("subscriber", connect=[direct_ep]), n, period)
    with capsys.disabled():
        print(f"\n[router hop] {n_routed}/{n} PoseFrames client -> router -> client: p50 {routed[0]:.3f} ms, "
              f"p99 {routed[1]:.3f} ms, max {routed[2]:.3f} ms; direct peer -> peer: {n_direct}/{n}, "
              f"p50 {direct[0]:.3f} ms, p99 {direct[1]:.3f} ms")
    assert n_routed >= 0.95 * n and n_direct >= 0.95 * n
    assert routed[0] < 50.0 and routed[1] < 500.0  # loose: 2 busy cores


@pytest.mark.slow
def test_the_documented_lan_commands_work_on_loopback() -> None:
    """docs/DEPLOY.md's router set-up with its ports changed: router, tracker replay in client mode,
    echo in client mode."""
    ep = free_tcp_endpoint()
    with running_router(endpoint=ep):
        echo = Proc([*ECHO, "--id", "cam0", "--count", "20", "--timeout", "20", "--mode", "client", "--connect", ep])
        tracker = Proc([*TRACKER, "replay", "--synthetic-wave", "--rate", "60", "--frames", "20", "--id", "cam0",
                        "--wait-for-subscriber", "15", "--mode", "client", "--connect", ep])
        try:
            assert tracker.popen.wait(timeout=25) == 0, "\n".join(tracker.err)
            assert echo.popen.wait(timeout=25) == 0, "\n".join(echo.err)
            assert any("20 pose" in line for line in echo.err), echo.err
        finally:
            tracker.kill()
            echo.kill()


# --- shared memory: a stranger on the same host leaves nothing behind ---------------------------------

_STRANGER = """
import json, sys, time, zenoh
c = zenoh.Config()  # zenoh's defaults, shared memory on
for key, value in [("mode", '"client"'), ("connect/endpoints", json.dumps([sys.argv[1]])),
                   ("scouting/multicast/enabled", "false")]:
    c.insert_json5(key, value)
with zenoh.open(c) as s:
    for _ in range(6):
        s.put("mocap/test/shm", b"x" * 8000)  # over zenoh's 3,072-byte shared-memory threshold
        time.sleep(0.02)
    time.sleep(0.3)
"""


def _shm_mapped() -> tuple[int, int]:
    """(Zenoh shared-memory segments mapped into this process, its locked memory in kB)."""
    maps = sum(".zenoh" in line for line in Path("/proc/self/maps").read_text().splitlines())
    locked = next(int(line.split()[1]) for line in Path("/proc/self/status").read_text().splitlines()
                  if line.startswith("VmLck:"))
    return maps, locked


@pytest.mark.skipif(not Path("/proc/self/maps").is_file(), reason="reads /proc (Linux)")
def test_router_maps_no_strangers_shared_memory_and_receives_every_message() -> None:
    # eclipse-zenoh 1.6.2-1.10.2 maps and locks each same-host sender's 16 MiB pool for good (+19 MB a
    # session, upstream #2787) and, where it may not lock it, drops those messages: build_config turns
    # shared memory off, and the receiver's setting decides it whatever the sender's.
    endpoint = free_tcp_endpoint()
    before = _shm_mapped()
    with zenoh.open(router_config(listen=[endpoint])) as router:
        sub = router.declare_subscriber("mocap/test/**", zenoh.handlers.FifoChannel(100))
        try:
            for _ in range(2):  # two sessions, one after the other
                run = subprocess.run([sys.executable, "-c", _STRANGER, endpoint], capture_output=True,
                                     text=True, timeout=60, env=child_env())
                assert run.returncode == 0, run.stderr[-800:]
            time.sleep(0.2)
            got = 0
            while sub.try_recv() is not None:
                got += 1
            assert got == 12
            assert _shm_mapped() == before
        finally:
            undeclare_quietly(sub)
