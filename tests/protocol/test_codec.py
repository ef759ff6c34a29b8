"""Tests of :mod:`protocol.wire.codec`: round trips, one test per class of invalid input, and fuzzing.

Every invalid-input test asserts :class:`ProtocolError` with a message naming the problem; the
hypothesis tests assert that no other exception ever escapes :func:`decode`.
"""

from __future__ import annotations

from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from protocol.skeleton import N_CAPSULES, N_JOINTS, N_PARTS, POSE_SIZE, body_from_measurements, default_body
from protocol.wire import codec as codec
from protocol.wire.codec import MAX_PAYLOAD_BYTES, ProtocolError, decode, encode, message_type_name
from protocol.wire.messages import (
    SCHEMA_VERSION,
    BodyInfo,
    PoseFrame,
    TrackerState,
    TrackerStatus,
    body_info_from_body,
)

F32 = np.finfo(np.float32)
FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# --- valid instances ------------------------------------------------------------------------------


def pose_frame(**kw: Any) -> PoseFrame:
    args: dict[str, Any] = dict(
        tracker_id="cam0", seq=7, capture_ts=12.5, publish_ts=1_700_000_000.123456, capture_wall_ts=1_700_000_000.1,
        pose=np.linspace(-1.0, 1.0, POSE_SIZE), joints=np.arange(N_JOINTS * 3).reshape(N_JOINTS, 3) * 0.01,
        visibility=np.linspace(0.0, 1.0, N_PARTS), confidence=0.75, estimator="tree", body_model="mMA",
    )
    return PoseFrame(**(args | kw))


def body_info(**kw: Any) -> BodyInfo:
    info = body_info_from_body(default_body(), "cam0")
    args = {f: getattr(info, f) for f in codec._REGISTRY["body_info"][1]}
    return BodyInfo(**(args | kw))


def status(**kw: Any) -> TrackerStatus:
    args: dict[str, Any] = dict(
        tracker_id="cam0", state=TrackerState.TRACKING, ts=1_700_000_001.5, uptime_s=61.0, fps=29.97,
        frames=1830, counters={"bad_frames": 3, "dropped_frames": 0}, stage_ms={"features": 2.5},
        estimator="tree", body_model="mMA",
    )
    return TrackerStatus(**(args | kw))


ID_CHARS = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-"
EXTREME = np.array([F32.max, -F32.max, F32.tiny, -F32.tiny, F32.smallest_subnormal, -0.0, 0.0, 1e-30])

ROUND_TRIP: list[Any] = [
    pose_frame(),
    pose_frame(seq=0, capture_ts=0, publish_ts=0, capture_wall_ts=0, confidence=0, visibility=np.zeros(N_PARTS),
               pose=np.zeros(POSE_SIZE), joints=np.zeros((N_JOINTS, 3))),
    pose_frame(seq=2**63 - 1, confidence=1.0, visibility=np.ones(N_PARTS), tracker_id=ID_CHARS[:64],
               pose=np.resize(EXTREME, POSE_SIZE), joints=np.resize(EXTREME[::-1], (N_JOINTS, 3)),
               capture_ts=1e300, publish_ts=4_102_444_800.000001, capture_wall_ts=4_102_444_800.0),
    pose_frame(tracker_id="-", estimator="é" * 256, body_model="\U0001f600" * 256),  # 1024 UTF-8 bytes
    body_info(),
    body_info(tracker_id="x", measurements={}, body_model="b"),
    body_info_from_body(body_from_measurements(0.8, weight_kg=10.0, name="tiny"), "kid_1"),
    body_info_from_body(body_from_measurements(2.3, weight_kg=200.0, arm_ratio=1.3, name="tall"), "T-2"),
    body_info(measurements={f"m{i}": float(i) for i in range(codec.MAX_MAP_ENTRIES)},
              capsule_radii=np.full((N_CAPSULES, 2), F32.smallest_subnormal)),
    *[status(state=s) for s in TrackerState],
    status(counters={}, stage_ms={}, estimator="", body_model="", fps=0, frames=0, uptime_s=0, ts=0),
    status(counters={"k" * 256: 2**63 - 1}, stage_ms={"s": 0, "t": 1e308}),
]


@pytest.mark.parametrize("msg", ROUND_TRIP, ids=lambda m: type(m).__name__)
def test_round_trip(msg: Any) -> None:
    data = encode(msg)
    out = decode(data)
    assert type(out) is type(msg) and out == msg
    assert decode(data, type(msg)) == msg
    assert decode(bytearray(data)) == msg and decode(memoryview(data)) == msg
    assert encode(out) == data
    for name in codec._REGISTRY[message_type_name(msg)][1]:
        a, b = getattr(msg, name), getattr(out, name)
        if isinstance(a, np.ndarray):  # bit-exact, -0.0 and subnormals included
            assert a.dtype == b.dtype == np.float32 and np.array_equal(a.view(np.uint32), b.view(np.uint32))


