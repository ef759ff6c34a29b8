"""Msgpack wire codec for the messages of :mod:`protocol.wire.messages` (contract: ``docs/PROTOCOL.md``).

Wire format
-----------
Every message is one msgpack map with string keys: the message dataclass's constructor fields plus
``"type"`` (its registered name, e.g. ``"pose_frame"``); ``"schema_version"`` is one of the
fields. Arrays are (nested) msgpack lists. Float arrays are written as msgpack float32, which holds
the dataclasses' float32 values exactly; scalar floats are written as float64 (Unix timestamps
need it). A reader accepts float32, float64 or an integer wherever a float is expected; array
elements are rounded to float32 and then range-checked. ``BodyInfo.bone_lengths`` is not sent: it
is derived from ``offsets`` on construction.

Strictness
----------
:func:`decode` is total: for any input it returns a valid message or raises :class:`ProtocolError`.
Every field is required, unknown and duplicate keys are rejected, and only :data:`SCHEMA_VERSION`
is accepted. :func:`encode` applies the same checks, so it never emits what :func:`decode` would
refuse.

Adding a message type
---------------------
Call :func:`register_message` with the wire name, the frozen dataclass and ``{field: check}``
(the tracker's types are registered here; the game's in :mod:`protocol.wire.game_messages`). A check
is a function ``(value, where) -> value`` built by the public factories (:func:`int_check`,
:func:`float_check`, :func:`str_check`, :func:`enum_check`, :func:`list_check`,
:func:`map_check`, :func:`array_check`, :func:`schema_version_check`); it raises
:class:`ProtocolError`. Registration checks that the row covers exactly the dataclass's
constructor fields.
"""

from __future__ import annotations

import dataclasses
import math
import re
import reprlib
from collections.abc import Callable
from enum import Enum
from typing import Any, Final, NoReturn, TypeVar, overload

import msgpack
import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import N_CAPSULES, N_JOINTS, N_PARTS, POSE_SIZE
from protocol.wire.messages import SCHEMA_VERSION, BodyInfo, PoseFrame, TrackerState, TrackerStatus

__all__ = [
    "MAX_MAP_ENTRIES", "MAX_PAYLOAD_BYTES", "MAX_STRING_LEN", "MESSAGE_TYPES", "TRACKER_ID_PATTERN",
    "Check", "ProtocolError", "array_check", "decode", "encode", "enum_check", "fail", "float_check", "int_check",
    "list_check", "map_check", "message_type_name", "register_message", "schema_version_check", "str_check",
]

#: Largest payload :func:`decode` will unpack (checked before unpacking).
MAX_PAYLOAD_BYTES: Final[int] = 256 * 1024
#: Longest string (in characters) allowed in any field or map key, other than ``tracker_id``.
MAX_STRING_LEN: Final[int] = 256
#: Most entries allowed in a string-keyed map field (``measurements``, ``counters``, ``stage_ms``).
MAX_MAP_ENTRIES: Final[int] = 64
#: ``tracker_id`` must match this (it is also a Zenoh key-expression chunk).
TRACKER_ID_PATTERN: Final[re.Pattern[str]] = re.compile(r"[A-Za-z0-9_-]{1,64}")
_INT64_MAX: Final[int] = 2**63 - 1
_FLOAT32_MAX: Final[float] = float(np.finfo(np.float32).max)
# Unpacker limits: strings in bytes (UTF-8 takes up to 4 per character); no field is binary or an ext.
_UNPACK_LIMITS: Final[dict[str, int]] = dict(max_str_len=4 * MAX_STRING_LEN, max_bin_len=0, max_ext_len=0,
                                             max_array_len=4096, max_map_len=MAX_MAP_ENTRIES)

T = TypeVar("T")
Check = Callable[[Any, str], Any]
_repr = reprlib.Repr()
_repr.maxlevel, _repr.maxlist, _repr.maxdict, _repr.maxstring, _repr.maxother = 2, 4, 4, 40, 40


