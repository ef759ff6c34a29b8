"""BVH motion files: a strict reader (any channel and rotation order, both offset conventions,
unit detection) with forward kinematics of the file's own skeleton, and a writer for our skeleton.

Offset conventions
------------------
* ``"add"`` (the BVH standard, CMU): a joint's position channels are added to its ``OFFSET``.
* ``"replace"`` (Bandai Namco): every joint has 6 channels whose positions *are* the joint's local
  translation and replace the ``OFFSET`` (adding them doubles every bone).
``"auto"`` picks ``replace`` when non-root joints carry position channels whose values match their
``OFFSET``\\ s, else ``add``.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from protocol.rotations import euler_to_matrix, matrix_to_euler, rotvec_to_matrix
from protocol.skeleton import END_JOINTS, JOINT_NAMES, N_JOINTS, PARENTS, POSE_SIZE, ROT_SLOT, Body

__all__ = ["BvhError", "BvhFile", "BvhJoint", "bvh_fk", "read_bvh", "write_bvh"]

log = logging.getLogger(__name__)

OffsetMode = Literal["auto", "add", "replace"]
_ROT = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}
_POS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}


#: Accepted ``Frame Time`` range (seconds): 10 kHz down to one frame per 10 s.
MIN_FRAME_TIME = 1e-4
MAX_FRAME_TIME = 10.0
#: Largest accepted magnitude of a position channel (file units) and a rotation channel (degrees).
MAX_TRANSLATION = 1e4
MAX_ROTATION_DEG = 1e6


class BvhError(ValueError):
    """A malformed BVH file; the message names the file and the line."""

    def __init__(self, path: str | Path, line: int, what: str) -> None:
        super().__init__(f"{path}:{line}: {what}")
        self.path = str(path)
        self.line = line


@dataclass(frozen=True)
class BvhJoint:
    """One joint of a BVH hierarchy.

    Attributes
    ----------
    name : str
    parent : int
        Index of the parent joint, -1 for the root.
    offset : (3,) float64
        ``OFFSET`` in file units.
    channels : tuple[str, ...]
        Channel names in file order.
    channel_start : int
        Column of the first channel in the motion table.
    end_site : (3,) float64 or None
        ``End Site`` offset, if the joint has one.
    """

    name: str
    parent: int
    offset: NDArray[np.float64]
    channels: tuple[str, ...]
    channel_start: int
    end_site: NDArray[np.float64] | None

    @property
    def rotation_order(self) -> str:
        return "".join(_ROT[c] for c in self.channels if c in _ROT)


@dataclass(frozen=True)
class BvhFile:
    """A parsed BVH file.

    Attributes
    ----------
    path : str
    joints : tuple[BvhJoint, ...]
        In file (depth-first) order, so parents precede children.
    frame_time : float
        Seconds per frame as stamped in the file.
    motion : (F, C) float64
        Channel values, file units and degrees.
    offset_mode : {'add', 'replace'}
        The resolved offset convention.
    """

    path: str
    joints: tuple[BvhJoint, ...]
    frame_time: float
    motion: NDArray[np.float64]
    offset_mode: Literal["add", "replace"]

    @property
    def names(self) -> list[str]:
        return [j.name for j in self.joints]

    @property
    def n_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def fps(self) -> float:
        """Frames per second; ``1 / frame_time`` snapped to a whole number when within 0.1 %
        (files stamp 0.0083333 for 120 Hz)."""
        f = 1.0 / self.frame_time
        return float(round(f)) if abs(f - round(f)) < 1e-3 * f else f


def _tokens(text: str) -> list[tuple[str, int]]:
    out: list[tuple[str, int]] = []
    for ln, line in enumerate(text.splitlines(), start=1):
        for tok in re.findall(r"[{}]|[^\s{}]+", line):
            out.append((tok, ln))
    return out


def read_bvh(path: str | Path, offset_mode: OffsetMode = "auto", *, text: str | None = None) -> BvhFile:
    """Parse a BVH file strictly.

    Parameters
    ----------
    path : str or Path
        File to read (also used in error messages when ``text`` is given).
    offset_mode : {'auto', 'add', 'replace'}
        Offset convention (see module docstring).
    text : str, optional
        File contents, if already in memory.

    Returns
    -------
    BvhFile

    Raises
    ------
    BvhError
        Malformed hierarchy or motion section (message names file and line).
    OSError
        The file cannot be read.
    """
    if text is None:
        raw = Path(path).read_bytes()
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            text = raw.decode("latin-1")
    m = re.search(r"^\s*MOTION\s*$", text, flags=re.MULTILINE)
    if not text.lstrip().startswith("HIERARCHY"):
        raise BvhError(path, 1, "expected 'HIERARCHY' at the start of the file")
    if m is None:
        raise BvhError(path, text.count("\n") + 1, "no 'MOTION' section")
    head = text[: m.start()]
    motion_line0 = head.count("\n") + 1
    joints = _parse_hierarchy(path, head)
    n_channels = sum(len(j.channels) for j in joints)
    motion = _parse_motion(path, text[m.end():], motion_line0, n_channels)
    frames, frame_time = motion
    _check_channel_values(path, joints, frames, motion_line0)
    mode = _resolve_offset_mode(joints, frames, offset_mode)
    return BvhFile(path=str(path), joints=tuple(joints), frame_time=frame_time, motion=frames, offset_mode=mode)


def _parse_hierarchy(path: str | Path, head: str) -> list[BvhJoint]:
    toks = _tokens(head)
    i = 1  # skip HIERARCHY
    joints: list[BvhJoint] = []
    stack: list[int] = []  # indices of open joints; -2 marks an open End Site
    col = 0
    pending: dict[str, object] | None = None

    def need(k: int, what: str) -> None:
        if k >= len(toks):
            raise BvhError(path, toks[-1][1] if toks else 1, f"unexpected end of hierarchy, expected {what}")

    def number(k: int) -> float:
        need(k, "a number")
        try:
            v = float(toks[k][0])
        except ValueError:
            raise BvhError(path, toks[k][1], f"expected a number, got {toks[k][0]!r}") from None
        if not np.isfinite(v):
            raise BvhError(path, toks[k][1], f"non-finite number {toks[k][0]!r}")
        return v

    end_sites: dict[int, NDArray[np.float64]] = {}
    while i < len(toks):
        tok, ln = toks[i]
        if tok in ("ROOT", "JOINT"):
            if (tok == "ROOT") != (not stack):
                raise BvhError(path, ln, f"{tok} not allowed here")
            need(i + 1, "a joint name")
            pending = {"name": toks[i + 1][0], "line": ln}
            i += 2
            need(i, "'{'")
            if toks[i][0] != "{":
                raise BvhError(path, toks[i][1], f"expected '{{' after {tok} {pending['name']}")
            i += 1
            # OFFSET then CHANNELS
            need(i, "OFFSET")
            if toks[i][0] != "OFFSET":
                raise BvhError(path, toks[i][1], f"expected OFFSET in joint {pending['name']}")
            off = np.array([number(i + 1), number(i + 2), number(i + 3)])
            i += 4
            need(i, "CHANNELS")
            if toks[i][0] != "CHANNELS":
                raise BvhError(path, toks[i][1], f"expected CHANNELS in joint {pending['name']}")
            try:
                nch = int(toks[i + 1][0])
            except (ValueError, IndexError):
                raise BvhError(path, toks[i][1], "CHANNELS needs a count") from None
            chans = tuple(t for t, _ in toks[i + 2: i + 2 + nch])
            if len(chans) != nch or any(c not in _ROT and c not in _POS for c in chans):
                raise BvhError(path, toks[i][1], f"bad channel list {chans!r}")
            if sum(c in _ROT for c in chans) not in (0, 3) or len(set(chans)) != len(chans):
                raise BvhError(path, toks[i][1], f"need 0 or 3 distinct rotation channels, got {chans!r}")
            i += 2 + nch
            parent = stack[-1] if stack else -1
            joints.append(BvhJoint(str(pending["name"]), parent, off, chans, col, None))
            col += nch
            stack.append(len(joints) - 1)
        elif tok == "End":
            if not stack or stack[-1] < 0:
                raise BvhError(path, ln, "End Site outside a joint")
            if i + 3 >= len(toks) or toks[i + 1][0] != "Site" or toks[i + 2][0] != "{" or toks[i + 3][0] != "OFFSET":
                raise BvhError(path, ln, "malformed End Site")
            end_sites[stack[-1]] = np.array([number(i + 4), number(i + 5), number(i + 6)])
            i += 7
            need(i, "'}'")
            if toks[i][0] != "}":
                raise BvhError(path, toks[i][1], "expected '}' closing End Site")
            i += 1
        elif tok == "}":
            if not stack:
                raise BvhError(path, ln, "unbalanced '}'")
            stack.pop()
            i += 1
        else:
            raise BvhError(path, ln, f"unexpected token {tok!r} in hierarchy")
    if stack:
        raise BvhError(path, toks[-1][1] if toks else 1, "hierarchy not closed ('}' missing)")
    if not joints:
        raise BvhError(path, 1, "no ROOT joint")
    return [
        BvhJoint(j.name, j.parent, j.offset, j.channels, j.channel_start, end_sites.get(k))
        for k, j in enumerate(joints)
    ]


def _parse_motion(path: str | Path, body: str, line0: int, n_channels: int) -> tuple[NDArray[np.float64], float]:
    lines = body.split("\n")
    k = 1  # lines[0] is the rest of the MOTION line
    while k < len(lines) and not lines[k].strip():
        k += 1
    fm = re.match(r"\s*Frames:\s*(\d+)\s*$", lines[k] if k < len(lines) else "")
    if not fm:
        raise BvhError(path, line0 + k, "expected 'Frames: N'")
    n_frames = int(fm.group(1))
    tm = re.match(r"\s*Frame Time:\s*(\S+)\s*$", lines[k + 1] if k + 1 < len(lines) else "")
    try:
        frame_time = float(tm.group(1)) if tm else float("nan")
    except ValueError:
        frame_time = float("nan")
    if not (frame_time > 0 and np.isfinite(frame_time)):
        raise BvhError(path, line0 + k + 1, "expected 'Frame Time: <seconds > 0>'")
    if not (MIN_FRAME_TIME <= frame_time <= MAX_FRAME_TIME):
        raise BvhError(path, line0 + k + 1, f"Frame Time {frame_time:g} s is outside the accepted range "
                       f"[{MIN_FRAME_TIME:g}, {MAX_FRAME_TIME:g}] s ({1 / MAX_FRAME_TIME:g} to "
                       f"{1 / MIN_FRAME_TIME:g} fps)")
    data_lines = lines[k + 2:]
    while data_lines and not data_lines[-1].strip():
        data_lines.pop()
    first = line0 + k + 2
    if len(data_lines) < n_frames:
        raise BvhError(path, first + len(data_lines),
                       f"truncated: header says {n_frames} frames, found {len(data_lines)}")
    if len(data_lines) > n_frames:
        raise BvhError(path, first + n_frames, f"header says {n_frames} frames but more data follows")
    try:
        values = np.array(" ".join(data_lines).split(), dtype=np.float64)
    except ValueError:
        values = None
    if values is None or values.size != n_frames * n_channels or not np.all(np.isfinite(values)):
        for r, ln in enumerate(data_lines):
            parts = ln.split()
            if len(parts) != n_channels:
                raise BvhError(path, first + r, f"expected {n_channels} values, found {len(parts)}")
            try:
                row = np.array(parts, dtype=np.float64)
            except ValueError:
                raise BvhError(path, first + r, "non-numeric value in motion data") from None
            if not np.all(np.isfinite(row)):
                raise BvhError(path, first + r, "NaN or infinite value in motion data")
        raise BvhError(path, first, "malformed motion data")  # pragma: no cover - defensive
    return values.reshape(n_frames, n_channels), frame_time


def _check_channel_values(path: str | Path, joints: list[BvhJoint], frames: NDArray[np.float64],
                          motion_line0: int) -> None:
    """Reject absurd channel values (|position| > MAX_TRANSLATION, |rotation| > MAX_ROTATION_DEG)."""
    if frames.size == 0:
        return
    # the first data line: MOTION, Frames:, Frame Time: (blank lines between are rare; the line is
    # approximate only when they occur)
    first = motion_line0 + 3
    for j in joints:
        for c, ch in enumerate(j.channels):
            col = frames[:, j.channel_start + c]
            limit, unit = (MAX_TRANSLATION, "units") if ch in _POS else (MAX_ROTATION_DEG, "degrees")
            bad = np.flatnonzero(~(np.abs(col) <= limit))
            if bad.size:
                r = int(bad[0])
                raise BvhError(path, first + r, f"absurd value {col[r]:g} in channel {ch} of joint {j.name} "
                               f"(frame {r + 1}; accepted |value| <= {limit:g} {unit})")


def _resolve_offset_mode(joints: list[BvhJoint], frames: NDArray[np.float64],
                         mode: OffsetMode) -> Literal["add", "replace"]:
    if mode in ("add", "replace"):
        return mode
    if mode != "auto":
        raise ValueError(f"offset_mode must be auto, add or replace, got {mode!r}")
    diffs, sizes = [], []
    for j in joints[1:]:
        cols = [j.channel_start + q for q, c in enumerate(j.channels) if c in _POS]
        if len(cols) == 3 and frames.shape[0] > 0:
            order = [_POS[c] for c in j.channels if c in _POS]
            pos = np.empty(3)
            pos[order] = frames[0, cols]
            diffs.append(np.linalg.norm(pos - j.offset))
            sizes.append(np.linalg.norm(j.offset))
    if not diffs:
        return "add"
    # positions equal to the offsets -> they are meant to replace them
    return "replace" if np.median(diffs) < 0.05 * max(float(np.median(sizes)), 1e-9) else "add"


def bvh_fk(bvh: BvhFile, scale: float = 1.0, root_translation_scale: float | None = None
           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Forward kinematics of the file's own skeleton.

    Parameters
    ----------
    bvh : BvhFile
    scale : float
        File units -> metres for offsets and non-root translations.
    root_translation_scale : float, optional
        File units -> metres for the root's position channels (defaults to ``scale``; some
        conversions store the root translation in other units than the bones).

    Returns
    -------
    positions : (F, Jb, 3) float64
        Joint positions, metres.
    rotations : (F, Jb, 3, 3) float64
        Global joint orientations.
    """
    f = bvh.n_frames
    nj = len(bvh.joints)
    pos = np.zeros((f, nj, 3))
    rot = np.zeros((f, nj, 3, 3))
    rts = scale if root_translation_scale is None else root_translation_scale
    for k, j in enumerate(bvh.joints):
        chans = j.channels
        loc = np.broadcast_to(j.offset * scale, (f, 3)).copy()
        pcols = [(j.channel_start + q, _POS[c]) for q, c in enumerate(chans) if c in _POS]
        if pcols:
            s = rts if j.parent < 0 else scale
            tr = np.zeros((f, 3))
            for col, ax in pcols:
                tr[:, ax] = bvh.motion[:, col] * s
            loc = tr if (bvh.offset_mode == "replace" and len(pcols) == 3) else loc + tr
        rcols = [j.channel_start + q for q, c in enumerate(chans) if c in _ROT]
        if rcols:
            r = euler_to_matrix(np.radians(bvh.motion[:, rcols]), j.rotation_order)
        else:
            r = np.broadcast_to(np.eye(3), (f, 3, 3))
        if j.parent < 0:
            pos[:, k] = loc
            rot[:, k] = r
        else:
            pr = rot[:, j.parent]
            pos[:, k] = pos[:, j.parent] + np.einsum("fij,fj->fi", pr, loc)
            rot[:, k] = pr @ r
    return pos, rot