def test_wire_layout() -> None:
    pf, bi = pose_frame(pose=np.full(POSE_SIZE, 0.1)), body_info()
    wire = msgpack.unpackb(encode(pf))
    assert set(wire) == {"type", *codec._REGISTRY["pose_frame"][1]} and wire["type"] == "pose_frame"
    assert wire["schema_version"] == SCHEMA_VERSION and len(wire["joints"]) == N_JOINTS
    data = encode(pf)
    assert msgpack.packb(pf.pose.tolist(), use_single_float=True) in data  # float arrays: float32
    assert msgpack.packb(pf.publish_ts) in data  # scalar floats: float64
    assert msgpack.unpackb(encode(pf))["publish_ts"] == pf.publish_ts
    bwire = msgpack.unpackb(encode(bi))
    assert "bone_lengths" not in bwire and bwire["parents"][0] == -1
    assert np.array_equal(decode(encode(bi), BodyInfo).bone_lengths, bi.bone_lengths)
    assert msgpack.unpackb(encode(status()))["state"] == "tracking"


def test_lenient_numbers() -> None:
    """Ints are accepted for floats; float64 array elements are rounded to float32, then range-checked."""
    w = msgpack.unpackb(encode(pose_frame()))
    w |= {"confidence": 1, "capture_ts": 3, "pose": [0] * POSE_SIZE}
    w["joints"][0] = [0.1, 2**40, -5]
    w["visibility"][0] = 1.0 + 1e-12  # rounds to 1.0f
    out = decode(msgpack.packb(w), PoseFrame)
    assert out.confidence == 1.0 and out.joints[0, 0] == np.float32(0.1) and out.visibility[0] == 1.0


def test_api_misuse() -> None:
    with pytest.raises(TypeError):
        encode(object())
    with pytest.raises(TypeError):
        message_type_name("pose_frame")
    with pytest.raises(TypeError):
        decode(encode(pose_frame()), dict)
    assert [message_type_name(m) for m in (pose_frame(), body_info(), status())] == [
        "pose_frame", "body_info", "tracker_status"]
    for bad in ("text", None, 12):
        with pytest.raises(ProtocolError, match="must be bytes"):
            decode(bad)  # type: ignore[call-overload]


@pytest.mark.parametrize("msg", [
    pose_frame(pose=np.full(POSE_SIZE, np.nan)), pose_frame(tracker_id="a b"), pose_frame(seq=-1),
    pose_frame(confidence=1.5), status(counters={"x": -1}), status(estimator="e" * 300),
    body_info(capsule_radii=np.zeros((N_CAPSULES, 2))),
])
def test_encode_refuses_what_decode_rejects(msg: Any) -> None:
    with pytest.raises(ProtocolError):
        encode(msg)


# --- invalid input, one test per class ------------------------------------------------------------


def wire(msg: Any = None) -> dict[str, Any]:
    out: dict[str, Any] = msgpack.unpackb(encode(pose_frame() if msg is None else msg))
    return out


def reject(obj: Any, match: str, expected: type | None = None) -> None:
    data = obj if isinstance(obj, bytes) else msgpack.packb(obj, use_bin_type=True)
    with pytest.raises(ProtocolError, match=match):
        decode(data, expected)


def with_(msg: Any, path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    w = wire(msg)
    node = w
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value
    return w


@pytest.mark.parametrize(("msg", "path", "value", "match"), [
    (None, ("seq",), True, "seq: expected an integer"),
    (None, ("seq",), 7.0, "seq: expected an integer"),
    (None, ("seq",), "7", "seq: expected an integer"),
    (None, ("confidence",), False, "confidence: expected a number"),
    (None, ("confidence",), "0.5", "confidence: expected a number"),
    (None, ("capture_ts",), None, "capture_ts: expected a number"),
    (None, ("tracker_id",), 5, "tracker_id: expected a string"),
    (None, ("tracker_id",), b"cam0", "malformed msgpack.*bin"),
    (None, ("estimator",), ["tree"], "estimator: expected a string"),
    (None, ("pose",), {"0": 1.0}, "pose: expected nested lists"),
    (None, ("pose", 3), True, r"pose\[3\]: expected a number"),
    (None, ("pose", 3), [1.0], r"pose\[3\]: expected a number"),
    (None, ("joints", 2, 1), "x", r"joints\[2, 1\]: expected a number"),
    (status(), ("state",), 3, "state: expected one of"),
    (status(), ("counters", "bad_frames"), 1.5, "counters.*expected an integer"),
    (status(), ("counters", "bad_frames"), True, "counters.*expected an integer"),
    (status(), ("stage_ms",), [1.0], "stage_ms: expected a map"),
    (body_info(), ("parents", 4), 3.0, r"parents\[4\]: expected an integer"),
    (body_info(), ("capsule_joints", 0), (1, "a"), r"capsule_joints\[0\]\[1\]: expected an integer"),
    (body_info(), ("joint_names", 0), None, r"joint_names\[0\]: expected a string"),
])
def test_wrong_types(msg: Any, path: tuple[Any, ...], value: Any, match: str) -> None:
    reject(with_(msg, path, value), match)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), float("-inf")])