class ProtocolError(ValueError):
    """The bytes (or message) are not a valid message of this protocol; the text says where and why."""


def _fail(where: str, what: str, value: object) -> NoReturn:
    raise ProtocolError(f"{where}: {what}, got {_repr.repr(value)}")


def _is_number(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)

# --- check factories ------------------------------------------------------------------------------

def _int(lo: int = 0, hi: int = _INT64_MAX) -> Check:
    """An integer (not a bool) in ``[lo, hi]``."""
    def check(v: Any, where: str) -> int:
        if not isinstance(v, int) or isinstance(v, bool):
            _fail(where, "expected an integer", v)
        if not lo <= v <= hi:
            _fail(where, f"integer out of range [{lo}, {hi}]", v)
        return int(v)
    return check


def _float(lo: float = -math.inf, hi: float = math.inf) -> Check:
    """A finite number in ``[lo, hi]`` (an integer is accepted), returned as a float."""
    def check(v: Any, where: str) -> float:
        if not _is_number(v):
            _fail(where, "expected a number", v)
        try:
            x = float(v)
        except OverflowError:
            _fail(where, "number too large", v)
        if not math.isfinite(x):
            _fail(where, "expected a finite number (NaN and inf are not allowed)", v)
        if not lo <= x <= hi:
            _fail(where, f"number out of range [{lo}, {hi}]", v)
        return x
    return check


def _str(min_len: int = 1, max_len: int = MAX_STRING_LEN, pattern: re.Pattern[str] | None = None) -> Check:
    """A string of ``min_len`` to ``max_len`` characters, fully matching ``pattern`` if given."""
    def check(v: Any, where: str) -> str:
        if not isinstance(v, str):
            _fail(where, "expected a string", v)
        if pattern is not None and not pattern.fullmatch(v):
            _fail(where, f"string must match ^{pattern.pattern}$", v)
        if not min_len <= len(v) <= max_len:
            _fail(where, f"string length must be in [{min_len}, {max_len}]", v)
        return v
    return check


def _enum(cls: type[Enum]) -> Check:
    """One of the string values of ``cls``."""
    values = tuple(m.value for m in cls)

    def check(v: Any, where: str) -> Enum:
        if not isinstance(v, str) or v not in values:
            _fail(where, f"expected one of {', '.join(values)}", v)
        return cls(v)
    return check


def _list_of(n: int, item: Check, *, unique: bool = False) -> Check:
    """A list of exactly ``n`` items, each passing ``item``; returned as a tuple."""
    def check(v: Any, where: str) -> tuple[Any, ...]:
        if not isinstance(v, list) or len(v) != n:
            _fail(where, f"expected a list of {n} items", v)
        out = tuple(item(x, f"{where}[{i}]") for i, x in enumerate(v))
        if unique and len(set(out)) != n:
            _fail(where, "items must be unique", v)
        return out
    return check


def _map(value: Check) -> Check:
    """A map of at most :data:`MAX_MAP_ENTRIES` string keys to values passing ``value``."""
    key = _str()

    def check(v: Any, where: str) -> dict[str, Any]:
        if not isinstance(v, dict) or len(v) > MAX_MAP_ENTRIES:
            _fail(where, f"expected a map of at most {MAX_MAP_ENTRIES} string keys", v)
        return {key(k, f"{where} key"): value(x, f"{where}[{_repr.repr(k)}]") for k, x in v.items()}
    return check


