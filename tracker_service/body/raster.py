"""Fast binary silhouettes, part labels and run-length contours of capsule bodies.

A tapered capsule (convex hull of two spheres) projects to the convex hull of the two spheres'
images. Each sphere image is taken as a circle of radius ``f R L / (z sqrt(L^2 - R^2))`` (the
ellipse's minor semi-axis: exact on the optical axis; the radial elongation ``1 / cos(theta)``
off-axis is ignored), so a capsule becomes the hull of two circles. Every image row meets the hull
in one interval -- from the two circles and the two outer tangent segments -- which the numba
scanline kernels of :mod:`tracker_service.body._kernels` fill directly (no polygons, only the rows the
capsule covers). The same intervals, merged per row, are the run-length contours ``(y, x_start,
x_end)`` of the template database (Okada & Stenger Fig. 5, eq. 12) -- :func:`silhouette_runs`.

Part labels (eq. 14's occlusion reasoning) z-buffer each capsule with the depth of its front
surface (centre depth and radius interpolated along the projected axis, lowered by the sphere /
cylinder profile across it); ``visible_counts[p]`` is how many pixels part ``p`` owns.

Every function has a plain numpy / OpenCV reference (``*_reference``: ``cv2.fillConvexPoly`` on a
polygon of the two-circle hull, drawn capsule by capsule) that the tests hold it to.

Inputs are joints ``(J, 3)`` (capsule ends taken from :data:`~protocol.skeleton.CAPSULES`) or
capsule end points ``(C, 2, 3)``, world metres, with radii ``(C, 2)`` metres.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from protocol.skeleton import CAPSULE_JOINTS, CAPSULE_PART, N_CAPSULES, N_JOINTS, N_PARTS
from tracker_service.body._kernels import (
    capsule_runs_batch_kernel,
    capsule_runs_kernel,
    fill_capsules_batch_kernel,
    fill_capsules_kernel,
    label_capsules_kernel,
)
from tracker_service.camera import Camera

__all__ = [
    "project_capsules",
    "render_labels",
    "render_labels_reference",
    "render_labels_with_areas",
    "render_silhouette",
    "render_silhouette_cv2",
    "render_silhouette_reference",
    "render_silhouettes",
    "silhouette_runs",
    "silhouette_runs_batch",
]


def _endpoints(points: ArrayLike) -> NDArray[np.float64]:
    p = np.asarray(points, dtype=np.float64)
    if p.shape[-2:] == (N_JOINTS, 3):
        return p[..., CAPSULE_JOINTS, :]
    if p.shape[-3:] == (N_CAPSULES, 2, 3) or (p.ndim >= 3 and p.shape[-2:] == (2, 3)):
        return p
    raise ValueError(f"expected joints (..., {N_JOINTS}, 3) or capsule end points (..., C, 2, 3), got {p.shape}")


def project_capsules(points: ArrayLike, radii: ArrayLike, camera: Camera) -> NDArray[np.float64]:
    """Image-space description of capsules, the kernels' input.

    Parameters
    ----------
    points : (..., J, 3) or (..., C, 2, 3) float
        Joints or capsule end points, world metres.
    radii : (C, 2) or (..., C, 2) float
        Capsule radii at both ends, metres.
    camera : Camera

    Returns
    -------
    (..., C, 10) float64, C-contiguous
        ``(x1, y1, r1, x2, y2, r2, z1, z2, R1, R2)``: circle centres and radii in pixels, the depth
        of both end centres and the radii in metres. Capsules that reach behind the near plane get
        ``r1 = r2 = -1`` (skipped by the kernels).
    """
    ends = _endpoints(points)
    rad = np.broadcast_to(np.asarray(radii, dtype=np.float64), ends.shape[:-1])
    uv, z = camera.project_with_depth(ends)
    cam_pts = camera.to_camera(ends)
    dist = np.linalg.norm(cam_pts, axis=-1)
    ok = z - rad > camera.znear
    safe_z = np.where(ok, z, 1.0)
    safe_l = np.where(ok, dist, 2.0)
    rho = camera.focal * rad * safe_l / (safe_z * np.sqrt(np.maximum(safe_l**2 - rad**2, 1e-12)))
    if camera.has_distortion:
        x = cam_pts[..., 0] / safe_z
        y = cam_pts[..., 1] / safe_z
        rho = rho * camera.radial_scale(x * x + y * y)
    cap_ok = np.all(ok, axis=-1, keepdims=True)
    rho = np.where(cap_ok, rho, -1.0)
    uv = np.where(cap_ok[..., None], uv, 0.0)
    out = np.empty((*ends.shape[:-2], 10))
    out[..., 0:2] = uv[..., 0, :]
    out[..., 2] = rho[..., 0]
    out[..., 3:5] = uv[..., 1, :]
    out[..., 5] = rho[..., 1]
    out[..., 6:8] = z
    out[..., 8:10] = rad
    return np.ascontiguousarray(out)


def render_silhouette(points: ArrayLike, radii: ArrayLike, camera: Camera,
                      out: NDArray[np.bool_] | None = None) -> NDArray[np.bool_]:
    """Binary silhouette of one capsule body.

    Parameters
    ----------
    points : (J, 3) or (C, 2, 3) float
        Joints or capsule end points, world metres.
    radii : (C, 2) float
        Capsule radii, metres.
    camera : Camera
    out : (H, W) bool, optional
        Buffer to reuse (cleared here).

    Returns
    -------
    (H, W) bool
        True where a pixel centre lies inside the projection of some capsule.
    """
    caps = project_capsules(points, radii, camera)
    mask = np.zeros((camera.height, camera.width), bool) if out is None else out
    if out is not None:
        mask[:] = False
    fill_capsules_kernel(caps, mask)
    return mask


def render_silhouettes(points: ArrayLike, radii: ArrayLike, camera: Camera) -> NDArray[np.bool_]:
    """Binary silhouettes of a batch of poses (one numba call).

    Parameters
    ----------
    points : (N, J, 3) or (N, C, 2, 3) float
    radii : (C, 2) or (N, C, 2) float
    camera : Camera

    Returns
    -------
    (N, H, W) bool
    """
    caps = project_capsules(points, radii, camera)
    if caps.ndim != 3:
        raise ValueError("render_silhouettes expects a batch; use render_silhouette for one pose")
    masks = np.empty((caps.shape[0], camera.height, camera.width), bool)
    fill_capsules_batch_kernel(caps, masks)
    return masks


def _labels(points: ArrayLike, radii: ArrayLike, camera: Camera,
            parts: ArrayLike | None) -> tuple[NDArray[np.int8], NDArray[np.int64], NDArray[np.int64]]:
    caps = project_capsules(points, radii, camera)
    if caps.ndim != 2:
        raise ValueError("expected a single pose")
    part = np.ascontiguousarray(CAPSULE_PART if parts is None else np.asarray(parts), dtype=np.int64)
    if part.shape != (caps.shape[0],) or part.min() < 0 or part.max() >= 16:
        raise ValueError("parts must give a part index in [0, 16) for every capsule")
    h, w = camera.height, camera.width
    labels = np.full((h, w), -1, np.int8)
    zbuf = np.full((h, w), np.inf, np.float32)
    cover = np.zeros((h, w), np.uint16)
    n_parts = max(N_PARTS, int(part.max()) + 1)
    visible = np.zeros(n_parts, np.int64)
    areas = np.zeros(n_parts, np.int64)
    label_capsules_kernel(caps, part, labels, zbuf, cover, visible, areas)
    return labels, visible, areas


def render_labels(points: ArrayLike, radii: ArrayLike, camera: Camera,
                  parts: ArrayLike | None = None) -> tuple[NDArray[np.int8], NDArray[np.int64]]:
    """Per-pixel body part in front, and each part's visible pixel count.

    Parameters
    ----------
    points : (J, 3) or (C, 2, 3) float
    radii : (C, 2) float
    camera : Camera
    parts : (C,) int, optional
        Part of each capsule (default :data:`~protocol.skeleton.CAPSULE_PART`).

    Returns
    -------
    labels : (H, W) int8
        Index into :data:`~protocol.skeleton.PARTS` of the nearest part, -1 for background.
    visible_counts : (N_PARTS,) int64
        Pixels labelled with each part (0: the part is occluded or off-screen, eq. 14).
    """
    labels, visible, _ = _labels(points, radii, camera, parts)
    return labels, visible


def render_labels_with_areas(points: ArrayLike, radii: ArrayLike, camera: Camera, parts: ArrayLike | None = None
                             ) -> tuple[NDArray[np.int8], NDArray[np.int64], NDArray[np.int64]]:
    """:func:`render_labels` plus ``areas (N_PARTS,) int64``: pixels each part would cover if nothing
    occluded it, so ``visible_counts / areas`` is the visible fraction of each part."""
    return _labels(points, radii, camera, parts)


def silhouette_runs(points: ArrayLike, radii: ArrayLike, camera: Camera) -> NDArray[np.int16]:
    """Run-length form of :func:`render_silhouette`, computed without rasterising.

    Returns
    -------
    (R, 3) int16
        ``(y, x_start, x_end)`` with ``x_end`` exclusive, sorted by row then column -- the format of
        :func:`tracker_service.silhouette.distance.mask_to_runs`.
    """
    caps = project_capsules(points, radii, camera)
    buf = np.empty((camera.height * caps.shape[0] + 1, 3), np.int16)
    n = capsule_runs_kernel(caps, camera.height, camera.width, buf)
    return buf[:n].copy()


def silhouette_runs_batch(points: ArrayLike, radii: ArrayLike,
                          camera: Camera) -> tuple[NDArray[np.int16], NDArray[np.int64]]:
    """Runs of a batch of poses packed like :class:`tracker_service.silhouette.distance.RunSet`.

    Parameters
    ----------
    points : (N, J, 3) or (N, C, 2, 3) float
    radii : (C, 2) or (N, C, 2) float
    camera : Camera

    Returns
    -------
    data : (R, 3) int16
        All runs; pose ``i`` owns ``data[ptr[i]:ptr[i + 1]]``.
    ptr : (N + 1,) int64
    """
    caps = project_capsules(points, radii, camera)
    if caps.ndim != 3:
        raise ValueError("silhouette_runs_batch expects a batch")
    data, ptr = capsule_runs_batch_kernel(caps, camera.height, camera.width)
    return data, ptr


# ---------------------------------------------------------------------------------- references
def _capsule_mask_dense(cap: NDArray[np.float64], jj: NDArray[np.float64],
                        ii: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Dense test of every pixel centre against the hull of the two circles of ``cap``: inside
    either circle, or inside the quadrilateral of the four outer tangent points."""
    (x1, y1, r1, x2, y2, r2) = cap[:6]
    inside = ((jj - x1) ** 2 + (ii - y1) ** 2 <= r1 * r1) | ((jj - x2) ** 2 + (ii - y2) ** 2 <= r2 * r2)
    d = np.hypot(x2 - x1, y2 - y1)
    if d <= abs(r1 - r2):
        return inside
    u = np.array([x2 - x1, y2 - y1]) / d
    nrm = np.array([-u[1], u[0]])
    s = (r1 - r2) / d
    c = np.sqrt(max(1.0 - s * s, 0.0))
    m1, m2 = s * u + c * nrm, s * u - c * nrm  # outward normals of the two tangent lines
    quad = np.array([[x1, y1] + r1 * m1, [x2, y2] + r2 * m1, [x2, y2] + r2 * m2, [x1, y1] + r1 * m2])
    sides = []
    for k in range(4):
        a, b = quad[k], quad[(k + 1) % 4]
        sides.append((b[0] - a[0]) * (ii - a[1]) - (b[1] - a[1]) * (jj - a[0]))
    st = np.stack(sides)
    return inside | np.all(st >= 0, axis=0) | np.all(st <= 0, axis=0)


