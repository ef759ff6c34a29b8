"""Training the appearance cue's network (:mod:`tracker_service.cues.appearance`) on rendered views of
the training recordings and gesture scripts.

Data: every ``every``-th frame of every training take (the held-out takes,
``tracker_service.build.database.is_held_out``,
are never used; the gesture scripts the database holds are takes too, numbered from
:data:`SCRIPT_ROW_BASE`) played by the synthetic scene on a random person (``seed_base + row``
chooses the person, the outfit, the room and the lighting; the benchmark subjects' seeds 3, 7 and
11 are not among them). Posture passes play the poses stooped and with bent knees first
(:mod:`tracker_service.build.posture_variation`). Each sample is
:func:`~tracker_service.cues.appearance.person_crop` of a silhouette and the joints relative to
the pelvis in the camera's axes over the person's height. The silhouette is the tracker's own by
default (``TrainConfig.masks``): background subtraction against a model learned from the empty
room's first frames, as :func:`tracker_service.pipeline.process.process_frame` observes it, with
its holes where the person's colours are the room's and its shadows; or the renderer's exact one
(``"truth"``). Frames whose true silhouette touches the image border are skipped. Rendered samples
are cached per take and pass under the network's folder (``data/``), so a second training does not
render again.

Network: five 3 x 3 convolutions with batch norm and ReLU (the first with stride 2, max pools after
the second, third and fourth), then two dense layers; the output is the 72 coordinates and their 72
log variances. Loss: the Gaussian negative log likelihood plus ``mse_weight`` times the squared
error (which keeps the means from being traded for large variances early on). Augmentation: left-
right mirroring (joints swapped and ``x`` negated), brightness, contrast and colour-balance jitter,
and the mask grown or shrunk by a pixel (the observed silhouette is not the true one). Training
needs PyTorch (CPU build; ``pip install torch``), inference does not: the batch norms are folded
into the convolutions and the layers exported for the numpy forward pass.
"""

from __future__ import annotations

import logging
import os
import time
import zipfile
import zlib
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import MIRROR_JOINTS, N_JOINTS
from tracker_service.build.posture_variation import POSTURE_VERSION, PostureParams, vary_posture
from tracker_service.cues.appearance import AppearanceNet, Layer, camera_joints, in_view, person_crop
from tracker_service.pipeline.config import TrackerConfig
from tracker_service.silhouette.background import learn_background, subtract

__all__ = ["MASK_SOURCES", "MASK_VERSION", "MEMBER_PASSES", "MEMBER_POSTURE_PASSES", "MEMBER_VARY_PASSES",
           "SCRIPT_ROW_BASE", "VARY_VERSION",
           "Samples", "TrainConfig", "config_samples",
           "export_layers", "member_extra_passes", "render_samples", "render_take",
           "train_network", "training_takes", "vary_axes"]

log = logging.getLogger(__name__)

#: Bumped whenever the subtracted training silhouettes change (:func:`render_take`): their cached
#: renders are named with it.
MASK_VERSION = 1

#: ``TrainConfig.masks`` choices.
MASK_SOURCES = ("subtracted", "truth")


@dataclass(frozen=True)
class TrainConfig:
    """How the network is trained (defaults: the product's network, docs/TRACKER.md).

    Attributes
    ----------
    size : int
        Input side (pixels).
    width : int
        Channels of the first convolution (the others are 2, 4, 8 and 8 times it). 24: the joints are
        5 % better than at 16, at +1.7 ms a frame (docs/TRACKER.md).
    passes : tuple of (int, int)
        ``(seed_base, every)`` per pass over the training takes: each pass renders every take on
        another person, every ``every``-th frame.
    posture_passes : tuple of (int, int)
        More passes, their poses varied by ``posture`` (:mod:`tracker_service.build.posture_variation`).
    vary_passes : tuple of (int, int)
        More passes in a randomised scene: each take on its person varied along one or two axes of
        :data:`tracker_service.scene.variation.AXES` (:func:`vary_axes`).
    posture : PostureParams
        How the posture passes vary the poses.
    epochs, batch : int
    lr, weight_decay : float
        AdamW with a one-cycle learning-rate schedule peaking at ``lr``.
    mse_weight : float
        Weight of the squared-error term beside the Gaussian negative log likelihood.
    validation_every : int
        Every this many-th training take is kept out of training to report the validation error.
    seed : int
        Initial weights, sample order and augmentation.
    masks : {"subtracted", "truth"}
        The silhouette each view is cropped and masked with: the tracker's background subtraction
        (what the network reads at run time) or the renderer's exact silhouette.
    """

    size: int = 64
    width: int = 24
    passes: tuple[tuple[int, int], ...] = ((1000, 3), (2000, 2), (3000, 2), (4000, 2))
    posture_passes: tuple[tuple[int, int], ...] = ()
    vary_passes: tuple[tuple[int, int], ...] = ()
    posture: PostureParams = field(default_factory=PostureParams)
    epochs: int = 15
    batch: int = 64
    lr: float = 2e-3
    weight_decay: float = 1e-4
    mse_weight: float = 100.0
    validation_every: int = 20
    seed: int = 0
    masks: str = "subtracted"

    def __post_init__(self) -> None:
        if self.masks not in MASK_SOURCES:
            raise ValueError(f"TrainConfig.masks must be one of {', '.join(MASK_SOURCES)}, not {self.masks!r}")
        if min(self.size, self.width, self.epochs, self.batch, self.validation_every) < 1:
            raise ValueError("TrainConfig: size, width, epochs, batch and validation_every must be positive")