def _farray(
    shape: tuple[int, ...], lo: float = -math.inf, hi: float = math.inf, *, lo_open: bool = False
) -> Check:
    """Nested lists of finite numbers with the given shape; returned as a float32 array.

    Elements are rounded to float32 first (magnitudes above float32's maximum are rejected), then
    checked against ``[lo, hi]`` (``(lo, hi]`` if ``lo_open``).
    """
    shape_txt = "x".join(map(str, shape))
    span = f"{'(' if lo_open else '['}{lo}, {hi}]"

    def bad(where: str, i: int, what: str, x: object) -> NoReturn:
        _fail(f"{where}{list(map(int, np.unravel_index(i, shape)))}", what, x)

    def check(v: Any, where: str) -> NDArray[np.float32]:
        rows = [v]
        for n in shape:
            if not all(isinstance(r, list) and len(r) == n for r in rows):
                _fail(where, f"expected nested lists of shape {shape_txt}", v)
            rows = [x for r in rows for x in r]
        for i, x in enumerate(rows):
            if not _is_number(x):
                bad(where, i, "expected a number", x)
        try:
            a64 = np.array(rows, dtype=np.float64)
        except OverflowError:
            _fail(where, "number too large", v)
        for i in np.flatnonzero(~np.isfinite(a64))[:1]:
            bad(where, int(i), "expected a finite number (NaN and inf are not allowed)", rows[i])
        for i in np.flatnonzero(np.abs(a64) > _FLOAT32_MAX)[:1]:
            bad(where, int(i), "number exceeds the float32 range", rows[i])
        a = a64.astype(np.float32)
        for i in np.flatnonzero((a > hi) | ((a <= lo) if lo_open else (a < lo)))[:1]:
            bad(where, int(i), f"number out of range {span}", rows[i])
        return a.reshape(shape)
    return check


def _schema_version(v: Any, where: str) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or v != SCHEMA_VERSION:
        _fail(where, f"unsupported schema_version (this codec speaks {SCHEMA_VERSION})", v)
    return SCHEMA_VERSION


def _parents(v: Any, where: str) -> tuple[int, ...]:
    """Parent index per joint: -1 for joint 0, else an earlier joint (a topologically sorted tree)."""
    out: tuple[int, ...] = _list_of(N_JOINTS, _int(-1, N_JOINTS - 1))(v, where)
    if out[0] != -1 or any(not 0 <= p < i for i, p in enumerate(out) if i > 0):
        _fail(where, "parents[0] must be -1 and parents[i] in [0, i) for i > 0", v)
    return out

# --- the registry ---------------------------------------------------------------------------------
_NAME: Final[Check] = _str()
_OPT_NAME: Final[Check] = _str(min_len=0)
_TIME: Final[Check] = _float(0.0)
_UNIT: Final[Check] = _float(0.0, 1.0)

#: Wire name -> (dataclass, {field name: check}). One row per message type.
_REGISTRY: Final[dict[str, tuple[type[Any], dict[str, Check]]]] = {
    "pose_frame": (PoseFrame, {
        "schema_version": _schema_version,
        "tracker_id": _str(pattern=TRACKER_ID_PATTERN),
        "seq": _int(0),
        "capture_ts": _TIME, "publish_ts": _TIME, "capture_wall_ts": _TIME,
        "pose": _farray((POSE_SIZE,)),
        "joints": _farray((N_JOINTS, 3)),
        "visibility": _farray((N_PARTS,), 0.0, 1.0),
        "confidence": _UNIT,
        "estimator": _NAME, "body_model": _NAME,
    }),
    "body_info": (BodyInfo, {
        "schema_version": _schema_version,
        "tracker_id": _str(pattern=TRACKER_ID_PATTERN),
        "body_model": _NAME,
        "measurements": _map(_float(0.0)),
        "offsets": _farray((N_JOINTS, 3)),
        "capsule_radii": _farray((N_CAPSULES, 2), 0.0, lo_open=True),
        "joint_names": _list_of(N_JOINTS, _NAME, unique=True),
        "parents": _parents,
        "capsule_names": _list_of(N_CAPSULES, _NAME, unique=True),
        "capsule_joints": _list_of(N_CAPSULES, _list_of(2, _int(0, N_JOINTS - 1))),
    }),
    "tracker_status": (TrackerStatus, {
        "schema_version": _schema_version,
        "tracker_id": _str(pattern=TRACKER_ID_PATTERN),
        "state": _enum(TrackerState),
        "ts": _TIME, "uptime_s": _TIME, "fps": _float(0.0), "frames": _int(0),
        "counters": _map(_int(0)),
        "stage_ms": _map(_float(0.0)),
        "estimator": _OPT_NAME, "body_model": _OPT_NAME,
        "advice": _str(0),
        "camera": _map(_float()),
    }),
}
#: The registered message classes by wire name (do not modify; use :func:`register_message`).
MESSAGE_TYPES: Final[dict[str, type[Any]]] = {}
_NAME_OF: Final[dict[type[Any], str]] = {}

