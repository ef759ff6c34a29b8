"""Key expressions and id validation, zenoh config building, signal helper, recordings folder."""

from __future__ import annotations

import argparse
import json
import os
import signal
import threading
from pathlib import Path

import pytest
import zenoh

from protocol.formats.mocap_data import ENV_VAR, index_entries, mocap_root, recording_path
from protocol.net.session import (
    add_zenoh_args,
    build_config,
    config_from_args,
    free_tcp_endpoint,
    stop_on_signals,
)
from protocol.wire import keys as keys
from protocol.wire.keys import (
    ALL_ALIVE,
    ALL_BODIES,
    ALL_POSES,
    ALL_STATUS,
    ANY,
    DEFAULT_ENDPOINT,
    KeyParts,
    alive_key,
    body_key,
    cloth_mesh_key,
    game_event_key,
    game_state_key,
    pose_key,
    split_key,
    status_key,
    validate_id,
)

# ------------------------------------------------------------------------------------------ keys


def test_key_builders() -> None:
    assert pose_key("cam0") == "mocap/tracker/cam0/pose"
    assert body_key("cam0") == "mocap/tracker/cam0/body"
    assert status_key("cam0") == "mocap/tracker/cam0/status"
    assert alive_key("cam0") == "mocap/tracker/cam0/alive"
    assert game_event_key("g-1") == "mocap/game/g-1/event"
    assert game_state_key("g_1") == "mocap/game/g_1/state"
    assert cloth_mesh_key("C9") == "mocap/cloth/C9/mesh"
    assert DEFAULT_ENDPOINT == "tcp/127.0.0.1:7447"


def test_wildcards_are_valid_and_match() -> None:
    assert ALL_POSES == pose_key(ANY) == "mocap/tracker/*/pose"
    assert (ALL_BODIES, ALL_STATUS, ALL_ALIVE) == (
        "mocap/tracker/*/body", "mocap/tracker/*/status", "mocap/tracker/*/alive")
    assert zenoh.KeyExpr(ALL_POSES).includes(pose_key("some-tracker_1"))
    assert not zenoh.KeyExpr(ALL_POSES).intersects(status_key("x"))
    for k in (pose_key("a"), game_event_key("b"), cloth_mesh_key("c"), ALL_STATUS):
        assert str(zenoh.KeyExpr(k)) == k  # canonical zenoh key expressions


@pytest.mark.parametrize("good", ["a", "cam0", "A_b-9", "x" * 64])
def test_validate_id_accepts(good: str) -> None:
    assert validate_id(good) == good


@pytest.mark.parametrize("bad", ["", "x" * 65, "a/b", "*", "**", "a b", "caméra", "a.b", "$x"])
def test_validate_id_rejects(bad: str) -> None:
    with pytest.raises(ValueError, match="invalid id"):
        validate_id(bad)
    if bad != ANY:  # the builders accept "*" on purpose (subscriber wildcard)
        with pytest.raises(ValueError, match="invalid id"):
            pose_key(bad)


def test_validate_id_wildcard_only_when_allowed() -> None:
    assert validate_id("*", allow_any=True) == "*"
    with pytest.raises(ValueError, match=r"or '\*' for any"):
        validate_id("a/b", allow_any=True)


def test_validate_id_non_string() -> None:
    with pytest.raises(ValueError, match="must be a string"):
        validate_id(7)  # type: ignore[arg-type]


def test_split_key_round_trip_and_errors() -> None:
    assert split_key(pose_key("t1")) == KeyParts("tracker", "t1", "pose")
    assert split_key(game_state_key("g")) == KeyParts("game", "g", "state")
    assert split_key(cloth_mesh_key("c")).leaf == "mesh"
    for bad in ("mocap/tracker/t1", "other/tracker/t1/pose", "mocap/tracker/t1/mesh",
                "mocap/tracker/*/pose", "mocap/robot/t1/pose", "mocap/tracker/t1/pose/x"):
        with pytest.raises(ValueError):
            split_key(bad)


def test_keys_module_does_not_import_zenoh() -> None:
    assert "zenoh" not in vars(keys)


