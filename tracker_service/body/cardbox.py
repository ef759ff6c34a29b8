"""The 3D cardbox body model of the cardbox paper (``upper_body_cardbox_drs.txt``, §III-A, Fig. 1-2).

"Our 3D cardbox model represents each body part with two or three 2D patches that are
perpendicular to each other": every body part of :data:`protocol.skeleton.CAPSULES` becomes two
planar, tapered quadrilaterals through its bone axis (three for the abdomen and the thorax: the
torso's third patch lies across the axis, through its middle). A patch spans the bone from joint
``a`` to joint ``b``; its width at each end is a *size parameter* (the paper's Fig. 2), initialised
from the capsule diameters and refined by :func:`fit_sizes` (the paper's Algorithm 1). Fewer
primitives to project than a volumetric model: each patch is four projected corners.

The patches' directions come from the frame of the joint that carries the part (the deepest common
ancestor of its two ends): of that frame's three axes the one most aligned with the bone is
dropped, the other two (made perpendicular to the bone) span the two patches. An arm held out
sideways is then drawn by a vertical and a horizontal patch, a leg by a frontal and a sagittal one.

The silhouette is the union of the projected patches, rasterised at pixel centres (integer pixel
coordinates, as :class:`~tracker_service.camera.Camera` projects). :func:`cardbox_sums` is the numba
kernel that adds the observation's per-pixel image over that union for a batch of poses;
:func:`cardbox_masks_reference` renders the same masks densely in numpy (the test holds them equal).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numba import njit
from numpy.typing import NDArray

from protocol.kinematics import fk_global
from protocol.skeleton import CAPSULE_INDEX, CAPSULE_JOINTS, CAPSULE_OWNER, N_CAPSULES, Body
from tracker_service.camera import Camera

__all__ = [
    "SIZE_GROUPS",
    "CardboxModel",
    "cardbox_masks_reference",
    "cardbox_quads",
    "cardbox_sums",
    "cardbox_sums_reference",
]


#: The joint whose frame carries each part.
PART_OWNER = CAPSULE_OWNER
#: Parts drawn with a third patch across the axis (the paper's torso).
THREE_PATCHES = (CAPSULE_INDEX["abdomen"], CAPSULE_INDEX["thorax"])
N_PATCHES = 2 * N_CAPSULES + len(THREE_PATCHES)

#: The size parameters estimated together (Algorithm 1's three steps, eq. 6; the legs' step is this
#: project's, the paper tracks the upper body): part indices and which widths (0 the first patch's,
#: 1 the second's).
SIZE_GROUPS: dict[str, tuple[tuple[int, ...], tuple[int, ...]]] = {
    "torso and head, front view": (tuple(CAPSULE_INDEX[n] for n in ("pelvis", "abdomen", "thorax", "shoulders",
                                                                     "neck", "skull")), (0,)),
    "torso and head, side view": (tuple(CAPSULE_INDEX[n] for n in ("pelvis", "abdomen", "thorax", "shoulders",
                                                                    "neck", "skull")), (1,)),
    "arms": (tuple(CAPSULE_INDEX[n] for n in ("l_upper_arm", "l_forearm", "l_hand", "r_upper_arm", "r_forearm",
                                              "r_hand")), (0, 1)),
    "legs": (tuple(CAPSULE_INDEX[n] for n in ("l_thigh", "l_shin", "l_foot", "r_thigh", "r_shin", "r_foot")), (0, 1)),
}


@dataclass(frozen=True)
class CardboxModel:
    """A body's cardbox: its skeleton and the widths of its patches.

    Attributes
    ----------
    body : Body
        Bone offsets (the posture parameters act on them).
    widths : (C, 2, 2) float64
        Full width (metres) of part ``c``'s patch ``k`` (0: the first of the frame's two axes, 1:
        the second) at its ends ``a`` and ``b``. The torso's third patch is ``widths[c, 0]`` wide
        and ``widths[c, 1]`` deep.
    """

    body: Body
    widths: NDArray[np.float64]

    def __post_init__(self) -> None:
        w = np.asarray(self.widths, np.float64)
        if w.shape != (N_CAPSULES, 2, 2) or not (np.isfinite(w).all() and (w > 0).all()):
            raise ValueError(f"widths must be ({N_CAPSULES}, 2, 2) finite and > 0")
        object.__setattr__(self, "widths", w)

    @staticmethod
    def from_body(body: Body) -> CardboxModel:
        """The initial guess: both patches as wide as the capsule's diameter at each end."""
        r = np.asarray(body.capsule_radii, np.float64)
        return CardboxModel(body, np.repeat(2.0 * r[:, None, :], 2, axis=1))

    def with_widths(self, widths: NDArray[np.float64]) -> CardboxModel:
        return replace(self, widths=np.asarray(widths, np.float64))


