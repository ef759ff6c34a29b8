"""Numba kernels of :mod:`tracker_service.body`. Each has a plain-numpy reference beside the code
that uses it, and a test holds the two equal."""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray

# ------------------------------------------------------------------------------------------------
# Capsule silhouette rasteriser (tracker_service.body.raster). A projected tapered capsule is
# the convex hull of two circles; each image row meets it in one interval, found from the two
# circles and the two outer tangent segments. ``caps`` rows hold
# ``(x1, y1, r1, x2, y2, r2, z1, z2, R1, R2)``: circle centres and radii in pixels (OpenCV
# pixel-centre convention), the depth of each end's centre and its radius (metres); ``r1 <= 0``
# marks a capsule to skip.
# ------------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def capsule_hull_kernel(cap: NDArray[np.float64], hull: NDArray[np.float64]) -> int:
    """Outer tangent points of one projected capsule.

    Parameters
    ----------
    cap : (10,) float64
        ``(x1, y1, r1, x2, y2, r2, z1, z2, R1, R2)``.
    hull : (8,) float64
        Written with the tangent segments ``(ax1, ay1, ax2, ay2, bx1, by1, bx2, by2)``.

    Returns
    -------
    int
        0: skip the capsule; 1: circle 1 alone covers it; 2: circle 2 alone; 3: two circles and
        two tangent segments.
    """
    x1, y1, r1, x2, y2, r2 = cap[0], cap[1], cap[2], cap[3], cap[4], cap[5]
    if not (r1 > 0.0 and r2 > 0.0):
        return 0
    dx = x2 - x1
    dy = y2 - y1
    d = np.sqrt(dx * dx + dy * dy)
    if d <= abs(r1 - r2) + 1e-9:
        return 1 if r1 >= r2 else 2
    ux = dx / d
    uy = dy / d
    s = (r1 - r2) / d
    c = np.sqrt(max(1.0 - s * s, 0.0))
    for k in range(2):
        sign = 1.0 if k == 0 else -1.0
        mx = s * ux - sign * c * uy
        my = s * uy + sign * c * ux
        hull[4 * k + 0] = x1 + r1 * mx
        hull[4 * k + 1] = y1 + r1 * my
        hull[4 * k + 2] = x2 + r2 * mx
        hull[4 * k + 3] = y2 + r2 * my
    return 3


@njit(cache=True, nogil=True)
def capsule_span_kernel(cap: NDArray[np.float64], hull: NDArray[np.float64], kind: int,
                        y: float) -> tuple[float, float]:
    """Interval ``[lo, hi]`` (pixels) of a projected capsule on image row ``y``; ``lo > hi`` if empty."""
    lo = np.inf
    hi = -np.inf
    for k in range(2):
        if (kind == 1 and k == 1) or (kind == 2 and k == 0):
            continue
        cx = cap[3 * k]
        cy = cap[3 * k + 1]
        r = cap[3 * k + 2]
        ddy = y - cy
        if abs(ddy) <= r:
            w = np.sqrt(r * r - ddy * ddy)
            lo = min(lo, cx - w)
            hi = max(hi, cx + w)
    if kind == 3:
        for k in range(2):
            ax = hull[4 * k]
            ay = hull[4 * k + 1]
            bx = hull[4 * k + 2]
            by = hull[4 * k + 3]
            if (ay - y) * (by - y) <= 0.0 and ay != by:
                x = ax + (y - ay) * (bx - ax) / (by - ay)
                lo = min(lo, x)
                hi = max(hi, x)
    return lo, hi


@njit(cache=True, nogil=True)
def _capsule_rows(cap: NDArray[np.float64], height: int) -> tuple[int, int]:
    top = min(cap[1] - cap[2], cap[4] - cap[5])
    bot = max(cap[1] + cap[2], cap[4] + cap[5])
    return max(int(np.ceil(top)), 0), min(int(np.floor(bot)), height - 1)


@njit(cache=True, nogil=True)
def fill_capsules_kernel(caps: NDArray[np.float64], mask: NDArray[np.bool_]) -> None:
    """OR-fill projected capsules into a binary mask (pixel centres inside the hull).

    Parameters
    ----------
    caps : (C, 10) float64
        Projected capsules (see the section comment).
    mask : (H, W) bool
        Filled in place (not cleared first).
    """
    h, w = mask.shape
    hull = np.empty(8)
    for c in range(caps.shape[0]):
        kind = capsule_hull_kernel(caps[c], hull)
        if kind == 0:
            continue
        r0, r1 = _capsule_rows(caps[c], h)
        for i in range(r0, r1 + 1):
            lo, hi = capsule_span_kernel(caps[c], hull, kind, float(i))
            j0 = max(int(np.ceil(lo)), 0)
            j1 = min(int(np.floor(hi)), w - 1)
            for j in range(j0, j1 + 1):
                mask[i, j] = True


@njit(cache=True, nogil=True)
def fill_capsules_batch_kernel(caps: NDArray[np.float64], masks: NDArray[np.bool_]) -> None:
    """:func:`fill_capsules_kernel` over a batch: ``caps (N, C, 10)``, ``masks (N, H, W)`` (cleared here)."""
    for n in range(caps.shape[0]):
        masks[n, :, :] = False
        fill_capsules_kernel(caps[n], masks[n])