#: The passes of each network of the product's ensemble (``train-appearance``'s default): the first
#: network sees :class:`TrainConfig`'s default passes; the second sees two other people per take and
#: shares two passes with the first.
MEMBER_PASSES: tuple[tuple[tuple[int, int], ...], ...] = (
    ((1000, 3), (2000, 2), (3000, 2), (4000, 2)),
    ((5000, 2), (6000, 2), (2000, 2), (3000, 2)),
)
#: Each network's passes with varied postures (:mod:`tracker_service.build.posture_variation`).
MEMBER_POSTURE_PASSES: tuple[tuple[tuple[int, int], ...], ...] = (((7000, 3),), ((8000, 3),))


#: Each network's passes in a randomised scene (:func:`vary_axes`).
MEMBER_VARY_PASSES: tuple[tuple[tuple[int, int], ...], ...] = (((9000, 3),), ((10000, 3),))

#: Bumped whenever :func:`vary_axes` (or what an axis draws) changes: cached renders are named with it.
VARY_VERSION = 1


def member_extra_passes(table: tuple[tuple[tuple[int, int], ...], ...], n: int
                        ) -> tuple[tuple[tuple[int, int], ...], ...]:
    """The default extra passes (:data:`MEMBER_POSTURE_PASSES`, :data:`MEMBER_VARY_PASSES`) of an
    ensemble of ``n`` networks: networks beyond the table get none."""
    return (*table, *((),) * n)[:n]


def vary_axes(seed: int) -> tuple[str, ...]:
    """The domain-randomisation axes of one training take on the person ``seed`` draws: one axis of
    :data:`~tracker_service.scene.variation.AXES` (two thirds of the takes) or two, drawn from their
    own stream of ``seed``, so that every axis is seen alone and in company.

    Parameters
    ----------
    seed : int

    Returns
    -------
    tuple of str
        In :data:`~tracker_service.scene.variation.AXES`'s order.
    """
    from tracker_service.scene.variation import AXES

    rng = np.random.default_rng([int(seed), 6])
    k = 1 if rng.random() < 2 / 3 else 2
    chosen = set(rng.choice(len(AXES), size=k, replace=False).tolist())
    return tuple(a for i, a in enumerate(AXES) if i in chosen)


@dataclass(frozen=True)
class Samples:
    """Training samples.

    Attributes
    ----------
    crops : (N, S, S, 3) uint8
    masks : (N, S, S) bool
    joints : (N, J, 3) float32
        Relative to the pelvis, camera axes, over the person's height.
    take : (N,) int64
        INDEX.tsv row of each sample's take.
    """

    crops: NDArray[np.uint8]
    masks: NDArray[np.bool_]
    joints: NDArray[np.float32]
    take: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))

    def __len__(self) -> int:
        return len(self.crops)


