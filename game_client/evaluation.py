"""Scoring recognised gestures against ground truth, and degrading pose streams like a tracker would.

Used by the tests and ``bench/bench_game.py``; pure functions over arrays and event lists.

Matching
--------
A ground-truth gesture (:class:`~game_client.variants.Label`) is matched by at most one event of the
same gesture (and side-step direction) recognised within ``[end_s - early_s, end_s + late_s]``
(stream time of recognition). Labels and events are matched greedily in time order. Unmatched
events are false positives, unmatched labels misses. The latency of a match is the event's
recognition time minus the label's ``end_s`` (negative: recognised before the motion finished).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import N_PARTS, PARTS

from .gestures import GestureEvent, RecognizerConfig, recognize
from .variants import Label, Variant, load_labels, variant_labels, variant_motion

__all__ = ["Case", "Match", "Score", "allowed_gestures", "degrade", "expected_gestures",
           "match_events", "occlude", "random_cases", "recording", "run_case", "turn_in_place"]

@dataclass(frozen=True)
class Match:
    """Result of matching one sequence's events to its labels."""

    pairs: tuple[tuple[Label, GestureEvent], ...]
    false_positives: tuple[GestureEvent, ...]
    misses: tuple[Label, ...]

    @property
    def latencies_ms(self) -> list[float]:
        """Recognition time minus ground-truth end, milliseconds, one per matched pair."""
        return [1000.0 * (e.t - lb.end_s) for lb, e in self.pairs]

    @property
    def in_order(self) -> bool:
        """True if the matched events come in the labels' order."""
        ts = [e.t for _, e in self.pairs]
        return ts == sorted(ts)


def match_events(events: Sequence[GestureEvent], labels: Sequence[Label], *, early_s: float = 1.2,
                 late_s: float = 0.5) -> Match:
    """Match recognised events to ground truth (see the module docstring)."""
    used: set[int] = set()
    pairs: list[tuple[Label, GestureEvent]] = []
    misses: list[Label] = []
    for lb in sorted(labels, key=lambda x: x.end_s):
        hit = next((k for k, e in enumerate(events)
                    if k not in used and e.gesture.value == lb.gesture
                    and (lb.direction is None or e.direction == lb.direction)
                    and lb.end_s - early_s <= e.t <= lb.end_s + late_s), None)
        if hit is None:
            misses.append(lb)
        else:
            used.add(hit)
            pairs.append((lb, events[hit]))
    fps = tuple(e for k, e in enumerate(events) if k not in used)
    return Match(tuple(pairs), fps, tuple(misses))


@dataclass
class Score:
    """Counts per gesture over many sequences, and the latencies of the matches."""

    tp: dict[str, int] = field(default_factory=dict)
    fp: dict[str, int] = field(default_factory=dict)
    fn: dict[str, int] = field(default_factory=dict)
    latencies_ms: dict[str, list[float]] = field(default_factory=dict)
    out_of_order: int = 0

    def add(self, m: Match) -> None:
        """Accumulate one sequence's match."""
        for lb, _ in m.pairs:
            self.tp[lb.gesture] = self.tp.get(lb.gesture, 0) + 1
        for lb, lat in zip((lb for lb, _ in m.pairs), m.latencies_ms, strict=True):
            self.latencies_ms.setdefault(lb.gesture, []).append(lat)
        for e in m.false_positives:
            self.fp[e.gesture.value] = self.fp.get(e.gesture.value, 0) + 1
        for lb in m.misses:
            self.fn[lb.gesture] = self.fn.get(lb.gesture, 0) + 1
        self.out_of_order += 0 if m.in_order else 1

    def gestures(self) -> list[str]:
        """Every gesture seen in the counts, sorted."""
        return sorted(set(self.tp) | set(self.fp) | set(self.fn))

    def precision(self, g: str) -> float:
        """tp / (tp + fp); 1.0 when nothing was recognised."""
        tp, fp = self.tp.get(g, 0), self.fp.get(g, 0)
        return tp / (tp + fp) if tp + fp else 1.0

    def recall(self, g: str) -> float:
        """tp / (tp + fn); 1.0 when there was nothing to find."""
        tp, fn = self.tp.get(g, 0), self.fn.get(g, 0)
        return tp / (tp + fn) if tp + fn else 1.0

    def latency_percentile(self, q: float, g: str | None = None) -> float:
        """``q``-th percentile of the latencies (ms) of gesture ``g`` (all gestures if ``None``)."""
        vals = self.latencies_ms.get(g, []) if g else [x for v in self.latencies_ms.values() for x in v]
        return float(np.percentile(vals, q)) if vals else float("nan")