@njit(cache=True, nogil=True)
def label_capsules_kernel(caps: NDArray[np.float64], parts: NDArray[np.int64],
                          labels: NDArray[np.int8], zbuf: NDArray[np.float32], cover: NDArray[np.uint16],
                          visible: NDArray[np.int64], areas: NDArray[np.int64]) -> None:
    """Z-buffered part labels of projected capsules.

    The depth of a capsule at a pixel is that of its front surface: with ``t`` the pixel's clamped
    position along the projected axis, ``q`` its image distance from the axis point at ``t`` and
    ``rho``, ``R``, ``z`` the projected radius, radius and centre depth interpolated at ``t``,
    ``z - R sqrt(1 - (q / rho)^2)``.

    Parameters
    ----------
    caps : (C, 10) float64
        Projected capsules.
    parts : (C,) int64
        Part index (< 16) of each capsule.
    labels : (H, W) int8
        Written: -1 background, else the part in front. Must be filled with -1 on entry.
    zbuf : (H, W) float32
        Depth buffer, ``inf`` on entry.
    cover : (H, W) uint16
        Bit ``p`` set where part ``p`` covers the pixel; zeros on entry.
    visible, areas : (N_PARTS,) int64
        Written: pixels where each part is in front / covers the pixel regardless of occlusion.
    """
    h, w = labels.shape
    hull = np.empty(8)
    top, bot, left, right = h, -1, w, -1
    for c in range(caps.shape[0]):
        kind = capsule_hull_kernel(caps[c], hull)
        if kind == 0:
            continue
        x1, y1, x2, y2 = caps[c, 0], caps[c, 1], caps[c, 3], caps[c, 4]
        z1, z2 = caps[c, 6], caps[c, 7]
        rr1, rr2 = caps[c, 2], caps[c, 5]
        w1, w2 = caps[c, 8], caps[c, 9]
        ax = x2 - x1
        ay = y2 - y1
        l2 = ax * ax + ay * ay
        inv = 1.0 / l2 if l2 > 1e-12 else 0.0
        bit = np.uint16(1 << parts[c])
        lab = np.int8(parts[c])
        r0, r1 = _capsule_rows(caps[c], h)
        for i in range(r0, r1 + 1):
            lo, hi = capsule_span_kernel(caps[c], hull, kind, float(i))
            j0 = max(int(np.ceil(lo)), 0)
            j1 = min(int(np.floor(hi)), w - 1)
            if j1 < j0:
                continue
            top = min(top, i)
            bot = max(bot, i)
            left = min(left, j0)
            right = max(right, j1)
            for j in range(j0, j1 + 1):
                t = ((j - x1) * ax + (i - y1) * ay) * inv
                t = min(max(t, 0.0), 1.0)
                qx = j - (x1 + t * ax)
                qy = i - (y1 + t * ay)
                rho = rr1 + t * (rr2 - rr1)
                f = max(1.0 - (qx * qx + qy * qy) / (rho * rho), 0.0)
                z = np.float32(z1 + t * (z2 - z1) - (w1 + t * (w2 - w1)) * np.sqrt(f))
                cover[i, j] |= bit
                if z < zbuf[i, j]:
                    zbuf[i, j] = z
                    labels[i, j] = lab
    visible[:] = 0
    areas[:] = 0
    for i in range(top, bot + 1):
        for j in range(left, right + 1):
            lab = labels[i, j]
            if lab >= 0:
                visible[lab] += 1
            b = int(cover[i, j])
            p = 0
            while b:
                if b & 1:
                    areas[p] += 1
                b >>= 1
                p += 1


@njit(cache=True, nogil=True)
def capsule_runs_kernel(caps: NDArray[np.float64], height: int, width: int,
                        out: NDArray[np.int16]) -> int:
    """Horizontal runs of the union of projected capsules, without rasterising.

    Parameters
    ----------
    caps : (C, 10) float64
    height, width : int
        Image size (runs are clipped to it).
    out : (M, 3) int16
        Written with ``(y, x_start, x_end)`` runs (``x_end`` exclusive), sorted by ``y`` then ``x``;
        ``M >= height * C`` always suffices.

    Returns
    -------
    int
        Number of runs written.
    """
    n_caps = caps.shape[0]
    hulls = np.empty((n_caps, 8))
    kinds = np.empty(n_caps, np.int64)
    rows = np.empty((n_caps, 2), np.int64)
    top, bot = height, -1
    for c in range(n_caps):
        kinds[c] = capsule_hull_kernel(caps[c], hulls[c])
        r0, r1 = _capsule_rows(caps[c], height)
        rows[c, 0] = r0
        rows[c, 1] = r1
        if kinds[c] > 0 and r1 >= r0:
            top = min(top, r0)
            bot = max(bot, r1)
    lo_buf = np.empty(n_caps, np.int64)
    hi_buf = np.empty(n_caps, np.int64)
    n_out = 0
    for i in range(top, bot + 1):
        m = 0
        for c in range(n_caps):
            if kinds[c] == 0 or i < rows[c, 0] or i > rows[c, 1]:
                continue
            lo, hi = capsule_span_kernel(caps[c], hulls[c], kinds[c], float(i))
            j0 = max(int(np.ceil(lo)), 0)
            j1 = min(int(np.floor(hi)), width - 1)
            if j1 < j0:
                continue
            k = m  # insertion sort by start
            while k > 0 and lo_buf[k - 1] > j0:
                lo_buf[k] = lo_buf[k - 1]
                hi_buf[k] = hi_buf[k - 1]
                k -= 1
            lo_buf[k] = j0
            hi_buf[k] = j1
            m += 1
        k = 0
        while k < m:
            s = lo_buf[k]
            e = hi_buf[k]
            k += 1
            while k < m and lo_buf[k] <= e + 1:
                e = max(e, hi_buf[k])
                k += 1
            out[n_out, 0] = i
            out[n_out, 1] = s
            out[n_out, 2] = e + 1
            n_out += 1
    return n_out