# --------------------------------------------------------------------------------------- session


def _get(conf: zenoh.Config, key: str) -> object:
    return json.loads(conf.get_json(key))


def test_publisher_defaults() -> None:
    conf = build_config("publisher")
    assert _get(conf, "mode") == "peer"
    assert _get(conf, "scouting/multicast/enabled") is False
    assert _get(conf, "listen/endpoints") == [DEFAULT_ENDPOINT]
    assert _get(conf, "connect/endpoints") == []


def test_subscriber_defaults_are_loopback() -> None:
    conf = build_config("subscriber")
    assert _get(conf, "mode") == "peer"
    assert _get(conf, "scouting/multicast/enabled") is False
    assert _get(conf, "connect/endpoints") == [DEFAULT_ENDPOINT]
    assert _get(conf, "listen/endpoints") == ["tcp/127.0.0.1:0"]


@pytest.mark.parametrize("role", ["publisher", "subscriber"])
def test_shared_memory_is_off_unless_a_config_file_turns_it_on(role: str, tmp_path: Path) -> None:
    # eclipse-zenoh 1.6.2-1.10.2 keeps every peer's pool mapped and locked (+19 MB a session)
    assert _get(build_config(role), "transport/shared_memory/enabled") is False  # type: ignore[arg-type]
    assert _get(build_config(role, mode="router"), "transport/shared_memory/enabled") is False  # type: ignore[arg-type]
    cfg = tmp_path / "shm.json5"
    cfg.write_text("{ transport: { shared_memory: { enabled: true } } }\n")
    assert _get(build_config(role, config_file=cfg), "transport/shared_memory/enabled") is True  # type: ignore[arg-type]


def test_explicit_options_replace_defaults() -> None:
    conf = build_config("subscriber", mode="client", connect=["tcp/127.0.0.1:9000", "tcp/127.0.0.1:9001"],
                        listen=[])
    assert _get(conf, "mode") == "client"
    assert _get(conf, "connect/endpoints") == ["tcp/127.0.0.1:9000", "tcp/127.0.0.1:9001"]
    assert _get(conf, "listen/endpoints") == []


def test_bad_values_raise_value_error() -> None:
    with pytest.raises(ValueError, match="mode"):
        build_config("publisher", mode="bogus")
    with pytest.raises(ValueError, match="connect/endpoints"):
        build_config("subscriber", connect=["not-an-endpoint"])
    with pytest.raises(ValueError, match="role"):
        build_config("router")  # type: ignore[arg-type]


def test_config_file_settings_win_over_defaults_and_flags_over_file(tmp_path: Path) -> None:
    cfg = tmp_path / "z.json5"
    cfg.write_text('{ mode: "client", connect: { endpoints: ["tcp/127.0.0.1:1234"] },\n'
                   '  scouting: { multicast: { enabled: true } } }\n')
    conf = build_config("subscriber", config_file=cfg)
    assert _get(conf, "mode") == "client"
    assert _get(conf, "connect/endpoints") == ["tcp/127.0.0.1:1234"]
    assert _get(conf, "scouting/multicast/enabled") is True
    assert _get(conf, "listen/endpoints") == ["tcp/127.0.0.1:0"]  # not in the file: our default
    conf = build_config("subscriber", config_file=cfg, mode="peer", connect=["tcp/127.0.0.1:5678"])
    assert _get(conf, "mode") == "peer"
    assert _get(conf, "connect/endpoints") == ["tcp/127.0.0.1:5678"]


def test_config_file_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="zenoh config file not found"):
        build_config("publisher", config_file=tmp_path / "missing.json5")
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: 42 }")
    with pytest.raises(ValueError, match="zenoh rejected config file"):
        build_config("publisher", config_file=bad)


