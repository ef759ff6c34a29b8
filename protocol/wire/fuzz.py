"""Hostile payloads for a client's keys: what ``python -m protocol fuzz`` publishes so that an
integrator can check that their own client survives whatever arrives.

Two families:

* **malformed** -- bytes the codec must refuse (:class:`~protocol.wire.codec.ProtocolError`):
  random bytes, truncated messages, a wrong or missing ``schema_version``, the wrong message type,
  NaN and infinity, oversized arrays, deep nesting, unknown keys;
* **valid but wrong in meaning** -- messages that decode, whose values a client must bound itself
  (:mod:`protocol.wire.validate`): capture times far in the future or the past, sequence numbers at
  the top of their range or going backwards, a sequence number one ahead of the real stream (a
  spoofer), bodies a thousandth or a hundred times a person's size, poses with absurd rotations
  and joints kilometres away.

Everything is drawn from an explicit generator: the same seed gives the same payloads.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import Any, Final

import msgpack
import numpy as np

from protocol.wire.codec import MAX_PAYLOAD_BYTES, encode
from protocol.wire.messages import BodyInfo, PoseFrame

__all__ = ["CASES", "MALFORMED", "MEANING", "hostile_payload", "hostile_stream"]

#: Cases the codec must refuse.
MALFORMED: Final[tuple[str, ...]] = ("random_bytes", "truncated", "wrong_schema", "wrong_type", "non_finite",
                                     "huge_array", "deep_nesting", "unknown_key")
#: Cases that decode and must be refused (or bounded) by the client's own checks.
MEANING: Final[tuple[str, ...]] = ("far_future", "far_past", "max_seq", "seq_backwards", "spoof_next_seq",
                                   "giant_body", "tiny_body", "huge_rotation", "far_joints")
CASES: Final[tuple[str, ...]] = MALFORMED + MEANING


def _raw(msg: object) -> dict[str, Any]:
    return dict(msgpack.unpackb(encode(msg), raw=False))


def _pack(obj: Any) -> bytes:
    return bytes(msgpack.packb(obj, use_single_float=False))


def hostile_payload(case: str, template: PoseFrame | BodyInfo, rng: np.random.Generator,
                    last_seq: int = 0, clock: float = 0.0) -> bytes:
    """One hostile payload of ``case`` built from a valid ``template`` message.

    Parameters
    ----------
    case : str
        One of :data:`CASES` (body cases need a ``BodyInfo`` template, pose cases a ``PoseFrame``;
        the malformed ones take either).
    template : PoseFrame or BodyInfo
    rng : np.random.Generator
    last_seq : int
        The real stream's latest sequence number (for ``spoof_next_seq`` and ``seq_backwards``).
    clock : float
        The real stream's capture time, seconds (for the time cases).

    Returns
    -------
    bytes
    """
    if case == "random_bytes":
        return rng.bytes(int(rng.integers(1, 4096)))
    if case == "truncated":
        data = encode(template)
        return data[: int(rng.integers(1, len(data)))]
    raw = _raw(template)
    if case == "wrong_schema":
        raw["schema_version"] = int(rng.choice([0, 999, -1]))
        return _pack(raw)
    if case == "wrong_type":
        raw["type"] = "BodyInfo" if isinstance(template, PoseFrame) else "PoseFrame"
        return _pack(raw)
    if case == "unknown_key":
        raw["x" + str(int(rng.integers(1000)))] = 1
        return _pack(raw)
    if case == "non_finite":
        key = next(k for k, v in raw.items() if isinstance(v, list) and v and isinstance(_first(v), float))
        vals = raw[key]
        _set_first(vals, float(rng.choice([np.nan, np.inf, -np.inf])))
        return _pack(raw)
    if case == "huge_array":
        key = next(k for k, v in raw.items() if isinstance(v, list))
        n = MAX_PAYLOAD_BYTES // 8 + 1  # just past what the codec accepts
        return _pack({**raw, key: [0.0] * n})
    if case == "deep_nesting":  # one field nested in thousands of one-element arrays (built as bytes:
        # msgpack's packer refuses that depth)
        key = "pose" if "pose" in raw else "offsets"
        rest = {k: v for k, v in raw.items() if k != key}
        head = bytes(msgpack.Packer().pack_map_header(len(rest) + 1))
        body = b"".join(_pack(k) + _pack(v) for k, v in rest.items())
        return head + body + _pack(key) + b"\x91" * int(rng.integers(200, 5000)) + b"\x00"
    if isinstance(template, PoseFrame):
        return encode(_pose_case(case, template, rng, last_seq, clock))
    return encode(_body_case(case, template, rng))


def _first(v: list[Any]) -> Any:
    return _first(v[0]) if isinstance(v[0], list) else v[0]


def _set_first(v: list[Any], x: float) -> None:
    if isinstance(v[0], list):
        _set_first(v[0], x)
    else:
        v[0] = x


def _pose_case(case: str, f: PoseFrame, rng: np.random.Generator, last_seq: int, clock: float) -> PoseFrame:
    if case == "far_future":
        return dataclasses.replace(f, capture_ts=clock + float(rng.choice([1e4, 1e9, 1e12])))
    if case == "far_past":
        return dataclasses.replace(f, capture_ts=max(0.0, clock - float(rng.choice([60.0, 1e4]))))
    if case == "max_seq":
        return dataclasses.replace(f, seq=2**63 - 1)
    if case == "seq_backwards":
        return dataclasses.replace(f, seq=max(0, last_seq - int(rng.integers(5, 500))))
    if case == "spoof_next_seq":  # a plausible frame one ahead of the real stream: both arms overhead
        pose = np.array(f.pose, np.float32, copy=True)
        pose[3:] += rng.normal(0.0, 0.8, pose.size - 3).astype(np.float32)
        return dataclasses.replace(f, seq=last_seq + 1, capture_ts=clock, pose=pose)
    if case == "huge_rotation":
        pose = np.array(f.pose, np.float32, copy=True)
        pose[3:] = rng.choice([-1.0, 1.0], pose.size - 3).astype(np.float32) * 1e6
        return dataclasses.replace(f, pose=pose)
    if case == "far_joints":
        pose = np.array(f.pose, np.float32, copy=True)
        pose[:3] = np.float32(1e5)
        return dataclasses.replace(f, pose=pose, joints=np.array(f.joints, np.float32) + np.float32(1e5))
    raise ValueError(f"{case!r} is not a pose case; pose cases: {', '.join(c for c in MEANING if 'body' not in c)}")


def _body_case(case: str, b: BodyInfo, rng: np.random.Generator) -> BodyInfo:
    if case in ("giant_body", "tiny_body"):
        k = np.float32(float(rng.uniform(50, 200)) if case == "giant_body" else float(rng.uniform(1e-4, 1e-2)))
        return dataclasses.replace(b, offsets=np.array(b.offsets, np.float32) * k,
                                   capsule_radii=np.array(b.capsule_radii, np.float32) * k,
                                   measurements={key: float(v) * float(k) if key.endswith("_m") else float(v)
                                                 for key, v in b.measurements.items()})
    raise ValueError(f"{case!r} is not a body case; body cases: giant_body, tiny_body")


def cases_for(template: PoseFrame | BodyInfo) -> tuple[str, ...]:
    """The cases that apply to a template of this type."""
    body = {"giant_body", "tiny_body"}
    if isinstance(template, BodyInfo):
        return MALFORMED + tuple(c for c in MEANING if c in body)
    return MALFORMED + tuple(c for c in MEANING if c not in body)


def hostile_stream(template: PoseFrame | BodyInfo, rng: np.random.Generator, cases: tuple[str, ...] = (),
                   last_seq: int = 0, clock: float = 0.0) -> Iterator[tuple[str, bytes]]:
    """Endless ``(case, payload)`` pairs, cases drawn uniformly from ``cases`` (default: all that
    apply to the template)."""
    pool = cases or cases_for(template)
    while True:
        case = str(pool[int(rng.integers(len(pool)))])
        yield case, hostile_payload(case, template, rng, last_seq, clock)