# public names of the check factories, for message types registered by other modules
int_check, float_check, str_check, enum_check = _int, _float, _str, _enum
list_check, map_check, array_check, schema_version_check, fail = _list_of, _map, _farray, _schema_version, _fail


def register_message(name: str, cls: type[Any], checks: dict[str, Check]) -> None:
    """Make a message type known to :func:`encode` and :func:`decode`.

    Parameters
    ----------
    name : str
        Wire ``"type"`` (e.g. ``"game_event"``).
    cls : type
        Frozen dataclass; its constructor fields are the wire keys.
    checks : dict[str, Check]
        One check per constructor field (``schema_version`` included).

    Raises
    ------
    ValueError
        The checks do not cover exactly the constructor fields, or the name or class is already
        registered differently.
    """
    if set(checks) != {f.name for f in dataclasses.fields(cls) if f.init}:
        raise ValueError(f"codec row {name!r} does not match the fields of {cls.__name__}")
    if MESSAGE_TYPES.get(name, cls) is not cls or _NAME_OF.get(cls, name) != name:
        raise ValueError(f"message type {name!r} / {cls.__name__} is already registered differently")
    _REGISTRY[name] = (cls, dict(checks))
    MESSAGE_TYPES[name] = cls
    _NAME_OF[cls] = name


for _row, (_cls, _checks) in list(_REGISTRY.items()):
    register_message(_row, _cls, _checks)

# --- public API -----------------------------------------------------------------------------------

def message_type_name(msg: object) -> str:
    """The wire ``"type"`` of a message object (``"pose_frame"``, ``"body_info"``, ...).

    Raises
    ------
    TypeError
        If ``msg``'s class is not a registered message type.
    """
    try:
        return _NAME_OF[type(msg)]
    except KeyError:
        raise TypeError(f"{type(msg).__name__} is not a protocol message type") from None


def _plain(v: Any) -> Any:
    """Numpy arrays/scalars, enums and tuples -> msgpack-native lists, numbers and strings."""
    if isinstance(v, np.ndarray | np.generic):
        return v.tolist()
    if isinstance(v, Enum):
        return v.value
    if isinstance(v, list | tuple):
        return [_plain(x) for x in v]
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    return v


def encode(msg: object) -> bytes:
    """Serialise a message to msgpack bytes (float arrays as float32, scalar floats as float64).

    Parameters
    ----------
    msg : PoseFrame | BodyInfo | TrackerStatus
        Any registered message object.

    Raises
    ------
    ProtocolError
        If the message breaks a rule :func:`decode` enforces (NaN, out-of-range value, bad id...).
    TypeError
        If ``msg`` is not a registered message type.
    """
    name = message_type_name(msg)
    checks = _REGISTRY[name][1]
    # check the msgpack-native form, then send what the check returns (canonical: ints in float
    # fields become floats), so that encode(decode(data)) == data
    values = {key: check(_plain(getattr(msg, key)), f"{name}.{key}") for key, check in checks.items()}
    p64 = msgpack.Packer(use_single_float=False)
    p32 = msgpack.Packer(use_single_float=True)
    parts = [p64.pack_map_header(len(values) + 1), p64.pack("type"), p64.pack(name)]
    for key, v in values.items():
        parts += [p64.pack(key), (p32 if isinstance(v, np.ndarray) else p64).pack(_plain(v))]
    data = b"".join(parts)
    if len(data) > MAX_PAYLOAD_BYTES:
        raise ProtocolError(f"{name}: encoded size {len(data)} exceeds {MAX_PAYLOAD_BYTES} bytes")
    return data