def render_take(path: str | Path, seed: int, every: int, size: int, posture: PostureParams | None = None,
                axes: tuple[str, ...] = (), subtracted: bool = False) -> Samples:
    """Samples of one recording or gesture script played on the person ``seed`` chooses.

    Parameters
    ----------
    path : str or Path
    seed : int
    every : int
        Every this many-th frame (the first one drawn from ``seed``).
    size : int
        Crop side.
    posture : PostureParams, optional
        Vary the poses first (:func:`tracker_service.build.posture_variation.vary_posture`, drawn from
        ``seed`` too).
    axes : tuple of str, optional
        Domain-randomisation axes of the scene (:class:`~tracker_service.scene.synthetic.SceneConfig`).
    subtracted : bool
        Crop and mask each view with the tracker's silhouette: background subtraction
        (:func:`~tracker_service.silhouette.background.subtract`, the tracker's parameters) against a
        model learned from the empty room's first ``TrackerConfig.background_frames`` frames. A view
        whose subtracted silhouette is empty is skipped. False: the renderer's exact silhouette.

    Returns
    -------
    Samples
        ``take`` left empty (the caller knows it).
    """
    from protocol.formats.load import load_motion
    from tracker_service.scene.synthetic import SceneConfig, SyntheticScene

    motion = load_motion(path, fps=30.0)
    if posture is not None:
        motion = replace(motion, poses=vary_posture(motion.poses, motion.body, np.random.default_rng([seed, 1]),
                                                    posture))
    travel = np.ptp(motion.poses[:, [0, 2]], axis=0).max() if motion.n_frames else 0.0
    tracker = TrackerConfig()
    empty = tracker.background_frames if subtracted else 0
    cfg = SceneConfig(fps=30.0, in_place=bool(travel > 2.0), variation=axes,  # as evaluate_motion plays it
                      empty_prefix=empty)
    crops, masks, joints = [], [], []
    with SyntheticScene(motion, seed=seed, config=cfg) as scene:
        height = scene.subject.spec.height
        model = learn_background(np.stack([scene.frame(i).image for i in range(empty)])) if subtracted else None
        start = int(np.random.default_rng(seed).integers(every))
        for i in range(empty + start, scene.n_frames, every):
            fr = scene.frame(i)
            sil = fr.truth.silhouette
            if not in_view(sil):
                continue  # too small, or cut by the image border
            seen = sil if model is None else subtract(model, fr.image, tracker.background)
            c = person_crop(fr.image, seen, size)
            if c is None:
                continue
            crops.append(c[0])
            masks.append(c[1])
            joints.append(camera_joints(fr.truth.joints, fr.truth.camera, height))
    if not crops:
        return Samples(np.zeros((0, size, size, 3), np.uint8), np.zeros((0, size, size), bool),
                       np.zeros((0, N_JOINTS, 3), np.float32))
    return Samples(np.asarray(crops), np.asarray(masks), np.asarray(joints, np.float32))


def _render_job(job: tuple[str, int, int, int, str, PostureParams | None, bool, bool]) -> str:
    path, seed, every, size, out, posture, vary, subtracted = job
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    s = render_take(path, seed, every, size, posture, vary_axes(seed) if vary else (), subtracted)
    tmp = out + ".partial.npz"
    np.savez_compressed(tmp, crops=s.crops, masks=s.masks, joints=s.joints)
    os.replace(tmp, out)
    return out


#: Take number of the first gesture script among the training takes (the recordings keep their
#: INDEX.tsv rows, below it): it seeds the script's people and names its cached views.
SCRIPT_ROW_BASE = 900


def training_takes(recordings: Sequence[tuple[int, str]], scripts: Sequence[str | Path] = ()
                   ) -> list[tuple[int, str]]:
    """The network's training takes: the recordings by INDEX.tsv row, then the gesture scripts
    numbered from :data:`SCRIPT_ROW_BASE` (the motions the database has and the recordings lack,
    such as the game's crouch and side-steps).

    Parameters
    ----------
    recordings : sequence of (int, str)
        ``(INDEX.tsv row, path)``; rows must be below :data:`SCRIPT_ROW_BASE`.
    scripts : sequence of str or Path
        Gesture script files.

    Returns
    -------
    list of (int, str)
    """
    if any(row >= SCRIPT_ROW_BASE for row, _ in recordings):
        raise ValueError(f"recording rows must be below {SCRIPT_ROW_BASE} (the gesture scripts' numbers)")
    if len(scripts) > _MAX_SCRIPTS:  # the numbers must stay below the next pass's seed base
        raise ValueError(f"at most {_MAX_SCRIPTS} gesture scripts, got {len(scripts)}")
    return [*recordings, *((SCRIPT_ROW_BASE + k, str(p)) for k, p in enumerate(scripts))]


#: Seed bases are 1000 apart: the scripts' numbers stay below the next base.
_MAX_SCRIPTS = 1000 - SCRIPT_ROW_BASE


