"""Numba kernels of :mod:`tracker_service.pipeline.process`. Each has a plain-numpy reference beside the code
that uses it, and a test holds the two equal."""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import NDArray


@njit(cache=True, nogil=True)
def _swing_into(ax: float, ay: float, az: float, bx: float, by: float, bz: float,
                out: NDArray[np.float64]) -> None:
    """The smallest rotation turning direction a onto direction b, written to ``out`` (3, 3).
    Reference: :func:`tracker_service.pipeline.refinement.swing_rotation`."""
    for i in range(3):
        for j in range(3):
            out[i, j] = 1.0 if i == j else 0.0
    na = np.sqrt(ax * ax + ay * ay + az * az)
    nb = np.sqrt(bx * bx + by * by + bz * bz)
    if not (na > 1e-12 and nb > 1e-12):
        return
    ux, uy, uz = ax / na, ay / na, az / na
    wx, wy, wz = bx / nb, by / nb, bz / nb
    cx, cy, cz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
    s = np.sqrt(cx * cx + cy * cy + cz * cz)
    c = ux * wx + uy * wy + uz * wz
    if s < 1e-12:
        if c > 0.0:
            return
        # antiparallel: pi about an axis perpendicular to u (the cross with the smallest axis of u)
        m = 0
        if abs(uy) < abs(ux):
            m = 1
        if abs(uz) < min(abs(ux), abs(uy)):
            m = 2
        e = np.zeros(3)
        e[m] = 1.0
        px, py, pz = uy * e[2] - uz * e[1], uz * e[0] - ux * e[2], ux * e[1] - uy * e[0]
        n = np.sqrt(px * px + py * py + pz * pz)
        k = (px / n, py / n, pz / n)
        for i in range(3):
            for j in range(3):
                out[i, j] = 2.0 * k[i] * k[j] - (1.0 if i == j else 0.0)
        return
    kx, ky, kz = cx / s, cy / s, cz / s
    kk = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    k2 = kk @ kk
    for i in range(3):
        for j in range(3):
            out[i, j] += s * kk[i, j] + (1.0 - c) * k2[i, j]


@njit(cache=True, nogil=True)
def refine_rotations_kernel(local: NDArray[np.float64], cam_rot: NDArray[np.float64], offsets: NDArray[np.float64],
                            parents: NDArray[np.int64], slots: NDArray[np.int64], child_ptr: NDArray[np.int64],
                            child_idx: NDArray[np.int64], target: NDArray[np.float64], gain: NDArray[np.float64],
                            weight: NDArray[np.float64], prior: float) -> NDArray[np.float64]:
    """The pose refinement's walk down the kinematic tree (reference:
    :func:`tracker_service.pipeline.refinement.refine_rotations`, same arguments plus the skeleton's
    ``parents`` (J,), rotation ``slots`` (J,) and children in CSR form ``child_ptr`` (J + 1,),
    ``child_idx``).

    Returns
    -------
    (R, 3, 3) float64
        The refined local rotations.
    """
    nj = parents.shape[0]
    r = cam_rot
    rt = np.ascontiguousarray(r.T)
    out = local.copy()
    glob_c = np.empty((nj, 3, 3))
    pos = np.zeros((nj, 3))
    turn = np.empty((3, 3))
    for j in range(nj):
        par = parents[j]
        slot = slots[j]
        if par < 0:
            glob_c[j] = rt @ local[slot]
        else:
            pos[j] = pos[par] + glob_c[par] @ offsets[j]
            if slot >= 0:
                glob_c[j] = glob_c[par] @ local[slot]
            else:
                glob_c[j] = glob_c[par]
        n = child_ptr[j + 1] - child_ptr[j]
        if n == 0:
            continue
        a = np.empty((n, 3))
        tgt = np.empty((n, 3))
        for q in range(n):
            c = child_idx[child_ptr[j] + q]
            a[q] = glob_c[j] @ offsets[c]
            for d in range(3):
                tgt[q, d] = a[q, d] + gain[c, d] * (target[c, d] - (pos[j, d] + a[q, d]))
        if n == 1:
            _swing_into(a[0, 0], a[0, 1], a[0, 2], tgt[0, 0], tgt[0, 1], tgt[0, 2], turn)
        else:
            h = np.zeros((3, 3))
            spread = 0.0
            for q in range(n):
                w = weight[child_idx[child_ptr[j] + q]]
                spread += w * (a[q, 0] * a[q, 0] + a[q, 1] * a[q, 1] + a[q, 2] * a[q, 2])
                for d in range(3):
                    for e in range(3):
                        h[d, e] += w * a[q, d] * tgt[q, e]
            for d in range(3):
                h[d, d] += prior * spread
            u, _, vt = np.linalg.svd(h)
            v = np.ascontiguousarray(vt.T)
            ut = np.ascontiguousarray(u.T)
            if np.linalg.det(v @ ut) < 0.0:
                for d in range(3):
                    v[d, 2] = -v[d, 2]
            turn[:, :] = v @ ut
        glob_c[j] = turn @ glob_c[j]
        if par < 0:
            out[slot] = r @ glob_c[j]
        else:
            out[slot] = np.ascontiguousarray(glob_c[par].T) @ glob_c[j]
    return out