def degrade(times: NDArray[np.floating], joints: NDArray[np.floating], rng: np.random.Generator, *,
            jitter_m: float = 0.0, drop_p: float = 0.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Add per-joint position jitter and drop random frames, as an imperfect tracker would.

    Parameters
    ----------
    times : (N,) float
    joints : (N, J, 3) float
    rng : np.random.Generator
    jitter_m : float
        Standard deviation of independent Gaussian noise on every joint coordinate, metres.
    drop_p : float
        Probability of dropping each frame (the first and last frames are kept).

    Returns
    -------
    times : (M,) float64
    joints : (M, J, 3) float64
    """
    t = np.asarray(times, dtype=np.float64)
    j = np.asarray(joints, dtype=np.float64)
    if jitter_m > 0:
        j = j + rng.normal(0.0, jitter_m, j.shape)
    keep = rng.random(len(t)) >= drop_p
    keep[[0, -1]] = True
    return t[keep], j[keep]


def turn_in_place(joints: NDArray[np.floating], yaw_deg: NDArray[np.floating] | float) -> NDArray[np.float64]:
    """Each frame's body turned about the vertical through its pelvis by ``yaw_deg`` (per frame or
    one value; positive turns +Z towards +X): the pelvis path is kept, the facing changes, as when a
    single-camera tracker's heading wanders while the player faces the camera.

    Parameters
    ----------
    joints : (N, J, 3) float
    yaw_deg : (N,) float or float

    Returns
    -------
    (N, J, 3) float64
    """
    j = np.asarray(joints, dtype=np.float64)
    a = np.radians(np.broadcast_to(np.asarray(yaw_deg, dtype=np.float64), (len(j),)))[:, None]
    c, s = np.cos(a), np.sin(a)
    p = j[:, :1, :]
    x, z = j[:, :, 0] - p[:, :, 0], j[:, :, 2] - p[:, :, 2]
    out = j.copy()
    out[:, :, 0] = p[:, :, 0] + c * x + s * z
    out[:, :, 2] = p[:, :, 2] - s * x + c * z
    return out


def occlude(times: NDArray[np.floating], parts: Iterable[str], t0: float, t1: float,
            level: float = 0.0) -> NDArray[np.float64]:
    """Visibility ``(N, N_PARTS)`` with the named parts at ``level`` between ``t0`` and ``t1`` (else 1)."""
    t = np.asarray(times, dtype=np.float64)
    vis = np.ones((len(t), N_PARTS))
    cols = np.array([PARTS.index(p) for p in parts], dtype=np.int64)
    rows = np.flatnonzero((t >= t0) & (t <= t1))
    vis[np.ix_(rows, cols)] = level
    return vis


@dataclass(frozen=True)
class Case:
    """One scripted test sequence: a bundled script under a variant, degraded like a tracker would."""

    script: str
    variant: Variant
    jitter_m: float = 0.0
    drop_p: float = 0.0
    seed: int = 0

    @property
    def tag(self) -> str:
        """Readable identifier (script, variant, jitter, drops, seed)."""
        return f"{self.script}[{self.variant.tag}_j{self.jitter_m:g}_d{self.drop_p:g}_s{self.seed}]"


def random_cases(rng: np.random.Generator, per_script: int, scripts: Iterable[str] | None = None) -> list[Case]:
    """Random variants of the bundled scripts over the ranges the recogniser must handle.

    Speed 0.7-1.4x, amplitude 0.85-1.15, body height 1.5-1.95 m, facing -60..60 deg, rotation
    jitter 0-2 deg per joint, joint jitter 0 or 1 cm, 0 or 10 % dropped frames, 15/30/60/120 Hz.
    Whole-round scripts (``round_*``, composed for the default body and timed against the game's
    schedule) only vary in facing, jitter, drops and rate.
    """
    names = list(scripts) if scripts is not None else list(load_labels())
    cases = []
    for name in names:
        whole = name.startswith("round_")
        for _ in range(per_script):
            speed = float(rng.choice([0.7, 0.85, 1.0, 1.2, 1.4]))
            amplitude = float(rng.choice([0.85, 1.0, 1.15]))
            height = float(rng.choice([1.5, 1.7, 1.95]))
            v = Variant(speed=1.0 if whole else speed, amplitude=1.0 if whole else amplitude,
                        height_m=None if whole else height,
                        yaw_deg=round(float(rng.uniform(-60.0, 60.0)), 1),
                        noise_rot_deg=float(rng.choice([0.0, 1.0, 2.0])), noise_pos_m=0.005,
                        seed=int(rng.integers(1_000_000)), fps=float(rng.choice([15, 30, 60, 120])))
            cases.append(Case(name, v, float(rng.choice([0.0, 0.01])), float(rng.choice([0.0, 0.1])),
                              int(rng.integers(1_000_000))))
    return cases


def run_case(case: Case, config: RecognizerConfig | None = None,
             labels: dict[str, tuple[Label, ...]] | None = None) -> tuple[Match, int]:
    """Recognise one case and match it to its labels; also returns the number of frames fed."""
    from protocol.kinematics import fk

    lbs = (labels or load_labels())[case.script]
    m = variant_motion(case.script, case.variant)
    t, j = degrade(m.times, fk(m.poses, m.body), np.random.default_rng(case.seed),
                   jitter_m=case.jitter_m, drop_p=case.drop_p)
    events = recognize(t, j, config=config)
    return match_events(events, variant_labels(lbs, case.variant)), len(t)


def expected_gestures(tags: Iterable[str]) -> tuple[str, ...]:
    """Gestures a shared recording must yield, from its ``INDEX.tsv`` tags (one fire ring for
    ``firering_like`` takes, nothing otherwise)."""
    return ("fire_ring",) if "firering_like" in set(tags) else ()


def allowed_gestures(tags: Iterable[str]) -> frozenset[str]:
    """Gestures a shared recording may yield without counting as false: the expected ones, a
    strike in ``strike_like`` takes (a right arm or sword swung up and dropped fast) and a crouch
    in ``crouch`` takes."""
    t = set(tags)
    out = set(expected_gestures(t))
    if "strike_like" in t:
        out.add("strike")
    if "crouch" in t:
        out.add("crouch")
    return frozenset(out)


def recording(path: str, fps: float | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Frame times ``(N,)``, joints ``(N, 24, 3)`` and body height of a shared recording.

    ``path`` is relative to :func:`protocol.formats.mocap_data.mocap_root`; the motion is retargeted onto the
    default body by :func:`protocol.formats.load.load_motion` (optionally resampled to ``fps``).
    """
    from protocol.formats.load import load_motion
    from protocol.formats.mocap_data import recording_path
    from protocol.kinematics import fk

    m = load_motion(recording_path(path), fps=fps)
    return m.times, fk(m.poses, m.body), m.body.height