@pytest.mark.parametrize(("msg", "path"), [
    (None, ("pose", 5)), (None, ("joints", 3, 1)), (None, ("visibility", 0)), (None, ("confidence",)),
    (None, ("capture_ts",)), (None, ("publish_ts",)), (body_info(), ("measurements", "height_m")),
    (body_info(), ("offsets", 2, 0)), (body_info(), ("capsule_radii", 1, 1)), (status(), ("ts",)),
    (status(), ("fps",)), (status(), ("uptime_s",)), (status(), ("stage_ms", "features")),
])
def test_non_finite(msg: Any, path: tuple[Any, ...], bad: float) -> None:
    reject(with_(msg, path, bad), "finite")


@pytest.mark.parametrize(("msg", "path", "value", "match"), [
    (None, ("pose",), [0.0] * (POSE_SIZE - 1), "pose: expected nested lists of shape 60"),
    (None, ("pose",), [0.0] * (POSE_SIZE + 1), "pose: expected nested lists of shape 60"),
    (None, ("pose",), [], "pose: expected nested lists"),
    (None, ("joints",), [[0.0] * 3] * (N_JOINTS - 1), "joints: expected nested lists of shape 24x3"),
    (None, ("joints",), [0.0] * (N_JOINTS * 3), "joints: expected nested lists of shape 24x3"),
    (None, ("joints", 5), [0.0, 0.0], "joints: expected nested lists of shape 24x3"),
    (None, ("visibility",), [0.5] * (N_PARTS - 1), "visibility: expected nested lists of shape 15"),
    (body_info(), ("offsets", 0), [0.0] * 4, "offsets: expected nested lists of shape 24x3"),
    (body_info(), ("capsule_radii", 0), [0.1], "capsule_radii: expected nested lists of shape 18x2"),
    (body_info(), ("joint_names",), ["a"] * 23, "joint_names: expected a list of 24"),
    (body_info(), ("parents",), [-1] + [0] * 24, "parents: expected a list of 24"),
    (body_info(), ("capsule_names",), [], "capsule_names: expected a list of 18"),
    (body_info(), ("capsule_joints", 0), [0, 1, 2], r"capsule_joints\[0\]: expected a list of 2"),
])
def test_wrong_lengths(msg: Any, path: tuple[Any, ...], value: Any, match: str) -> None:
    reject(with_(msg, path, value), match)


@pytest.mark.parametrize("msg", [pose_frame(), body_info(), status()], ids=lambda m: type(m).__name__)
def test_unknown_and_missing_keys(msg: Any) -> None:
    reject(wire(msg) | {"extra": 1}, "unknown key.*'extra'")
    reject(wire(msg) | {"bone_lengths": [0.0] * N_JOINTS}, "unknown key.*'bone_lengths'")
    for key in [*codec._REGISTRY[message_type_name(msg)][1], "type"]:
        w = wire(msg)
        del w[key]
        reject(w, f"missing key.*'{key}'")
    dup = msgpack.packb(wire(msg))
    dup = bytes([dup[0] + 1]) + dup[1:] + msgpack.packb("type") + msgpack.packb("pose_frame")
    reject(dup, "duplicate key")


def test_unknown_type() -> None:
    for t in ["cloth_mesh", "", "PoseFrame", 5, None, ["pose_frame"]]:
        reject(wire() | {"type": t}, "type: unknown message type")
    reject(encode(pose_frame()), "expected a body_info message, got pose_frame", BodyInfo)
    reject(encode(status()), "expected a pose_frame message, got tracker_status", PoseFrame)


@pytest.mark.parametrize("version", [0, SCHEMA_VERSION + 1, -1, 2**64 - 1, 1.0, True, "1", None])
def test_unknown_schema_version(version: Any) -> None:
    reject(wire() | {"schema_version": version, "new_field": 1}, "unsupported schema_version")