def _pairs(pairs: list[tuple[Any, Any]]) -> dict[Any, Any]:
    out = dict(pairs)
    if len(out) != len(pairs):
        raise ProtocolError("duplicate key in a msgpack map")
    return out


def _no_ext(code: int, data: bytes) -> NoReturn:
    raise ProtocolError(f"msgpack extension types are not allowed (ext type {code})")


def _build(obj: Any, expected: type[Any] | None) -> Any:
    if not isinstance(obj, dict):
        _fail("message", "expected a msgpack map at the top level", obj)
    if "type" not in obj:
        raise ProtocolError("message: missing key 'type'")
    name = obj["type"]
    if not isinstance(name, str) or name not in _REGISTRY:
        _fail("message.type", f"unknown message type (known: {', '.join(_REGISTRY)})", name)
    cls, checks = _REGISTRY[name]
    if expected is not None and cls is not expected:
        raise ProtocolError(f"expected a {_NAME_OF[expected]} message, got {name}")
    if "schema_version" not in obj:
        raise ProtocolError(f"{name}: missing key 'schema_version'")
    _schema_version(obj["schema_version"], f"{name}.schema_version")  # before the key-set checks
    unknown = sorted(_repr.repr(k) for k in obj if k != "type" and k not in checks)
    if unknown:
        raise ProtocolError(f"{name}: unknown key(s) {', '.join(unknown)}")
    missing = [repr(k) for k in checks if k not in obj]
    if missing:
        raise ProtocolError(f"{name}: missing key(s) {', '.join(missing)}")
    return cls(**{key: check(obj[key], f"{name}.{key}") for key, check in checks.items()})


@overload
def decode(data: bytes | bytearray | memoryview, expected: type[T]) -> T: ...
@overload
def decode(data: bytes | bytearray | memoryview, expected: None = None) -> Any: ...
def decode(data: bytes | bytearray | memoryview, expected: type[Any] | None = None) -> Any:
    """Parse and validate msgpack bytes into a message object.

    Parameters
    ----------
    data : bytes-like
        One complete message (e.g. ``sample.payload.to_bytes()``).
    expected : type, optional
        The message class wanted (e.g. ``PoseFrame``); another type is an error. ``None`` returns
        whichever registered type the ``"type"`` key names.

    Raises
    ------
    ProtocolError
        For any invalid input; no other exception escapes, whatever the bytes.
    TypeError
        If ``expected`` is not a registered message class (a programming error).
    """
    if expected is not None and expected not in _NAME_OF:
        raise TypeError(f"{getattr(expected, '__name__', expected)!r} is not a protocol message type")
    if not isinstance(data, bytes | bytearray | memoryview):
        raise ProtocolError(f"payload must be bytes, got {type(data).__name__}")
    try:
        size = memoryview(data).nbytes
        if size == 0:
            raise ProtocolError("empty payload")
        if size > MAX_PAYLOAD_BYTES:
            raise ProtocolError(f"payload of {size} bytes exceeds {MAX_PAYLOAD_BYTES} bytes")
        try:
            obj = msgpack.unpackb(data, raw=False, strict_map_key=True, use_list=True,
                                  object_pairs_hook=_pairs, ext_hook=_no_ext, **_UNPACK_LIMITS)
        except msgpack.ExtraData:
            raise ProtocolError("trailing bytes after the message") from None
        except msgpack.StackError:
            raise ProtocolError("msgpack nesting too deep") from None
        except ProtocolError:
            raise
        except Exception as e:
            raise ProtocolError(f"malformed msgpack: {str(e) or type(e).__name__}") from None
        return _build(obj, expected)
    except ProtocolError:
        raise
    except Exception as e:  # defensive: a constructor or check raised something unforeseen
        raise ProtocolError(f"invalid message: {type(e).__name__}: {e}") from None