def render_silhouette_reference(points: ArrayLike, radii: ArrayLike, camera: Camera) -> NDArray[np.bool_]:
    """Reference for :func:`render_silhouette`: a dense numpy inside-test of every pixel centre
    against every capsule's two-circle hull."""
    caps = project_capsules(points, radii, camera)
    ii, jj = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    out = np.zeros((camera.height, camera.width), bool)
    for cap in caps.reshape(-1, 10):
        if cap[2] > 0 and cap[5] > 0:
            out |= _capsule_mask_dense(cap, jj, ii)
    return out


def render_silhouette_cv2(points: ArrayLike, radii: ArrayLike, camera: Camera, segments: int = 16) -> NDArray[np.bool_]:
    """The OpenCV way, for comparison: each capsule as a polygon (two half-circles of ``segments``
    points, radii shrunk by half a pixel to offset ``cv2.fillConvexPoly``'s inclusive edge rule)
    drawn separately -- one ``cv2.fillPoly`` over all of them would XOR the overlaps."""
    caps = project_capsules(points, radii, camera)
    img = np.zeros((camera.height, camera.width), np.uint8)
    th = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(th), np.sin(th)], axis=1)
    for cap in caps.reshape(-1, 10):
        if not (cap[2] > 0 and cap[5] > 0):
            continue
        pts = np.concatenate([cap[0:2] + max(cap[2] - 0.5, 0.1) * ring, cap[3:5] + max(cap[5] - 0.5, 0.1) * ring])
        hull = cv2.convexHull(np.round(pts * 16).astype(np.int32))
        cv2.fillConvexPoly(img, hull, 1, lineType=cv2.LINE_8, shift=4)
    return img.astype(bool)