@pytest.mark.parametrize(("msg", "path", "value"), [
    (None, ("seq",), -1), (None, ("seq",), 2**63), (status(), ("frames",), -1),
    (status(), ("counters", "bad_frames"), -1), (status(), ("counters", "x"), 2**64 - 1),
])
def test_negative_or_huge_integers(msg: Any, path: tuple[Any, ...], value: int) -> None:
    reject(with_(msg, path, value), "integer out of range")


@pytest.mark.parametrize(("msg", "path", "value"), [
    (None, ("confidence",), -0.01), (None, ("confidence",), 1.01), (None, ("visibility", 3), 1.5),
    (None, ("visibility", 0), -1e-3), (None, ("capture_ts",), -1.0), (status(), ("fps",), -1),
    (status(), ("stage_ms", "features"), -0.5), (body_info(), ("measurements", "height_m"), -1.7),
    (body_info(), ("capsule_radii", 0, 0), 0.0), (body_info(), ("capsule_radii", 4, 1), -0.02),
    (body_info(), ("capsule_radii", 4, 1), 1e-50),  # rounds to 0 in float32
    (body_info(), ("capsule_joints", 0, 1), N_JOINTS), (body_info(), ("parents", 3), -2),
])
def test_out_of_range(msg: Any, path: tuple[Any, ...], value: float) -> None:
    reject(with_(msg, path, value), "out of range")


def test_float32_overflow_and_topology() -> None:
    reject(with_(None, ("pose", 0), 1e39), r"pose\[0\]: number exceeds the float32 range")
    reject(with_(body_info(), ("parents", 0), 0), "parents.*must be -1")
    reject(with_(body_info(), ("parents", 3), 5), r"parents\[i\] in \[0, i\)")
    reject(with_(body_info(), ("joint_names", 1), "pelvis"), "joint_names: items must be unique")


@pytest.mark.parametrize(("msg", "path", "value", "match"), [
    (None, ("tracker_id",), "", "must match"), (None, ("tracker_id",), "a" * 65, "must match"),
    (None, ("tracker_id",), "a b", "must match"), (None, ("tracker_id",), "cam/0", "must match"),
    (None, ("tracker_id",), "cam0\n", "must match"), (None, ("tracker_id",), "*", "must match"),
    (None, ("tracker_id",), "caméra", "must match"),
    (None, ("estimator",), "", r"length must be in \[1, 256\]"),
    (None, ("body_model",), "m" * 257, r"length must be in \[1, 256\]"),
    (None, ("estimator",), "\U0001f600" * 257, "malformed msgpack.*max_str_len"),
    (body_info(), ("joint_names", 3), "", "length must be"),
    (body_info(), ("measurements", ""), 1.0, "measurements key: string length"),
    (body_info(), ("measurements", "k" * 257), 1.0, "measurements key: string length"),
    (status(), ("estimator",), "e" * 257, "length must be"),
])
def test_bad_strings(msg: Any, path: tuple[Any, ...], value: str, match: str) -> None:
    reject(with_(msg, path, value), match)


def test_oversized_payload_rejected_before_unpacking(monkeypatch: pytest.MonkeyPatch) -> None:
    def boom(*_a: Any, **_k: Any) -> None:
        raise AssertionError("unpackb must not be called")

    big = encode(pose_frame()) + b"\x00" * MAX_PAYLOAD_BYTES
    monkeypatch.setattr(codec.msgpack, "unpackb", boom)
    with pytest.raises(ProtocolError, match="exceeds 262144 bytes"):
        decode(big)
    monkeypatch.undo()
    reject(b"\x00" * (MAX_PAYLOAD_BYTES + 1), "exceeds")
    reject(with_(status(), ("stage_ms",), {str(i): 1.0 for i in range(65)}), "malformed.*max_map_len")


@pytest.mark.parametrize("msg", [pose_frame(), body_info(), status()], ids=lambda m: type(m).__name__)
def test_truncated(msg: Any) -> None:
    data = encode(msg)
    reject(b"", "empty payload")
    for n in range(1, len(data)):
        reject(data[:n], "malformed msgpack")


def test_garbage_and_trailing_bytes() -> None:
    reject(b"\xc1", "malformed msgpack")  # the one never-used msgpack byte
    reject(b"\xa3\xff\xfe\xfd", "malformed msgpack.*utf-8")
    reject(encode(status()) + b"\x00", "trailing bytes")
    reject(encode(status()) * 2, "trailing bytes")