def _cache_name(row: int, path: str) -> str:
    """A recording's cached views are named by its INDEX.tsv row; a gesture script's by its file
    name, its number (which chose the person: it depends on which scripts are used) and a digest of
    its full path (two folders may hold scripts of the same name)."""
    if row < SCRIPT_ROW_BASE:
        return f"{row:03d}.npz"
    p = Path(path).resolve()
    return f"script_{p.stem}_{row}_{zlib.crc32(str(p).encode()):08x}.npz"


def render_samples(entries: Sequence[tuple[int, str]], passes: Sequence[tuple[int, int]], size: int,
                   cache: Path, jobs: int = 1, progress: Callable[[int, int], None] | None = None,
                   load: bool = True, posture: PostureParams | None = None, vary: bool = False,
                   subtracted: bool = False) -> Samples:
    """Samples of every take and pass, rendered in ``jobs`` processes and cached.

    Parameters
    ----------
    entries : sequence of (int, str)
        ``(take number, path)`` of the training takes (:func:`training_takes`).
    passes : sequence of (int, int)
        ``(seed_base, every)``.
    size : int
    cache : Path
        Folder of the per-take files (``<seed_base>_<every>_<size>/<row>.npz``, a script's
        ``script_<name>_<number>_<path digest>.npz``).
    jobs : int
    progress : callable(done, total), optional
    load : bool
        False: only render what the cache lacks and return no samples (an empty ``Samples``).
    posture : PostureParams, optional
        Render the poses varied (:func:`render_take`); cached in folders named with the parameters
        (``<seed_base>_<every>_<size>_posture<version>_s<share>t<trunk>k<knee>``).
    vary : bool
        Render each take in a randomised scene (:func:`vary_axes`); cached in folders whose names end
        in ``_vary<version>``.
    subtracted : bool
        The tracker's silhouettes (:func:`render_take`); cached in folders whose names end in
        ``_sub<version>``.

    Returns
    -------
    Samples
    """
    todo: list[tuple[str, int, int, int, str, PostureParams | None, bool, bool]] = []
    files: list[tuple[int, Path]] = []
    tag = ("" if posture is None else
           f"_posture{POSTURE_VERSION}_s{posture.share:g}t{posture.trunk_deg:g}k{posture.knee_deg:g}")
    tag += f"_vary{VARY_VERSION}" if vary else ""
    tag += f"_sub{MASK_VERSION}" if subtracted else ""
    for base, every in passes:
        folder = cache / f"{base}_{every}_{size}{tag}"
        folder.mkdir(parents=True, exist_ok=True)
        for row, path in entries:
            f = folder / _cache_name(row, path)
            files.append((row, f))
            if not f.is_file():
                todo.append((str(path), base + row, every, size, str(f), posture, vary, subtracted))
    done = len(files) - len(todo)
    if progress is not None:
        progress(done, len(files))
    if todo:
        if jobs > 1:
            with ProcessPoolExecutor(jobs, mp_context=get_context("spawn")) as pool:
                for _ in pool.map(_render_job, todo):
                    done += 1
                    if progress is not None:
                        progress(done, len(files))
        else:
            for job in todo:
                _render_job(job)
                done += 1
                if progress is not None:
                    progress(done, len(files))
    if not load:
        return Samples(np.zeros((0, size, size, 3), np.uint8), np.zeros((0, size, size), bool),
                       np.zeros((0, N_JOINTS, 3), np.float32))
    crops, masks, joints, takes = [], [], [], []
    for row, f in files:
        try:
            with np.load(f) as z:
                c, m, j = z["crops"], z["masks"], z["joints"]
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as e:
            raise RuntimeError(f"cached training samples {f} are unreadable ({e}); delete the file and retry") from None
        crops.append(c)
        masks.append(m)
        joints.append(j)
        takes.append(np.full(len(c), row, np.int64))
    return Samples(np.concatenate(crops), np.concatenate(masks), np.concatenate(joints).astype(np.float32),
                   np.concatenate(takes))