_OUR_ORDER = "ZXY"


def write_bvh(path: str | Path, poses: NDArray[np.float64], body: Body, fps: float) -> None:
    """Write poses on our skeleton as a standard BVH file (centimetres, ZXY Euler channels).

    Parameters
    ----------
    path : str or Path
    poses : (F, P) float
    body : Body
        Supplies the rest offsets written in the hierarchy.
    fps : float
        Frame rate (``Frame Time = 1 / fps``).
    """
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != POSE_SIZE:
        raise ValueError(f"poses must be (F, {POSE_SIZE})")
    if not fps > 0:
        raise ValueError("fps must be positive")
    cm = 100.0
    children: dict[int, list[int]] = {i: [] for i in range(N_JOINTS)}
    for j, par in enumerate(PARENTS):
        if par >= 0:
            children[par].append(j)
    lines = ["HIERARCHY"]
    order: list[int] = []  # joints with channels, in file order

    def emit(j: int, depth: int) -> None:
        ind = "  " * depth
        off = body.offsets[j] * cm
        if JOINT_NAMES[j] in END_JOINTS:
            lines.extend([f"{ind}End Site", f"{ind}{{", f"{ind}  OFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}",
                          f"{ind}}}"])
            return
        kind = "ROOT" if PARENTS[j] < 0 else "JOINT"
        lines.extend([f"{ind}{kind} {JOINT_NAMES[j]}", f"{ind}{{",
                      f"{ind}  OFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}"])
        rch = " ".join(f"{a}rotation" for a in _OUR_ORDER)
        if PARENTS[j] < 0:
            lines.append(f"{ind}  CHANNELS 6 Xposition Yposition Zposition {rch}")
        else:
            lines.append(f"{ind}  CHANNELS 3 {rch}")
        order.append(j)
        for c in children[j]:
            emit(c, depth + 1)
        lines.append(f"{ind}}}")

    emit(0, 0)
    n = p.shape[0]
    rot = rotvec_to_matrix(p[:, 3:].reshape(n, -1, 3))
    cols = [p[:, :3] * cm]
    for j in order:
        cols.append(np.degrees(matrix_to_euler(rot[:, ROT_SLOT[j]], _OUR_ORDER)))
    table = np.concatenate(cols, axis=1)
    lines.extend(["MOTION", f"Frames: {n}", f"Frame Time: {1.0 / fps:.9f}"])
    body_txt = "\n".join(" ".join(f"{v:.6f}" for v in row) for row in table)
    Path(path).write_text("\n".join(lines) + "\n" + body_txt + ("\n" if n else ""))
