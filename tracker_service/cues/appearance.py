"""The appearance cue: where the joints are in depth, read from the person's colour image.

The silhouette does not say which leg is forward, how far a hand is in front of the chest or how
much the torso leans towards the camera, and on such frames the filter's support holds the right
leaf but ranks a depth-ambiguous one above it (docs/TRACKER.md, "where the remaining error is").
Inside the silhouette the image does carry it: shading, which limb hides which, the stripes of a
shirt cut by an arm in front of it. This module reads that with a small convolutional network
trained on rendered views of the training recordings (:mod:`tracker_service.build.appearance_train`;
the Kinect body-part classifier was trained on synthetic renders of motion capture the same way):

1. :func:`person_crop` cuts a square around the observed silhouette and scales it to the
   network's input (``S x S``): colour times the mask, and the mask itself, so that the room
   behind the person plays no part;
2. :func:`predict_joints` runs the network (OpenCV's DNN engine, :mod:`tracker_service.cues.appearance_engine`;
   :func:`forward` is its numpy reference, im2col + BLAS; the convolutions' batch norms are folded
   into their weights when the network is exported) and returns, for every joint, its
   position relative to the pelvis in the camera's axes divided by the person's height, with a
   variance per coordinate (the network was trained with a Gaussian negative log likelihood);
3. :func:`joints_cost` scores template leaves: ``0.5 sum_j sum_c (mu_jc - x_jc)^2 / var_jc`` over
   the chosen coordinates, where ``x`` are the leaf's joints in the same frame
   (:func:`camera_joints` of the leaves' joints, computed once when the database is loaded).

The cost joins the filter's leaf likelihood with a weight (``FilterParams.appearance_weight``);
measured in docs/TRACKER.md ("An appearance cue").
"""

from __future__ import annotations

import json
import zipfile
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import numpy as np
from numpy.typing import NDArray

from protocol.skeleton import MIRROR_JOINTS, N_JOINTS
from tracker_service.camera import Camera
from tracker_service.cues._kernels import proposal_cost_kernel
from tracker_service.cues.appearance_engine import AppearanceEngine
from tracker_service.cues.level_frame import level_to_camera, rotate_reading, upright_angle
from tracker_service.paths import out_dir

__all__ = ["APPEARANCE_FORMAT", "APPEARANCE_VERSION", "AppearanceError", "AppearanceNet", "HeadingWindow",
           "Layer", "camera_joints", "default_appearance_path", "ensemble", "forward", "in_view", "joints_cost",
           "load_appearance", "net_input", "person_crop", "pool_readings", "predict_joints", "propose_leaves",
           "propose_leaves_in_window", "save_appearance", "shipped_appearance_path"]

APPEARANCE_FORMAT = "mocap-appearance-net"
#: Bump on any change of the input, the output or the layers' meaning.
APPEARANCE_VERSION = 1
#: The crop's side is this many times the silhouette box's longer side.
CROP_MARGIN = 1.15
_REBUILD = "rebuild it with: mocap-tracker train-appearance --out {path}"
#: Log variances are clipped to this range (as in training).
LOG_VAR_RANGE = (-12.0, 4.0)


#: The camera placements the network reads well: the range measured. It was trained at the default
#: camera's (1.2 m high, level, no roll; distance and lens are free: the crop normalises the
#: person's size) and reads the body in a level camera's axes; :mod:`tracker_service.cues.level_frame`
#: turns its crop upright and its reading into a tilted or rolled camera's axes. Within these it
#: was measured 1.6-3.5 cm better than the silhouettes alone (docs/BENCHMARKS.md, "Camera
#: placements"); beyond them the cue is turned off.
FIT_HEIGHT_M = (0.6, 1.8)
FIT_TILT_DEG = 20.0
FIT_ROLL_DEG = 10.0