def render_labels_reference(points: ArrayLike, radii: ArrayLike, camera: Camera,
                            parts: ArrayLike | None = None) -> tuple[NDArray[np.int8], NDArray[np.int64]]:
    """Reference for :func:`render_labels`: dense capsule masks and a dense numpy z-buffer (float32
    depths, like the kernel)."""
    caps = project_capsules(points, radii, camera)
    part = CAPSULE_PART if parts is None else np.asarray(parts, dtype=np.int64)
    h, w = camera.height, camera.width
    ii, jj = np.mgrid[0:h, 0:w].astype(np.float64)
    labels = np.full((h, w), -1, np.int8)
    zbuf = np.full((h, w), np.inf)
    for c, cap in enumerate(caps):
        if not (cap[2] > 0 and cap[5] > 0):
            continue
        m = _capsule_mask_dense(cap, jj, ii)
        ax, ay = cap[3] - cap[0], cap[4] - cap[1]
        l2 = ax * ax + ay * ay
        t = ((jj - cap[0]) * ax + (ii - cap[1]) * ay) / l2 if l2 > 1e-12 else np.zeros_like(jj)
        t = np.clip(t, 0.0, 1.0)
        q2 = (jj - cap[0] - t * ax) ** 2 + (ii - cap[1] - t * ay) ** 2
        rho = cap[2] + t * (cap[5] - cap[2])
        prof = np.sqrt(np.maximum(1.0 - q2 / rho**2, 0.0))
        z = (cap[6] + t * (cap[7] - cap[6]) - (cap[8] + t * (cap[9] - cap[8])) * prof).astype(np.float32)
        win = m & (z < zbuf)
        zbuf[win] = z[win]
        labels[win] = part[c]
    counts = np.bincount(labels[labels >= 0].astype(np.int64), minlength=N_PARTS)
    return labels, counts