def config_samples(entries: Sequence[tuple[int, str]], config: TrainConfig, cache: Path, jobs: int = 1
                   ) -> Samples:
    """A network's training samples: its passes, its posture passes and its randomised-scene passes
    (:func:`render_samples`, rendered where the cache lacks them).

    Parameters
    ----------
    entries : sequence of (int, str)
        :func:`training_takes`.
    config : TrainConfig
    cache : Path
    jobs : int

    Returns
    -------
    Samples
    """
    sub = config.masks == "subtracted"
    parts = [render_samples(entries, config.passes, config.size, cache, jobs, subtracted=sub)]
    if config.posture_passes:
        parts.append(render_samples(entries, config.posture_passes, config.size, cache, jobs,
                                    posture=config.posture, subtracted=sub))
    if config.vary_passes:
        parts.append(render_samples(entries, config.vary_passes, config.size, cache, jobs, vary=True,
                                    subtracted=sub))
    if len(parts) == 1:
        return parts[0]
    return Samples(np.concatenate([p.crops for p in parts]), np.concatenate([p.masks for p in parts]),
                   np.concatenate([p.joints for p in parts]), np.concatenate([p.take for p in parts]))


def _torch() -> Any:
    try:
        import torch
    except ImportError:
        raise RuntimeError("training the appearance network needs PyTorch, the 'train' extra: "
                           "pip install -e '.[train]' (the CPU build is enough; the tracker itself does "
                           "not need it)") from None
    return torch