def appearance_unfit(camera: Camera) -> str | None:
    """Why the network should not read frames of ``camera`` (None: a placement it reads well,
    :data:`FIT_HEIGHT_M`, :data:`FIT_TILT_DEG`, :data:`FIT_ROLL_DEG`)."""
    # rounded (to a millimetre, a hundredth of a degree): a camera placed at a limit is within it
    h, tilt, roll = round(camera.height_m, 3), round(camera.tilt_deg, 2), round(camera.roll_deg, 2)
    if not FIT_HEIGHT_M[0] <= h <= FIT_HEIGHT_M[1]:
        return f"the camera is {h:.2f} m high (measured: {FIT_HEIGHT_M[0]}-{FIT_HEIGHT_M[1]} m)"
    if abs(tilt) > FIT_TILT_DEG:
        return f"the camera is tilted {tilt:+.1f} deg (measured: within {FIT_TILT_DEG:g} deg)"
    if abs(roll) > FIT_ROLL_DEG:
        return f"the camera is rolled {roll:+.1f} deg (measured: within {FIT_ROLL_DEG:g} deg)"
    return None


class AppearanceError(RuntimeError):
    """A network file that cannot be used; the message says why and how to rebuild it."""


def shipped_appearance_path() -> Path | None:
    """The newest network shipped in the package (``tracker_service/cues/models/appearance-vN.npz``,
    the largest N; its provenance in the ``.json`` beside it), or None."""
    files = sorted((Path(__file__).resolve().parent / "models").glob("appearance-v*.npz"),
                   key=lambda q: int(q.stem.rsplit("-v", 1)[-1]) if q.stem.rsplit("-v", 1)[-1].isdigit() else -1)
    return files[-1] if files else None


def default_appearance_path() -> Path:
    """``out/appearance/net.npz``: where ``train-appearance`` writes (``run``/``eval`` use it when no
    network ships in the package, or with ``--appearance PATH``)."""
    return out_dir() / "appearance" / "net.npz"


@dataclass(frozen=True)
class Layer:
    """One layer of the network.

    Attributes
    ----------
    kind : {'conv', 'dense'}
    weight : float32 array
        ``conv``: (O, C, 3, 3) with the batch norm folded in; ``dense``: (O, I).
    bias : (O,) float32
    stride : int
        Convolution stride (``conv`` only; padding 1).
    pool : bool
        A 2 x 2 max pool after the ReLU (``conv`` only).
    relu : bool
    """

    kind: str
    weight: NDArray[np.float32]
    bias: NDArray[np.float32]
    stride: int = 1
    pool: bool = False
    relu: bool = True
    #: The weights as the matrix of one product: ``(9 C, O)`` rows in (dy, dx, c) order for a
    #: convolution, ``(I, O)`` for a dense layer (derived).
    matrix: NDArray[np.float32] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        w = np.asarray(self.weight, np.float32)
        m = w.transpose(2, 3, 1, 0).reshape(-1, w.shape[0]) if w.ndim == 4 else w.T
        object.__setattr__(self, "matrix", np.ascontiguousarray(m))


@dataclass(frozen=True)
class AppearanceNet:
    """The trained network and what it was trained for.

    Attributes
    ----------
    size : int
        Input side ``S`` (pixels).
    layers : tuple of Layer
        The (first) network.
    meta : dict
        Training information (takes, samples, epochs, validation error); for an ensemble
        ``meta["members"]`` holds each network's.
    members : tuple of tuple of Layer
        The ensemble's other networks (empty: one network).
    """

    size: int
    layers: tuple[Layer, ...]
    meta: dict[str, Any]
    #: Further networks of the same input and output, trained on other views with other initial
    #: weights: an ensemble whose readings :func:`predict_joints` pools.
    members: tuple[tuple[Layer, ...], ...] = ()

    @property
    def n_outputs(self) -> int:
        return int(self.layers[-1].weight.shape[0])

    @property
    def networks(self) -> tuple[tuple[Layer, ...], ...]:
        """Every network's layers, the first one's first."""
        return (self.layers, *self.members)

    @property
    def engine(self) -> AppearanceEngine:
        """The networks compiled for OpenCV's DNN engine (made on first use, kept with the network)."""
        eng = self.__dict__.get("_engine")
        if eng is None:
            eng = AppearanceEngine(self)
            object.__setattr__(self, "_engine", eng)
        return eng


