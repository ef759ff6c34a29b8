"""Numba kernel of the avatar's articulated pose interpolation.

The plain numpy reference is :func:`cloth_client.avatar.capsules.interpolate_poses_reference`
(rotation vectors through matrices and :func:`protocol.rotations.quat_slerp`); a test holds both equal.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from cloth_client._jit import inline_kernel as _inline
from cloth_client._jit import jit_kernel as _jit

__all__ = ["interpolate_poses"]

F64 = NDArray[np.float64]


@_inline
def _rotvec_quat(p: F64, i: int) -> tuple[float, float, float, float]:  # pragma: no cover
    """Unit quaternion ``(w, x, y, z)``, ``w >= 0``, of the rotation vector ``p[i:i + 3]``."""
    rx, ry, rz = p[i], p[i + 1], p[i + 2]
    theta = math.sqrt(rx * rx + ry * ry + rz * rz)
    if theta < 1e-8:
        w, x, y, z = 1.0, 0.5 * rx, 0.5 * ry, 0.5 * rz
        n = math.sqrt(w * w + x * x + y * y + z * z)
        return w / n, x / n, y / n, z / n
    c, f = math.cos(0.5 * theta), math.sin(0.5 * theta) / theta
    if c < 0.0:
        c, f = -c, -f
    return c, f * rx, f * ry, f * rz


@_jit
def interpolate_poses(p0: F64, p1: F64, s: F64, out: F64) -> None:  # pragma: no cover
    """Articulated interpolation between poses ``p0`` and ``p1`` ``(P,)`` at fractions ``s (K,)``
    into ``out (K, P)``: the root position linearly, every rotation slerped along the shorter arc
    (reference: :func:`cloth_client.avatar.capsules.interpolate_poses_reference`)."""
    for k in range(s.shape[0]):
        t = s[k]
        for d in range(3):
            out[k, d] = (1.0 - t) * p0[d] + t * p1[d]
    for i in range(3, p0.shape[0], 3):
        aw, ax, ay, az = _rotvec_quat(p0, i)
        bw, bx, by, bz = _rotvec_quat(p1, i)
        dot = aw * bw + ax * bx + ay * by + az * bz
        if dot < 0.0:
            bw, bx, by, bz, dot = -bw, -bx, -by, -bz, -dot
        theta = math.acos(min(dot, 1.0))
        st = math.sin(theta)
        for k in range(s.shape[0]):
            t = s[k]
            if st < 1e-6:
                w0, w1 = 1.0 - t, t
            else:
                w0, w1 = math.sin((1.0 - t) * theta) / st, math.sin(t * theta) / st
            qw, qx, qy, qz = w0 * aw + w1 * bw, w0 * ax + w1 * bx, w0 * ay + w1 * by, w0 * az + w1 * bz
            qn = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            qw, qx, qy, qz = qw / qn, qx / qn, qy / qn, qz / qn
            sn = math.sqrt(qx * qx + qy * qy + qz * qz)
            scale = 2.0 if sn < 1e-12 else 2.0 * math.atan2(sn, qw) / sn
            out[k, i], out[k, i + 1], out[k, i + 2] = scale * qx, scale * qy, scale * qz