@pytest.mark.parametrize("top", [[1, 2], 1, None, "pose_frame", b"", 1.5, True])
def test_non_map_top_level(top: Any) -> None:
    reject(msgpack.packb(top), "expected a msgpack map at the top level")


@pytest.mark.parametrize("ext", [msgpack.ExtType(1, b"ab"), msgpack.ExtType(5, b""), msgpack.Timestamp(1, 2)])
def test_ext_types(ext: Any) -> None:
    reject(ext, "ext")
    reject(wire() | {"confidence": ext}, "ext")


def test_non_string_map_keys() -> None:
    reject({1: 2}, "malformed msgpack.*map key")
    reject(with_(body_info(), ("measurements",), {1: 1.0}), "malformed msgpack.*map key")


def test_deep_nesting() -> None:
    reject(b"\x91" * 200_000 + b"\xc0", "nesting too deep")
    reject(b"\x81\xa1a" * 50_000 + b"\xc0", "nesting too deep")
    nested: Any = 0.0
    for _ in range(60):
        nested = [nested]
    reject(with_(None, ("pose",), nested), "pose: expected nested lists")


# --- fuzzing --------------------------------------------------------------------------------------

VALID = [encode(m) for m in (pose_frame(), body_info(), status(), ROUND_TRIP[2])]


def decode_quietly(data: bytes) -> None:
    """Decode; a ProtocolError is fine, anything else propagates and fails the test."""
    try:
        decode(data)
    except ProtocolError as e:
        assert str(e)


@FUZZ
@given(st.binary(max_size=2048))
def test_fuzz_random_bytes(data: bytes) -> None:
    decode_quietly(data)


@st.composite
def mutated(draw: st.DrawFn) -> bytes:
    data = bytearray(draw(st.sampled_from(VALID)))
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "truncate", "splice", "insert", "delete"]))
        i = draw(st.integers(0, max(len(data) - 1, 0)))
        if op == "flip" and data:
            data[i] ^= draw(st.integers(1, 255))
        elif op == "truncate":
            del data[i:]
        elif op == "splice":
            other = draw(st.sampled_from(VALID))
            j = draw(st.integers(0, len(other)))
            data[i:] = other[j:]
        elif op == "insert":
            data[i:i] = draw(st.binary(min_size=1, max_size=8))
        else:
            del data[i:i + draw(st.integers(1, 8))]
    return bytes(data)


@FUZZ
@given(mutated())
def test_fuzz_mutated_encodings(data: bytes) -> None:
    decode_quietly(data)


MSGPACKABLE = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=12)
    | st.binary(max_size=12),
    lambda kids: st.lists(kids, max_size=6)
    | st.dictionaries(st.text(max_size=8) | st.integers(-9, 9), kids, max_size=6),
    max_leaves=30,
)


@FUZZ
@given(MSGPACKABLE)
def test_fuzz_random_objects(obj: Any) -> None:
    decode_quietly(msgpack.packb(obj, use_bin_type=True))


@FUZZ
@given(st.sampled_from([pose_frame(), body_info(), status()]), st.data())
def test_fuzz_one_field_replaced(msg: Any, data: st.DataObject) -> None:
    """A valid message with one field (or the type / version) replaced by a random object."""
    w = wire(msg)
    key = data.draw(st.sampled_from(sorted(w)))
    w[key] = data.draw(MSGPACKABLE)
    decode_quietly(msgpack.packb(w, use_bin_type=True))


def f32(lo: float | None = None, hi: float | None = None) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, width=32, allow_nan=False, allow_infinity=False)


@FUZZ
@given(
    tracker_id=st.from_regex(r"[A-Za-z0-9_-]{1,64}", fullmatch=True), seq=st.integers(0, 2**63 - 1),
    capture_ts=st.floats(0, 1e12), publish_ts=st.floats(0, 1e12), capture_wall_ts=st.floats(0, 1e12),
    pose=hnp.arrays(np.float32, POSE_SIZE, elements=f32()),
    joints=hnp.arrays(np.float32, (N_JOINTS, 3), elements=f32()),
    visibility=hnp.arrays(np.float32, N_PARTS, elements=f32(0, 1)), confidence=st.floats(0, 1),
    estimator=st.text(min_size=1, max_size=256), body_model=st.text(min_size=1, max_size=256),
)
def test_fuzz_valid_pose_frames_round_trip(**kw: Any) -> None:
    msg = PoseFrame(**kw)
    out = decode(encode(msg), PoseFrame)
    assert out == msg
    for a, b in ((msg.pose, out.pose), (msg.joints, out.joints), (msg.visibility, out.visibility)):
        assert np.array_equal(a.view(np.uint32), b.view(np.uint32))