def test_add_zenoh_args_round_trip(tmp_path: Path) -> None:
    parser = argparse.ArgumentParser()
    add_zenoh_args(parser, "publisher")
    assert DEFAULT_ENDPOINT in parser.format_help()
    args = parser.parse_args([])
    assert args.zenoh_role == "publisher"
    assert _get(config_from_args(args), "listen/endpoints") == [DEFAULT_ENDPOINT]
    args = parser.parse_args(["--listen", "tcp/127.0.0.1:7000", "--listen", "tcp/127.0.0.1:7001",
                              "--connect", "tcp/127.0.0.1:7002", "--mode", "client"])
    conf = config_from_args(args)
    assert _get(conf, "listen/endpoints") == ["tcp/127.0.0.1:7000", "tcp/127.0.0.1:7001"]
    assert _get(conf, "connect/endpoints") == ["tcp/127.0.0.1:7002"]
    assert _get(conf, "mode") == "client"
    assert _get(config_from_args(parser.parse_args([]), role="subscriber"), "connect/endpoints") == [
        DEFAULT_ENDPOINT]
    with pytest.raises(SystemExit):
        parser.parse_args(["--mode", "bogus"])


def test_free_tcp_endpoint() -> None:
    ep = free_tcp_endpoint()
    assert ep.startswith("tcp/127.0.0.1:")
    assert 0 < int(ep.rsplit(":", 1)[1]) < 65536


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_stop_on_signals_sets_event_and_restores(sig: signal.Signals) -> None:
    before = signal.getsignal(sig)
    with stop_on_signals(threading.Event()) as stop:
        os.kill(os.getpid(), sig)
        assert stop.wait(1.0)
    assert signal.getsignal(sig) is before


# ------------------------------------------------------------------------------ recordings folder

_HEADER = "path\tsource\tsubject\tmotion\ttags\tframes\tfps\tjoints\tlicence\n"


def test_mocap_root_from_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "INDEX.tsv").write_text(_HEADER + "a/x.bvh\tsrc\tsubj\twave\twave, jump\t60\t30\t22\tCC0\n")
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x.bvh").write_text("HIERARCHY\n")
    monkeypatch.setenv(ENV_VAR, str(tmp_path))
    assert mocap_root() == tmp_path.resolve()
    (entry,) = index_entries()
    assert entry.tags == ("wave", "jump") and entry.frames == 60 and entry.fps == 30.0
    assert entry.duration == pytest.approx(2.0)
    assert entry.absolute() == tmp_path.resolve() / "a" / "x.bvh"
    assert recording_path("a/x.bvh") == tmp_path.resolve() / "a" / "x.bvh"
    with pytest.raises(FileNotFoundError):
        recording_path("a/missing.bvh")
    with pytest.raises(ValueError, match="outside"):
        recording_path("../escape.bvh")
    with pytest.raises(ValueError, match="relative"):
        recording_path(tmp_path / "a" / "x.bvh")


def test_mocap_root_missing_names_both_places(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "nowhere"))
    with pytest.raises(FileNotFoundError) as err:
        mocap_root()
    msg = str(err.value)
    assert ENV_VAR in msg and "nowhere" in msg and str(Path("shared") / "mocap") in msg


def test_mocap_index_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"INDEX\.tsv"):
        index_entries(tmp_path)
    (tmp_path / "INDEX.tsv").write_text("path\tframes\n")
    with pytest.raises(ValueError, match="missing column"):
        index_entries(tmp_path)
    (tmp_path / "INDEX.tsv").write_text(_HEADER + "a.bvh\ts\ts\tm\tt\tmany\t30\t22\tCC0\n")
    with pytest.raises(ValueError, match=":2: malformed"):
        index_entries(tmp_path)


def test_default_root_ignores_working_directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(ENV_VAR, raising=False)
    monkeypatch.chdir(tmp_path)
    expected = Path(keys.__file__).resolve().parents[2].parent / "shared" / "mocap"
    if not expected.is_dir():
        pytest.skip(f"shared recordings not present at {expected}")
    assert mocap_root() == expected.resolve()


def test_real_index_lists_existing_files() -> None:
    try:
        root = mocap_root()
    except FileNotFoundError as exc:
        pytest.skip(str(exc))
    entries = index_entries()
    assert len(entries) > 0
    assert all(e.path.endswith(".bvh") and e.fps > 0 and e.frames > 0 for e in entries)
    assert all((root / e.path).is_file() for e in entries)