def cardbox_quads(model: CardboxModel, poses: NDArray[np.float64], camera: Camera) -> NDArray[np.float64]:
    """Every patch of every pose projected: ``(N, Q, 4, 2)`` float64 image corners, in order round
    the quadrilateral; a patch with a corner behind the camera is NaN (not drawn).

    Parameters
    ----------
    model : CardboxModel
    poses : (N, P) float64
    camera : Camera
        At the resolution the quads are wanted.
    """
    p = np.atleast_2d(np.asarray(poses, np.float64))
    joints, rot = fk_global(p, model.body)
    if p.shape[0] == 1 and joints.ndim == 2:
        joints, rot = joints[None], rot[None]
    a = joints[:, CAPSULE_JOINTS[:, 0]]  # (N, C, 3)
    b = joints[:, CAPSULE_JOINTS[:, 1]]
    frame = rot[:, PART_OWNER]  # (N, C, 3, 3): columns are the owner's axes
    u = b - a
    u /= np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
    along = np.abs(np.einsum("ncik,nci->nck", frame, u))  # |axis_k . u|
    drop = np.argmax(along, axis=-1)  # (N, C)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[drop]  # (N, C, 2)
    axes = np.take_along_axis(np.swapaxes(frame, -1, -2), keep[..., None], axis=2)  # (N, C, 2, 3)
    axes = axes - np.einsum("nckd,ncd->nck", axes, u)[..., None] * u[:, :, None, :]
    axes /= np.maximum(np.linalg.norm(axes, axis=-1, keepdims=True), 1e-12)
    half = 0.5 * model.widths  # (C, 2 patches, 2 ends)
    corners = np.stack([a[:, :, None] + half[None, :, :, 0, None] * axes,
                        b[:, :, None] + half[None, :, :, 1, None] * axes,
                        b[:, :, None] - half[None, :, :, 1, None] * axes,
                        a[:, :, None] - half[None, :, :, 0, None] * axes], axis=3)  # (N, C, 2, 4, 3)
    quads = [corners.reshape(len(p), 2 * N_CAPSULES, 4, 3)]
    for c in THREE_PATCHES:  # across the axis, through the middle: widths[c, 0] by widths[c, 1]
        m = 0.5 * (a[:, c] + b[:, c])
        e0, e1 = axes[:, c, 0], axes[:, c, 1]
        w0, w1 = 0.25 * model.widths[c, 0].sum(), 0.25 * model.widths[c, 1].sum()
        quads.append(np.stack([m + w0 * e0 + w1 * e1, m - w0 * e0 + w1 * e1, m - w0 * e0 - w1 * e1,
                               m + w0 * e0 - w1 * e1], axis=1)[:, None])
    world = np.concatenate(quads, axis=1)  # (N, Q, 4, 3)
    img, depth = camera.project_with_depth(world)
    img = np.array(img, np.float64)
    img[(depth <= 1e-6).any(axis=-1)] = np.nan
    return img


def _edge(px: float, py: float, x0: float, y0: float, x1: float, y1: float) -> float:
    return (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0)


_edge_jit = njit(cache=True, inline="always")(_edge)


@njit(cache=True, inline="always")
def _inside(c: NDArray[np.float64], sgn: float, x: int, y: int) -> bool:
    for e in range(4):
        f = (e + 1) % 4
        if sgn * _edge_jit(float(x), float(y), c[e, 0], c[e, 1], c[f, 0], c[f, 1]) < 0.0:
            return False
    return True