def ensemble(nets: Sequence[AppearanceNet]) -> AppearanceNet:
    """One network file of several networks (their readings pooled by :func:`predict_joints`).

    Parameters
    ----------
    nets : sequence of AppearanceNet
        Same input size and outputs; their own members join too.

    Returns
    -------
    AppearanceNet
        ``meta["members"]`` lists each network's own ``meta``.
    """
    if not nets:
        raise ValueError("an ensemble needs at least one network")
    first = nets[0]
    for n in nets[1:]:
        if n.size != first.size or n.n_outputs != first.n_outputs:
            raise ValueError(f"networks of different inputs or outputs ({n.size}/{n.n_outputs} vs "
                             f"{first.size}/{first.n_outputs}) cannot be pooled")
    layers = [lay for n in nets for lay in n.networks]
    metas = [m for n in nets for m in (n.meta.get("members") or [n.meta])]
    return AppearanceNet(first.size, layers[0], {"members": metas}, tuple(layers[1:]))


def person_crop(frame: NDArray[np.uint8], mask: NDArray[np.bool_], size: int, camera: Camera | None = None
                ) -> tuple[NDArray[np.uint8], NDArray[np.bool_]] | None:
    """The person's square crop at the network's input size.

    Parameters
    ----------
    frame : (H, W, 3) uint8
        BGR camera frame.
    mask : (H, W) bool
        The silhouette.
    size : int
    camera : Camera, optional
        The camera of ``frame``: when it is tilted or rolled, the crop is turned so that the
        world's up at the silhouette's centre points up in it, as in every training view
        (:func:`tracker_service.cues.level_frame.upright_angle`); a level camera's crop is the
        plain one.

    Returns
    -------
    crop : (size, size, 3) uint8
    crop_mask : (size, size) bool
    None when the mask is empty.
    """
    rows = np.flatnonzero(mask.any(axis=1))
    if not len(rows):
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    angle = 0.0 if camera is None else upright_angle(camera, 0.5 * (x0 + x1), 0.5 * (y0 + y1))
    if angle == 0.0:
        side = CROP_MARGIN * max(y1 - y0, x1 - x0)
        k = size / side
        m = np.array([[k, 0.0, size / 2 - 0.5 * (x0 + x1) * k], [0.0, k, size / 2 - 0.5 * (y0 + y1) * k]])
    else:  # the silhouette's box in the turned image (cv2.getRotationMatrix2D's sense: counter-clockwise)
        c, s = np.cos(np.radians(angle)), np.sin(np.radians(angle))
        turn = np.array([[c, s], [-s, c]])
        v, u = np.nonzero(mask[y0:y1, x0:x1])
        q = np.stack([u + float(x0), v + float(y0)], axis=1) @ turn.T
        lo, hi = q.min(axis=0), q.max(axis=0) + 1.0
        k = size / (CROP_MARGIN * float(max(hi - lo)))
        m = np.hstack([k * turn, (size / 2 - k * 0.5 * (lo + hi))[:, None]])
    # (warpAffine samples bilinearly whatever the flag says: INTER_AREA exists only in resize. The
    # networks were trained on exactly this crop; changing it needs a retrained network.)
    crop = np.asarray(cv2.warpAffine(frame, m, (size, size), flags=cv2.INTER_AREA, borderMode=cv2.BORDER_REPLICATE),
                      np.uint8)
    cm = np.asarray(cv2.warpAffine(mask.astype(np.uint8) * 255, m, (size, size), flags=cv2.INTER_AREA) > 127)
    return crop, cm


def in_view(mask: NDArray[np.bool_], min_pixels: int = 200) -> bool:
    """Whether the network may read this silhouette: at least ``min_pixels`` pixels and not cut by
    the image border (the training views are chosen by the same test, so a cut person is an input
    the network has never seen).

    Parameters
    ----------
    mask : (H, W) bool
    min_pixels : int
    """
    return bool(mask.sum() >= min_pixels and not (mask[0].any() or mask[-1].any() or mask[:, 0].any()
                                                    or mask[:, -1].any()))


def net_input(crop: NDArray[np.uint8], crop_mask: NDArray[np.bool_]) -> NDArray[np.float32]:
    """The network's input: ``(colour / 255 - 0.5) * mask`` and the mask, ``(S, S, 4)`` float32."""
    m = crop_mask.astype(np.float32)[..., None]
    x = (crop.astype(np.float32) * np.float32(1.0 / 255.0) - np.float32(0.5)) * m
    return np.concatenate([x, m], axis=-1)


