"""Messages that carry pictures and meshes: the tracker's preview (its camera frame with the overlay,
JPEG) and the cloth client's mesh. Both are msgpack maps with binary fields, outside the codec's
numeric schema (:mod:`protocol.wire.codec` has no byte strings), and follow its rules: frozen
dataclasses with ``schema_version``, and decoding untrusted bytes raises nothing but
:class:`~protocol.wire.codec.ProtocolError`.

Keys: ``mocap/tracker/<id>/preview`` (:func:`~protocol.wire.keys.preview_key`, at most a few frames a second, only
while somebody subscribes) and ``mocap/cloth/<id>/mesh`` (:func:`protocol.wire.keys.cloth_mesh_key`).

``cloth_mesh`` layout (unchanged since schema version 1): ``cloth_id``, ``seq``, ``ts`` (Unix time),
``capture_ts`` (the pose's stream time), ``garment``, ``n_vertices``, ``vertices`` (little-endian
float32, ``n_vertices x 3``, metres, Y up) and optionally ``triangles`` (little-endian uint32,
``T x 3``; the first message and every few after carry them).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Final

import msgpack
import numpy as np
from numpy.typing import NDArray

from protocol.wire.codec import MAX_PAYLOAD_BYTES, ProtocolError
from protocol.wire.keys import preview_key

__all__ = ["MAX_MESH_VERTICES", "ClothMesh", "PreviewFrame", "decode_cloth_mesh", "decode_preview",
           "encode_cloth_mesh", "encode_preview", "preview_key"]

SCHEMA_VERSION: Final[int] = 1
#: Largest cloth mesh a message may carry.
MAX_MESH_VERTICES: Final[int] = 20_000
_ID = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")


@dataclass(frozen=True)
class PreviewFrame:
    """The tracker's camera frame with its silhouette and skeleton drawn on it.

    Attributes
    ----------
    tracker_id : str
    seq : int
        The ``PoseFrame`` sequence number it goes with (or the last one published).
    capture_ts : float
        The frame's stream time, seconds.
    width, height : int
        Pixels of the JPEG.
    jpeg : bytes
        Baseline JPEG (starts with ``FF D8``), at most 256 KiB.
    schema_version : int
    """

    tracker_id: str
    seq: int
    capture_ts: float
    width: int
    height: int
    jpeg: bytes
    schema_version: int = SCHEMA_VERSION


@dataclass(frozen=True)
class ClothMesh:
    """The cloth client's garment in one frame.

    Attributes
    ----------
    cloth_id : str
    seq : int
    ts, capture_ts : float
        Unix time of publishing; the pose's stream time.
    garment : str
    vertices : (V, 3) float32
        Metres, Y up.
    triangles : (T, 3) uint32 or None
        Indices into ``vertices``; None in messages that do not repeat the topology.
    schema_version : int
    """

    cloth_id: str
    seq: int
    ts: float
    capture_ts: float
    garment: str
    vertices: NDArray[np.float32]
    triangles: NDArray[np.uint32] | None = None
    schema_version: int = SCHEMA_VERSION


def _unpack(data: bytes | bytearray | memoryview, kind: str) -> dict[str, Any]:
    if not isinstance(data, bytes | bytearray | memoryview):
        raise ProtocolError(f"payload must be bytes, got {type(data).__name__}")
    if not 0 < memoryview(data).nbytes <= MAX_PAYLOAD_BYTES:
        raise ProtocolError(f"{kind}: payload of {memoryview(data).nbytes} bytes outside 1..{MAX_PAYLOAD_BYTES}")
    try:
        obj = msgpack.unpackb(data, raw=False, strict_map_key=True, max_array_len=16, max_map_len=16)
    except Exception as exc:  # msgpack raises many types for hostile bytes
        raise ProtocolError(f"{kind}: not msgpack ({type(exc).__name__})") from None
    if not isinstance(obj, dict) or obj.get("type") != kind:
        raise ProtocolError(f"expected a {kind} message")
    if obj.get("schema_version") != SCHEMA_VERSION:
        raise ProtocolError(f"{kind}: schema_version must be {SCHEMA_VERSION}")
    return obj


def _get(obj: dict[str, Any], key: str, kind: type | tuple[type, ...], what: str) -> Any:
    v = obj.get(key)
    if not isinstance(v, kind) or isinstance(v, bool):
        raise ProtocolError(f"{what}.{key}: missing or of the wrong type")
    if isinstance(v, float) and not math.isfinite(v):
        raise ProtocolError(f"{what}.{key}: not finite")
    return v


def _text(obj: dict[str, Any], key: str, pattern: re.Pattern[str], what: str) -> str:
    v = _get(obj, key, str, what)
    if pattern.fullmatch(v) is None:
        raise ProtocolError(f"{what}.{key}: invalid")
    return str(v)


def encode_preview(msg: PreviewFrame) -> bytes:
    """Serialise a :class:`PreviewFrame` (``ProtocolError`` for an invalid one)."""
    data = bytes(msgpack.packb({"type": "preview", "schema_version": msg.schema_version,
                                "tracker_id": msg.tracker_id, "seq": int(msg.seq),
                                "capture_ts": float(msg.capture_ts), "width": int(msg.width),
                                "height": int(msg.height), "jpeg": bytes(msg.jpeg)}, use_bin_type=True))
    decode_preview(data)  # the same rules both ways
    return data


def decode_preview(data: bytes | bytearray | memoryview) -> PreviewFrame:
    """Parse and check a preview message; raises only :class:`ProtocolError`."""
    obj = _unpack(data, "preview")
    w, h = _get(obj, "width", int, "preview"), _get(obj, "height", int, "preview")
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise ProtocolError("preview: width and height must be 16..4096")
    jpeg = _get(obj, "jpeg", bytes, "preview")
    if not jpeg.startswith(b"\xff\xd8"):
        raise ProtocolError("preview: jpeg is not a JPEG")
    seq = _get(obj, "seq", int, "preview")
    ts = float(_get(obj, "capture_ts", (int, float), "preview"))
    if not (0 <= seq < 2**63 and 0.0 <= ts < 1e10):
        raise ProtocolError("preview: seq or capture_ts out of range")
    return PreviewFrame(_text(obj, "tracker_id", _ID, "preview"), seq, ts, w, h, jpeg)


def encode_cloth_mesh(msg: ClothMesh) -> bytes:
    """Serialise a :class:`ClothMesh` in the layout of the module docstring."""
    v = np.ascontiguousarray(msg.vertices, dtype="<f4")
    obj: dict[str, Any] = {"type": "cloth_mesh", "schema_version": msg.schema_version, "cloth_id": msg.cloth_id,
                           "seq": int(msg.seq), "ts": float(msg.ts), "capture_ts": float(msg.capture_ts),
                           "garment": msg.garment, "n_vertices": len(v), "vertices": v.tobytes()}
    if msg.triangles is not None:
        obj["triangles"] = np.ascontiguousarray(msg.triangles, dtype="<u4").tobytes()
    return bytes(msgpack.packb(obj, use_bin_type=True))


def decode_cloth_mesh(data: bytes | bytearray | memoryview) -> ClothMesh:
    """Parse and check a cloth mesh message; raises only :class:`ProtocolError`."""
    obj = _unpack(data, "cloth_mesh")
    n = _get(obj, "n_vertices", int, "cloth_mesh")
    if not 0 < n <= MAX_MESH_VERTICES:
        raise ProtocolError(f"cloth_mesh: n_vertices must be 1..{MAX_MESH_VERTICES}")
    raw = _get(obj, "vertices", bytes, "cloth_mesh")
    if len(raw) != 12 * n:
        raise ProtocolError("cloth_mesh: vertices do not hold n_vertices x 3 float32")
    v = np.frombuffer(raw, dtype="<f4").reshape(n, 3).astype(np.float32)
    if not np.isfinite(v).all() or np.abs(v).max() > 50.0:
        raise ProtocolError("cloth_mesh: vertices not finite or beyond 50 m")
    tri = None
    if "triangles" in obj:
        t = _get(obj, "triangles", bytes, "cloth_mesh")
        if len(t) % 12 or not t:
            raise ProtocolError("cloth_mesh: triangles do not hold T x 3 uint32")
        tri = np.frombuffer(t, dtype="<u4").reshape(-1, 3).astype(np.uint32)
        if int(tri.max()) >= n:
            raise ProtocolError("cloth_mesh: a triangle index is out of range")
    seq = _get(obj, "seq", int, "cloth_mesh")
    if not 0 <= seq < 2**63:
        raise ProtocolError("cloth_mesh: seq out of range")
    return ClothMesh(_text(obj, "cloth_id", _ID, "cloth_mesh"), seq,
                     float(_get(obj, "ts", (int, float), "cloth_mesh")),
                     float(_get(obj, "capture_ts", (int, float), "cloth_mesh")),
                     _text(obj, "garment", _NAME, "cloth_mesh"), v, tri)