@njit(cache=True, nogil=True)
def capsule_runs_batch_kernel(caps: NDArray[np.float64], height: int,
                              width: int) -> tuple[NDArray[np.int16], NDArray[np.int64]]:
    """:func:`capsule_runs_kernel` over ``caps (N, C, 10)``: packed ``data (R, 3) int16`` and ``ptr (N + 1,)``."""
    n = caps.shape[0]
    scratch = np.empty((height * caps.shape[1] + 1, 3), np.int16)
    data = np.empty((max(n * 64, 64), 3), np.int16)
    ptr = np.zeros(n + 1, np.int64)
    total = 0
    for p in range(n):
        k = capsule_runs_kernel(caps[p], height, width, scratch)
        if total + k > data.shape[0]:
            grown = np.empty((max(2 * data.shape[0], total + k), 3), np.int16)
            grown[:total] = data[:total]
            data = grown
        data[total:total + k] = scratch[:k]
        total += k
        ptr[p + 1] = total
    return data[:total].copy(), ptr

# ---- end of the capsule silhouette rasteriser ----


# ------------------------------------------------------------------------------------------------
# Forward kinematics (tracker_service.body.kinematics; reference: protocol.kinematics.fk_global).
# ------------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def fk_global_kernel(poses: NDArray[np.float64], offsets: NDArray[np.float64], parents: NDArray[np.int64],
                     slots: NDArray[np.int64], pos: NDArray[np.float64], rot: NDArray[np.float64]) -> None:
    """Joint positions and global orientations of a batch of poses, written into ``pos`` and ``rot``.

    Rodrigues' formula per rotation slot (Taylor terms below 1e-8 rad, as the reference), then
    the parent chain in joint order.

    Parameters
    ----------
    poses : (N, P) float64
    offsets : (J, 3) float64
    parents : (J,) int64
        Parent of each joint (-1 for the root, which is joint 0).
    slots : (J,) int64
        Rotation slot of each joint (-1: an end joint, which keeps its parent's frame).
    pos : (N, J, 3) float64
    rot : (N, J, 3, 3) float64
    """
    n_joints = offsets.shape[0]
    local = np.empty((3, 3))
    for i in range(poses.shape[0]):
        for j in range(n_joints):
            s = slots[j]
            if s >= 0:
                x = poses[i, 3 + 3 * s]
                y = poses[i, 4 + 3 * s]
                z = poses[i, 5 + 3 * s]
                theta = np.sqrt(x * x + y * y + z * z)
                if theta < 1e-8:
                    a = 1.0 - theta * theta / 6.0
                    b = 0.5 - theta * theta / 24.0
                else:
                    a = np.sin(theta) / theta
                    b = (1.0 - np.cos(theta)) / (theta * theta)
                local[0, 0] = 1.0 - b * (y * y + z * z)
                local[0, 1] = -a * z + b * x * y
                local[0, 2] = a * y + b * x * z
                local[1, 0] = a * z + b * x * y
                local[1, 1] = 1.0 - b * (x * x + z * z)
                local[1, 2] = -a * x + b * y * z
                local[2, 0] = -a * y + b * x * z
                local[2, 1] = a * x + b * y * z
                local[2, 2] = 1.0 - b * (x * x + y * y)
            par = parents[j]
            if par < 0:
                for r in range(3):
                    pos[i, j, r] = poses[i, r]
                    for c in range(3):
                        rot[i, j, r, c] = local[r, c]
                continue
            for r in range(3):
                pos[i, j, r] = (pos[i, par, r] + rot[i, par, r, 0] * offsets[j, 0] + rot[i, par, r, 1] * offsets[j, 1]
                                + rot[i, par, r, 2] * offsets[j, 2])
                for c in range(3):
                    if s >= 0:
                        rot[i, j, r, c] = (rot[i, par, r, 0] * local[0, c] + rot[i, par, r, 1] * local[1, c]
                                           + rot[i, par, r, 2] * local[2, c])
                    else:
                        rot[i, j, r, c] = rot[i, par, r, c]