def _conv(x: NDArray[np.float32], layer: Layer) -> NDArray[np.float32]:
    """3 x 3 convolution, padding 1, of ``x`` (N, H, W, C): the nine shifted copies side by side
    (im2col) and one matrix product for the whole batch."""
    n, h, w, c = x.shape
    s = layer.stride
    ho, wo = (h - 1) // s + 1, (w - 1) // s + 1
    xp = np.zeros((n, h + 2, w + 2, c), np.float32)
    xp[:, 1:-1, 1:-1] = x
    cols = np.empty((n, ho, wo, 9 * c), np.float32)
    for k in range(9):
        dy, dx = divmod(k, 3)
        cols[..., k * c: (k + 1) * c] = xp[:, dy: dy + s * (ho - 1) + 1: s, dx: dx + s * (wo - 1) + 1: s]
    y = cols.reshape(n * ho * wo, 9 * c) @ layer.matrix
    y += layer.bias
    return y.reshape(n, ho, wo, -1)


def forward(net: AppearanceNet, x: NDArray[np.float32], member: int = 0) -> NDArray[np.float32]:
    """The network's raw output for one input or a batch.

    Parameters
    ----------
    net : AppearanceNet
    x : (S, S, 4) or (N, S, S, 4) float32
        :func:`net_input`.
    member : int
        Which of the ensemble's networks (0: ``net.layers``).

    Returns
    -------
    (n_outputs,) or (N, n_outputs) float32
    """
    h: NDArray[np.float32] = np.asarray(x, np.float32)
    single = h.ndim == 3
    if single:
        h = h[None]
    for layer in net.networks[member]:
        if layer.kind == "conv":
            h = _conv(h, layer)
            if layer.relu:
                np.maximum(h, 0.0, out=h)
            if layer.pool:
                n, a, b, c = h.shape
                h = h[:, : a // 2 * 2, : b // 2 * 2].reshape(n, a // 2, 2, b // 2, 2, c).max(axis=(2, 4))
        else:
            if h.ndim == 4:  # flatten in the training framework's (C, H, W) order
                h = np.ascontiguousarray(h.transpose(0, 3, 1, 2)).reshape(h.shape[0], -1)
            h = h @ layer.matrix + layer.bias
            if layer.relu:
                np.maximum(h, 0.0, out=h)
    return h[0] if single else h


def predict_joints(net: AppearanceNet, frame: NDArray[np.uint8], mask: NDArray[np.bool_], mirror: bool = False,
                   camera: Camera | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """The joints' positions relative to the pelvis, camera axes, in units of the person's height.

    Parameters
    ----------
    net : AppearanceNet
    frame : (H, W, 3) uint8
    mask : (H, W) bool
    mirror : bool
        Also read the crop flipped left-right (the network was trained on mirrored views too: left
        and right joints swapped, ``x`` negated) and return the mean of both readings, the variance
        widened by their disagreement (one view alone when the other's output is not finite).
        An ensemble (``net.members``) reads every view with every network and pools all readings
        the same way (:func:`pool_readings`).
    camera : Camera, optional
        The camera of ``frame``. The network reads the body in a level camera's axes: for a tilted
        or rolled camera the crop is turned upright (:func:`person_crop`) and the reading turned
        into the camera's axes (:func:`tracker_service.cues.level_frame.level_to_camera`); None,
        or a level camera: the reading as it is.

    Returns
    -------
    mu : (J, 3) float64
    var : (J, 3) float64
        The network's variance of each coordinate.
    None when the mask is empty or the network's output is not finite.
    """
    rotation = None if camera is None else level_to_camera(camera)  # None: a level camera, nothing to turn
    c = person_crop(frame, mask, net.size, None if rotation is None else camera)
    if c is None:
        return None
    x = net_input(*c)
    views = np.stack([x, x[:, ::-1]]) if mirror else x[None]  # one batch: both views
    idx = np.asarray(MIRROR_JOINTS)
    readings = []
    for out in net.engine.forward(views):
        readings.append(_read(out[0]))
        if mirror and (flipped := _read(out[1])) is not None:
            readings.append((flipped[0][idx] * np.array([-1.0, 1.0, 1.0]), flipped[1][idx]))
    pooled = pool_readings(readings)
    return pooled if pooled is None or rotation is None else rotate_reading(*pooled, rotation)


def pool_readings(readings: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]] | None]
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Several Gaussian readings of the same joints as one: the mean of the means, and the
    mixture's variance (the mean variance widened by the means' spread). Readings that are None
    (not finite) are left out; None when none is left.

    Parameters
    ----------
    readings : sequence of ((J, 3) float64, (J, 3) float64) or None

    Returns
    -------
    mu, var : (J, 3) float64, or None
    """
    ok = [r for r in readings if r is not None]
    if not ok:
        return None
    if len(ok) == 1:
        return ok[0]
    mus = np.stack([r[0] for r in ok])
    mu = mus.mean(axis=0)
    return mu, np.mean([r[1] for r in ok], axis=0) + np.square(mus - mu).mean(axis=0)


def _read(out: NDArray[np.float32]) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """The network's raw output as joints and variances; None when it is not finite."""
    o = out.astype(np.float64)
    if not np.isfinite(o).all():
        return None
    n = N_JOINTS * 3
    return o[:n].reshape(N_JOINTS, 3), np.exp(np.clip(o[n: 2 * n], *LOG_VAR_RANGE)).reshape(N_JOINTS, 3)