def _model(torch: Any, size: int, width: int) -> Any:
    nn = torch.nn

    def block(i: int, o: int, stride: int = 1) -> Any:
        return nn.Sequential(nn.Conv2d(i, o, 3, stride, 1, bias=False), nn.BatchNorm2d(o), nn.ReLU(inplace=True))

    w = width
    return nn.Sequential(
        block(4, w, 2), block(w, 2 * w), nn.MaxPool2d(2),
        block(2 * w, 4 * w), nn.MaxPool2d(2),
        block(4 * w, 8 * w), nn.MaxPool2d(2),
        block(8 * w, 8 * w),
        nn.Flatten(), nn.Linear(8 * w * (size // 16) ** 2, 256), nn.ReLU(inplace=True),
        nn.Linear(256, 2 * N_JOINTS * 3))


def export_layers(model: Any) -> tuple[Layer, ...]:
    """The trained model's layers for :func:`tracker_service.cues.appearance.forward`: each convolution's
    batch norm folded into its weights and bias, the pools and ReLUs as flags."""
    torch = _torch()
    nn = torch.nn
    mods = list(model)
    layers = []
    i = 0
    with torch.no_grad():
        while i < len(mods):
            m = mods[i]
            nxt = mods[i + 1] if i + 1 < len(mods) else None
            if isinstance(m, nn.Sequential):
                conv, bn = m[0], m[1]
                k = bn.weight / torch.sqrt(bn.running_var + bn.eps)
                w = (conv.weight * k[:, None, None, None]).numpy().astype(np.float32)
                b = (bn.bias - bn.running_mean * k).numpy().astype(np.float32)
                pool = isinstance(nxt, nn.MaxPool2d)
                layers.append(Layer("conv", w, b, int(conv.stride[0]), pool, True))
                i += 2 if pool else 1
            elif isinstance(m, nn.Linear):
                relu = isinstance(nxt, nn.ReLU)
                layers.append(Layer("dense", m.weight.numpy().astype(np.float32), m.bias.numpy().astype(np.float32),
                                    1, False, relu))
                i += 2 if relu else 1
            else:
                i += 1
    return tuple(layers)


def _batch_input(torch: Any, crops: NDArray[np.uint8], masks: NDArray[np.bool_],
                 rng: np.random.Generator | None) -> Any:
    """The network's input for a batch (``net_input`` of each, with augmentation when ``rng``)."""
    x = crops.astype(np.float32) * np.float32(1.0 / 255.0)
    m = masks.astype(np.float32)
    if rng is not None:
        n = len(x)
        gain = rng.uniform(0.7, 1.3, (n, 1, 1, 1)) * rng.uniform(0.9, 1.1, (n, 1, 1, 3))
        x = np.clip(x * gain.astype(np.float32) + rng.uniform(-0.1, 0.1, (n, 1, 1, 1)).astype(np.float32), 0.0, 1.0)
        kernel = np.ones((3, 3), np.uint8)
        for i, r in enumerate(rng.integers(-1, 2, n)):
            if r:
                m[i] = (cv2.dilate if r > 0 else cv2.erode)(m[i], kernel)
    x = (x - np.float32(0.5)) * m[..., None]
    return torch.from_numpy(np.concatenate([x, m[..., None]], axis=-1)).permute(0, 3, 1, 2).contiguous()


def _mirror(crops: NDArray[np.uint8], masks: NDArray[np.bool_], joints: NDArray[np.float32], flip: NDArray[np.bool_]
            ) -> tuple[NDArray[np.uint8], NDArray[np.bool_], NDArray[np.float32]]:
    """Left-right mirrored samples where ``flip``: the image flipped, left and right joints swapped, x negated."""
    jm = joints[:, np.asarray(MIRROR_JOINTS)]
    jm[..., 0] *= -1.0
    return (np.where(flip[:, None, None, None], crops[:, :, ::-1], crops),
            np.where(flip[:, None, None], masks[:, :, ::-1], masks),
            np.where(flip[:, None, None], jm, joints))


def train_network(samples: Samples, config: TrainConfig, threads: int | None = None,
                  progress: Callable[[int, int, dict[str, float]], None] | None = None) -> AppearanceNet:
    """Train the network on ``samples`` (validation: the takes ``config.validation_every`` selects).

    Parameters
    ----------
    samples : Samples
    config : TrainConfig
    threads : int, optional
        PyTorch's intra-op threads (default: its own choice).
    progress : callable(epoch, epochs, figures), optional

    Returns
    -------
    AppearanceNet
        ``meta`` holds the configuration, the sample counts and the validation error per
        coordinate (RMS, in units of the person's height).
    """
    torch = _torch()
    if threads:
        torch.set_num_threads(threads)
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    if len(samples) == 0:
        raise ValueError("no training samples")
    if samples.crops.shape[1:3] != (config.size, config.size):
        raise ValueError(f"samples are {samples.crops.shape[1:3]} crops, the network takes {config.size}")
    takes = np.unique(samples.take) if len(samples.take) else np.zeros(0, np.int64)
    recorded = takes[takes < SCRIPT_ROW_BASE]  # validated on recordings only: the scripts are few and short
    val_takes = (recorded[:: config.validation_every] if len(recorded) >= 2 * config.validation_every
                 else takes[:0])
    val = np.isin(samples.take, val_takes) if len(samples.take) else np.zeros(len(samples), bool)
    tr = np.flatnonzero(~val)
    va = np.flatnonzero(val)
    model = _model(torch, config.size, config.width)
    opt = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    per_epoch = max(len(tr) // config.batch, 1)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=config.lr, total_steps=config.epochs * per_epoch)
    nj = N_JOINTS * 3
    figures: dict[str, float] = {}
    t0 = time.perf_counter()
    for epoch in range(config.epochs):
        model.train()
        order = rng.permutation(tr)
        total = 0.0
        for b in range(per_epoch):
            idx = np.sort(order[b * config.batch: (b + 1) * config.batch])
            c, m, j = _mirror(samples.crops[idx], samples.masks[idx], samples.joints[idx], rng.random(len(idx)) < 0.5)
            y = torch.from_numpy(np.ascontiguousarray(j.reshape(len(idx), -1)))
            out = model(_batch_input(torch, c, m, rng))
            mu, log_var = out[:, :nj], out[:, nj:].clamp(-12.0, 4.0)
            sq = (y - mu) ** 2
            loss = (0.5 * (log_var + sq / log_var.exp())).mean() + 0.5 * config.mse_weight * sq.mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach())
        figures = {"loss": total / per_epoch, "seconds": time.perf_counter() - t0}
        if len(va):
            figures |= _validate(torch, model, samples, va)
        if progress is not None:
            progress(epoch + 1, config.epochs, figures)
    model.eval()
    meta = {"config": asdict(config), "samples": len(tr), "validation_samples": len(va),
            "validation_takes": [int(t) for t in val_takes], "takes": len(takes)}
    meta |= {k: float(v) for k, v in figures.items()}
    return AppearanceNet(size=config.size, layers=export_layers(model), meta=meta)


def _validate(torch: Any, model: Any, samples: Samples, idx: NDArray[np.int64]) -> dict[str, float]:
    """RMS error per coordinate of the validation samples (units of the person's height)."""
    model.eval()
    err = np.zeros(3)
    with torch.no_grad():
        for s in range(0, len(idx), 256):
            b = idx[s: s + 256]
            out = model(_batch_input(torch, samples.crops[b], samples.masks[b], None)).numpy()
            d = out[:, : N_JOINTS * 3].reshape(len(b), N_JOINTS, 3) - samples.joints[b]
            err += (d[:, 1:] ** 2).sum(axis=(0, 1))  # the pelvis is 0 by definition
    rms = np.sqrt(err / (len(idx) * (N_JOINTS - 1)))
    model.train()
    return {"val_rms_x": float(rms[0]), "val_rms_y": float(rms[1]), "val_rms_z": float(rms[2])}