@njit(cache=True, nogil=True)
def cardbox_sums(quads: NDArray[np.float64], a: NDArray[np.float64], mark: NDArray[np.bool_]) -> NDArray[np.float64]:
    """``sum(a)`` over each pose's silhouette, the union of its quadrilaterals (numba).

    Parameters
    ----------
    quads : (N, Q, 4, 2) float64
        :func:`cardbox_quads`.
    a : (H, W) float64
        The observation's per-pixel image (its XOR / cwXOR / nwXOR weights).
    mark : (H, W) bool
        A work buffer, all False (left so).

    Returns
    -------
    (N,) float64
    """
    h, w = a.shape
    n, q = quads.shape[0], quads.shape[1]
    out = np.zeros(n)
    ys = np.empty(h * w, np.int64)
    xs = np.empty(h * w, np.int64)
    for i in range(n):
        count = 0
        for k in range(q):
            c = quads[i, k]
            area = 0.0
            xmin = ymin = np.inf
            xmax = ymax = -np.inf
            for e in range(4):
                f = (e + 1) % 4
                area += c[e, 0] * c[f, 1] - c[f, 0] * c[e, 1]
                xmin, xmax = min(xmin, c[e, 0]), max(xmax, c[e, 0])
                ymin, ymax = min(ymin, c[e, 1]), max(ymax, c[e, 1])
            if not np.isfinite(area) or area == 0.0:  # behind the camera (NaN), or edge-on
                continue
            sgn = 1.0 if area > 0 else -1.0
            x0 = max(int(np.ceil(xmin)), 0)
            x1 = min(int(np.floor(xmax)), w - 1)
            y0 = max(int(np.ceil(ymin)), 0)
            y1 = min(int(np.floor(ymax)), h - 1)
            if x0 > x1 or y0 > y1:
                continue
            for y in range(y0, y1 + 1):
                # the row's span from the four edges' lines, then its ends settled by the exact
                # per-pixel test (the reference's), so rounding in the division changes nothing
                lo, hi = float(x0), float(x1)
                for e in range(4):
                    f = (e + 1) % 4
                    ka = -sgn * (c[f, 1] - c[e, 1])  # sgn * edge(x, y) = ka * x + kb
                    kb = sgn * ((c[f, 0] - c[e, 0]) * (y - c[e, 1]) + (c[f, 1] - c[e, 1]) * c[e, 0])
                    if ka > 0.0:
                        lo = max(lo, -kb / ka)
                    elif ka < 0.0:
                        hi = min(hi, -kb / ka)
                    elif kb < 0.0:
                        hi = lo - 1.0
                if hi < lo - 1.0:
                    continue
                xa = max(x0, int(np.floor(lo)) - 1)
                xb = min(x1, int(np.ceil(hi)) + 1)
                while xa <= xb and not _inside(c, sgn, xa, y):
                    xa += 1
                while xb >= xa and not _inside(c, sgn, xb, y):
                    xb -= 1
                for x in range(xa, xb + 1):
                    if not mark[y, x]:
                        mark[y, x] = True
                        ys[count] = y
                        xs[count] = x
                        count += 1
        s = 0.0
        for j in range(count):
            s += a[ys[j], xs[j]]
            mark[ys[j], xs[j]] = False
        out[i] = s
    return out


def cardbox_masks_reference(quads: NDArray[np.float64], shape: tuple[int, int]) -> NDArray[np.bool_]:
    """Dense numpy reference of :func:`cardbox_sums`' silhouettes: ``(N, H, W)`` bool, a pixel centre
    inside a quadrilateral when it is on the inner side of (or on) all four edges."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    out = np.zeros((quads.shape[0], h, w), bool)
    for i in range(quads.shape[0]):
        for c in quads[i]:
            if not np.isfinite(c).all():
                continue
            area = sum(c[e, 0] * c[(e + 1) % 4, 1] - c[(e + 1) % 4, 0] * c[e, 1] for e in range(4))
            if area == 0.0:
                continue
            sgn = 1.0 if area > 0 else -1.0
            inside = np.ones((h, w), bool)
            for e in range(4):
                f = (e + 1) % 4
                inside &= sgn * _edge(xx, yy, c[e, 0], c[e, 1], c[f, 0], c[f, 1]) >= 0.0
            out[i] |= inside
    return out


def cardbox_sums_reference(quads: NDArray[np.float64], a: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`cardbox_sums` from :func:`cardbox_masks_reference`."""
    return np.array([float(a[m].sum()) for m in cardbox_masks_reference(quads, a.shape)])