def camera_joints(joints: NDArray[np.floating[Any]], camera: Camera, height: float) -> NDArray[np.float32]:
    """Joints relative to the pelvis, in the camera's axes, over the person's height: what the
    network reads (its training targets) and what it scores the leaves by.

    Parameters
    ----------
    joints : (..., J, 3) float
        World joint positions (metres; joint 0 the pelvis), e.g. the leaves' forward kinematics.
    camera : Camera
    height : float
        The person's (or the body model's) height, metres.

    Returns
    -------
    (..., J, 3) float32
    """
    j = np.asarray(joints, np.float64)
    return np.asarray(((j - j[..., :1, :]) @ camera.pose[:3, :3]) / height, np.float32)


def joints_cost(mu: NDArray[np.float64], var: NDArray[np.float64], leaf_joints: NDArray[np.float32],
                coords: tuple[int, ...] = (0, 1, 2)) -> NDArray[np.float64]:
    """Negative log likelihood (up to a constant) of leaves' joints under the network's Gaussian.

    Parameters
    ----------
    mu, var : (J, 3) float64
        :func:`predict_joints`.
    leaf_joints : (n, J, 3) float32
        :func:`camera_joints` of the leaves to score.
    coords : tuple of int
        Coordinates that count (0 = x right, 1 = y up, 2 = z towards the camera).

    Returns
    -------
    (n,) float64
    """
    c = list(coords)
    d = leaf_joints[:, :, c].astype(np.float64) - mu[None, :, c]
    return 0.5 * np.einsum("njc,jc->n", d * d, 1.0 / var[:, c])


class HeadingWindow(NamedTuple):
    """Leaf headings the appearance cue may propose: within ``half_width`` of ``centre`` (radians,
    on the circle) and at most ``max_abs`` from facing the camera."""

    centre: float
    half_width: float
    max_abs: float = float(np.inf)

    def mask(self, heading: NDArray[np.floating[Any]]) -> NDArray[np.bool_]:
        """(NL,) bool of the leaves inside the window (the reference of the kernel's test)."""
        h = np.asarray(heading, np.float64)
        d = np.remainder(h - self.centre + np.pi, 2 * np.pi) - np.pi
        return np.asarray((np.abs(d) <= self.half_width) & (np.abs(h) <= self.max_abs), bool)


def _best_k(c: NDArray[np.float64], k: int) -> NDArray[np.int64]:
    """Indices of the ``k`` smallest finite entries of ``c``, smallest first."""
    k = min(k, int(np.isfinite(c).sum()))
    if k <= 0:
        return np.zeros(0, np.int64)
    idx = np.argpartition(c, k - 1)[:k]
    return np.asarray(idx[np.argsort(c[idx], kind="stable")], np.int64)


def propose_leaves(mu: NDArray[np.float64], var: NDArray[np.float64], leaf_joints: NDArray[np.float32], k: int,
                   allowed: NDArray[np.bool_] | None = None) -> NDArray[np.int64]:
    """The ``k`` leaves the network's Gaussian likes best (ELMO's retrieval of hypotheses from the
    observation, over the whole database). Plain-numpy reference of :func:`propose_leaves_in_window`.

    The cost of :func:`joints_cost` over every coordinate, expanded as
    ``0.5 (sum x^2 / var - 2 sum x mu / var) + const``.

    Parameters
    ----------
    mu, var : (J, 3) float64
    leaf_joints : (NL, J, 3) float32
        :func:`camera_joints` of every leaf.
    k : int
    allowed : (NL,) bool, optional
        Leaves that may be proposed (e.g. headings near the current one).

    An infinite variance leaves that coordinate out.

    Returns
    -------
    (min(k, n_allowed),) int64
        Leaf indices, best first.
    """
    x = leaf_joints.reshape(len(leaf_joints), -1).astype(np.float64)
    inv = (1.0 / var).ravel()
    c = (x * x) @ inv - 2.0 * (x @ (mu.ravel() * inv))
    if allowed is not None:
        c = np.where(allowed, c, np.inf)
    return _best_k(c, k)


def propose_leaves_in_window(mu: NDArray[np.float64], var: NDArray[np.float64], leaf_joints: NDArray[np.float32],
                             k: int, heading: NDArray[np.float32], window: HeadingWindow) -> NDArray[np.int64]:
    """:func:`propose_leaves` among the leaves whose heading is in ``window``, by one numba pass
    over the joints (``_kernels.proposal_cost_kernel``; with the heading window, 2.8 -> 1.5 ms a frame
    for 47,105 leaves in the pipeline).

    Parameters
    ----------
    mu, var : (J, 3) float64
    leaf_joints : (NL, J, 3) float32
    k : int
    heading : (NL,) float32
        The leaves' headings (``FilterDB.leaf_heading``).
    window : HeadingWindow

    Returns
    -------
    (min(k, n_allowed),) int64
        Leaf indices, best first.
    """
    c = proposal_cost_kernel(leaf_joints.reshape(len(leaf_joints), -1), np.ascontiguousarray((1.0 / var).ravel()),
                             np.ascontiguousarray(mu.ravel(), np.float64), np.asarray(heading, np.float32),
                             float(window.centre), float(window.half_width), float(window.max_abs))
    return _best_k(c, k)


def save_appearance(path: str | Path, net: AppearanceNet, half: bool = False) -> Path:
    """Write a network file (``.npz``: the layers' arrays and a JSON header with a CRC-32 of each).

    ``half``: the weights stored as float16 (half the size: the file shipped in the package); they
    are read back as float32."""
    p = Path(path)
    dtype = np.float16 if half else np.float32
    p.parent.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, NDArray[Any]] = {}

    def specs(layers: tuple[Layer, ...], prefix: str) -> list[dict[str, Any]]:
        spec = []
        for i, layer in enumerate(layers):
            w, b = f"{prefix}w{i}", f"{prefix}b{i}"
            arrays[w] = np.ascontiguousarray(layer.weight, dtype)
            arrays[b] = np.ascontiguousarray(layer.bias, dtype)
            spec.append({"kind": layer.kind, "stride": layer.stride, "pool": layer.pool, "relu": layer.relu,
                         "crc_w": zlib.crc32(arrays[w].tobytes()), "crc_b": zlib.crc32(arrays[b].tobytes())})
        return spec

    header = {"format": APPEARANCE_FORMAT, "version": APPEARANCE_VERSION, "size": net.size,
              "layers": specs(net.layers, ""), "meta": net.meta}
    if net.members:  # (a reader of one network ignores them and reads the first)
        header["members"] = [specs(m, f"m{k + 1}_") for k, m in enumerate(net.members)]
    tmp = p.with_name(p.name + ".partial.npz")
    arrays["header"] = np.array(json.dumps(header, default=float))
    np.savez(tmp, **arrays)  # type: ignore[arg-type]
    tmp.replace(p)
    return p


def load_appearance(path: str | Path) -> AppearanceNet:
    """Read and check a network file.

    Raises
    ------
    AppearanceError
        Missing, truncated, corrupt, stale or inconsistent file (with a rebuild hint).
    """
    p = Path(path)
    hint = _REBUILD.format(path=p)
    if not p.is_file():
        raise AppearanceError(f"no appearance network at {p}; {hint}")
    try:
        with np.load(p, allow_pickle=False) as z:
            header = json.loads(str(z["header"]))
            arrays = {k: np.asarray(z[k]) for k in z.files if k != "header"}
    except (OSError, ValueError, KeyError, TypeError, AttributeError, EOFError, zlib.error, zipfile.BadZipFile) as e:
        # (TypeError / AttributeError: a .npy array, not an archive, under this name)
        raise AppearanceError(f"cannot read {p} (truncated or corrupt: {type(e).__name__}: {e}); {hint}") from None
    if not isinstance(header, dict) or header.get("format") != APPEARANCE_FORMAT:
        raise AppearanceError(f"{p} is not an appearance network; {hint}")
    if header.get("version") != APPEARANCE_VERSION:
        raise AppearanceError(f"stale appearance network at {p} (format v{header.get('version')}, this program "
                              f"needs v{APPEARANCE_VERSION}); {hint}")
    def read_layers(spec: list[dict[str, Any]], prefix: str, what: str) -> tuple[Layer, ...]:
        layers = []
        for i, s in enumerate(spec):
            w, b = arrays[f"{prefix}w{i}"], arrays[f"{prefix}b{i}"]
            if zlib.crc32(np.ascontiguousarray(w).tobytes()) != s["crc_w"] or \
                    zlib.crc32(np.ascontiguousarray(b).tobytes()) != s["crc_b"]:
                raise AppearanceError(f"{p} is corrupt (checksum mismatch in {what}layer {i}); {hint}")
            if w.dtype == np.float16 and b.dtype == np.float16:  # a half-precision file: computed in float32
                w, b = w.astype(np.float32), b.astype(np.float32)
            if s["kind"] not in ("conv", "dense") or w.dtype != np.float32 or b.shape != (w.shape[0],) or \
                    (s["kind"] == "conv" and w.shape[2:] != (3, 3)) or (s["kind"] == "dense" and w.ndim != 2) or \
                    not 1 <= int(s["stride"]) <= 4:
                raise AppearanceError(f"{p}: {what}layer {i} has inconsistent shapes {w.shape} / {b.shape} or "
                                      f"stride {s['stride']}; {hint}")
            if not (np.isfinite(w).all() and np.isfinite(b).all()):
                raise AppearanceError(f"{p}: {what}layer {i} holds non-finite weights (a diverged training); {hint}")
            layers.append(Layer(s["kind"], w, b, int(s["stride"]), bool(s["pool"]), bool(s["relu"])))
        if not layers:
            raise AppearanceError(f"{p}: {what}has no layers; {hint}")
        return tuple(layers)

    try:
        first = read_layers(header["layers"], "", "")
        members = tuple(read_layers(spec, f"m{k + 1}_", f"member {k + 1}'s ")
                        for k, spec in enumerate(header.get("members", [])))
        if not 8 <= int(header["size"]) <= 512:
            raise AppearanceError(f"{p}: input size {header['size']} is out of range; {hint}")
        net = AppearanceNet(size=int(header["size"]), layers=first, meta=dict(header.get("meta", {})),
                            members=members)
        probes = [forward(net, np.zeros((net.size, net.size, 4), np.float32), k) for k in range(len(net.networks))]
    except AppearanceError:
        raise
    except (KeyError, TypeError, ValueError, IndexError, ArithmeticError) as e:
        raise AppearanceError(f"inconsistent appearance network at {p} ({type(e).__name__}: {e}); {hint}") from None
    for k, probe in enumerate(probes):
        what = f" (member {k})" if k else ""
        if probe.shape != (2 * N_JOINTS * 3,):
            raise AppearanceError(f"{p}{what} outputs {probe.shape[0]} values, expected {2 * N_JOINTS * 3}; {hint}")
        if not np.isfinite(probe).all():
            raise AppearanceError(f"{p}{what} gives non-finite outputs; {hint}")
    return net
