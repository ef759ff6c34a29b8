"""Batched 3D rotation conversions used by the skeleton, forward kinematics and motion files.

Conventions
-----------
* Rotation matrices act on column vectors: ``v_world = R @ v_local``.
* Rotation vectors (axis-angle, "rotvec") ``r = theta * axis`` with ``theta`` in radians.
* Quaternions are ``(w, x, y, z)``, unit norm.
* Euler angles follow BVH: for an order string such as ``"ZXY"`` the matrix is
  ``Rz(a0) @ Rx(a1) @ Ry(a2)`` (intrinsic rotations applied in the listed order).

Every function accepts arbitrary leading batch dimensions ``(..., 3)`` / ``(..., 3, 3)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "axis_rotation",
    "euler_to_matrix",
    "matrix_to_euler",
    "matrix_to_quat",
    "matrix_to_rotvec",
    "quat_slerp",
    "quat_to_matrix",
    "quat_to_rotvec",
    "rotation_angle_between",
    "rotvec_to_matrix",
    "rotvec_to_quat",
    "two_axis_frame",
]

FloatArray = NDArray[np.float64]

_EPS = 1e-12


def rotvec_to_matrix(rotvec: ArrayLike) -> FloatArray:
    """Rodrigues' formula.

    Parameters
    ----------
    rotvec : (..., 3) float
        Rotation vectors in radians.

    Returns
    -------
    (..., 3, 3) float64
        Rotation matrices.
    """
    r = np.asarray(rotvec, dtype=np.float64)
    theta = np.linalg.norm(r, axis=-1)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    # sin(t)/t and (1-cos(t))/t^2 with Taylor fallbacks near zero
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    x, y, z = r[..., 0], r[..., 1], r[..., 2]
    zero = np.zeros_like(x)
    k = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape((*r.shape[:-1], 3, 3))
    eye = np.broadcast_to(np.eye(3), k.shape)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def matrix_to_quat(m: ArrayLike) -> FloatArray:
    """Rotation matrices to unit quaternions ``(w, x, y, z)`` with ``w >= 0``.

    Parameters
    ----------
    m : (..., 3, 3) float

    Returns
    -------
    (..., 4) float64
    """
    m = np.asarray(m, dtype=np.float64)
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    # Shepperd's method: pick the numerically largest of 4 candidate denominators.
    cand = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    idx = np.argmax(cand, axis=-1)
    q = np.empty((*m.shape[:-2], 4))
    s = np.sqrt(np.maximum(np.take_along_axis(cand, idx[..., None], -1)[..., 0], _EPS)) * 2.0
    w0 = np.stack([0.25 * s, (m[..., 2, 1] - m[..., 1, 2]) / s, (m[..., 0, 2] - m[..., 2, 0]) / s,
                   (m[..., 1, 0] - m[..., 0, 1]) / s], -1)
    w1 = np.stack([(m[..., 2, 1] - m[..., 1, 2]) / s, 0.25 * s, (m[..., 0, 1] + m[..., 1, 0]) / s,
                   (m[..., 0, 2] + m[..., 2, 0]) / s], -1)
    w2 = np.stack([(m[..., 0, 2] - m[..., 2, 0]) / s, (m[..., 0, 1] + m[..., 1, 0]) / s, 0.25 * s,
                   (m[..., 1, 2] + m[..., 2, 1]) / s], -1)
    w3 = np.stack([(m[..., 1, 0] - m[..., 0, 1]) / s, (m[..., 0, 2] + m[..., 2, 0]) / s,
                   (m[..., 1, 2] + m[..., 2, 1]) / s, 0.25 * s], -1)
    q = np.choose(idx[..., None], [w0, w1, w2, w3])
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def quat_to_matrix(q: ArrayLike) -> FloatArray:
    """Unit quaternions ``(w, x, y, z)`` to rotation matrices.

    Parameters
    ----------
    q : (..., 4) float

    Returns
    -------
    (..., 3, 3) float64
    """
    qa: FloatArray = np.asarray(q, dtype=np.float64)
    qa = qa / np.linalg.norm(qa, axis=-1, keepdims=True)
    w, x, y, z = qa[..., 0], qa[..., 1], qa[..., 2], qa[..., 3]
    return np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], axis=-1).reshape((*qa.shape[:-1], 3, 3))


def matrix_to_rotvec(m: ArrayLike) -> FloatArray:
    """Rotation matrices to rotation vectors with angle in ``[0, pi]``.

    Parameters
    ----------
    m : (..., 3, 3) float

    Returns
    -------
    (..., 3) float64
    """
    return _unit_quat_to_rotvec(matrix_to_quat(m))  # w >= 0, so the angle is in [0, pi]


def _unit_quat_to_rotvec(q: FloatArray) -> FloatArray:
    """Unit quaternions with ``w >= 0`` to rotation vectors (angle in ``[0, pi]``)."""
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    theta = 2.0 * np.arctan2(s, q[..., 0])
    small = s < 1e-10
    scale = np.where(small, 2.0, theta / np.where(small, 1.0, s))
    return v * scale[..., None]


def rotvec_to_quat(rotvec: ArrayLike) -> FloatArray:
    """Rotation vectors to unit quaternions ``(w, x, y, z)`` with ``w >= 0`` (as
    ``matrix_to_quat(rotvec_to_matrix(r))``, without the matrices).

    Parameters
    ----------
    rotvec : (..., 3) float
        Rotation vectors in radians.

    Returns
    -------
    (..., 4) float64
    """
    r = np.asarray(rotvec, dtype=np.float64)
    theta = np.linalg.norm(r, axis=-1)
    small = theta < 1e-8
    half = 0.5 * theta
    # sin(t/2)/t with its Taylor term near zero
    k = np.where(small, 0.5 - theta**2 / 48.0, np.sin(half) / np.where(small, 1.0, theta))
    q = np.concatenate([np.cos(half)[..., None], r * k[..., None]], axis=-1)
    return np.where(q[..., :1] < 0, -q, q)  # an angle past pi: the same rotation, w >= 0


def quat_to_rotvec(q: ArrayLike) -> FloatArray:
    """Unit quaternions ``(w, x, y, z)`` to rotation vectors with angle in ``[0, pi]`` (as
    ``matrix_to_rotvec(quat_to_matrix(q))``, without the matrices).

    Parameters
    ----------
    q : (..., 4) float
        Need not be normalised.

    Returns
    -------
    (..., 3) float64
    """
    qa = np.asarray(q, dtype=np.float64)
    qa = qa / np.linalg.norm(qa, axis=-1, keepdims=True)
    return _unit_quat_to_rotvec(np.where(qa[..., :1] < 0, -qa, qa))


def axis_rotation(axis: str, angle: ArrayLike) -> FloatArray:
    """Elementary rotation about ``'X'``, ``'Y'`` or ``'Z'``.

    Parameters
    ----------
    axis : {'X', 'Y', 'Z'}
    angle : (...) float
        Radians.

    Returns
    -------
    (..., 3, 3) float64
    """
    a = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    ax = axis.upper()
    if ax == "X":
        rows = [o, z, z, z, c, -s, z, s, c]
    elif ax == "Y":
        rows = [c, z, s, z, o, z, -s, z, c]
    elif ax == "Z":
        rows = [c, -s, z, s, c, z, z, z, o]
    else:
        raise ValueError(f"unknown rotation axis {axis!r}")
    return np.stack(rows, axis=-1).reshape((*a.shape, 3, 3))


def euler_to_matrix(angles: ArrayLike, order: str) -> FloatArray:
    """Euler angles to matrices, BVH convention ``R = R_order[0] @ R_order[1] @ R_order[2]``.

    Parameters
    ----------
    angles : (..., 3) float
        Radians, in the order given by ``order``.
    order : str
        Three letters from ``XYZ``, e.g. ``"ZXY"``.

    Returns
    -------
    (..., 3, 3) float64
    """
    a = np.asarray(angles, dtype=np.float64)
    if len(order) != 3 or set(order.upper()) - set("XYZ"):
        raise ValueError(f"bad Euler order {order!r}")
    m = axis_rotation(order[0], a[..., 0])
    m = m @ axis_rotation(order[1], a[..., 1])
    return m @ axis_rotation(order[2], a[..., 2])


def matrix_to_euler(m: ArrayLike, order: str) -> FloatArray:
    """Inverse of :func:`euler_to_matrix` for any of the 6 Tait-Bryan orders.

    Parameters
    ----------
    m : (..., 3, 3) float
    order : str
        e.g. ``"ZXY"``; all three axes must differ.

    Returns
    -------
    (..., 3) float64
        Angles in radians, middle angle in ``[-pi/2, pi/2]``.
    """
    m = np.asarray(m, dtype=np.float64)
    order = order.upper()
    if len(order) != 3 or len(set(order)) != 3 or set(order) - set("XYZ"):
        raise ValueError(f"bad Euler order {order!r}")
    i, j, k = ("XYZ".index(c) for c in order)
    # parity: +1 for cyclic orders (XYZ, YZX, ZXY), -1 otherwise
    sign = 1.0 if (j - i) % 3 == 1 else -1.0
    # For R = R_i(a) R_j(b) R_k(c):  R[i,k] = sign * sin(b)
    sb = np.clip(sign * m[..., i, k], -1.0, 1.0)
    b = np.arcsin(sb)
    cb = np.sqrt(np.maximum(1.0 - sb * sb, 0.0))
    gimbal = cb < 1e-7
    a = np.arctan2(-sign * m[..., j, k], m[..., k, k])
    c = np.arctan2(-sign * m[..., i, j], m[..., i, i])
    # at gimbal lock put everything into the first angle
    a_g = np.arctan2(sign * m[..., k, j], m[..., j, j])
    a = np.where(gimbal, a_g, a)
    c = np.where(gimbal, 0.0, c)
    return np.stack([a, b, c], axis=-1)


def quat_slerp(q0: ArrayLike, q1: ArrayLike, t: ArrayLike) -> FloatArray:
    """Spherical linear interpolation along the shorter arc.

    Parameters
    ----------
    q0, q1 : (..., 4) float
        Unit quaternions.
    t : (...) float
        Interpolation parameter in ``[0, 1]`` (broadcast against the batch).

    Returns
    -------
    (..., 4) float64
    """
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)[..., None]
    d = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(d < 0, -q1, q1)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    st = np.sin(theta)
    lin = st < 1e-6
    safe = np.where(lin, 1.0, st)
    w0 = np.where(lin, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    w1 = np.where(lin, t, np.sin(t * theta) / safe)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def rotation_angle_between(m0: ArrayLike, m1: ArrayLike) -> FloatArray:
    """Geodesic angle (radians) between two batches of rotation matrices, shape ``(...)``."""
    m0 = np.asarray(m0, dtype=np.float64)
    m1 = np.asarray(m1, dtype=np.float64)
    tr = np.einsum("...ij,...ij->...", m0, m1)
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def _normalize(v: FloatArray) -> FloatArray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, _EPS)


def two_axis_frame(a_rest: ArrayLike, a_target: ArrayLike, b_rest: ArrayLike, b_target: ArrayLike) -> FloatArray:
    """Rotation that maps ``a_rest`` exactly onto the direction ``a_target`` and turns ``b_rest``
    as close as possible to ``b_target`` (the TRIAD construction).

    Parameters
    ----------
    a_rest, a_target, b_rest, b_target : (..., 3) float
        Need not be unit length; ``b`` must not be parallel to ``a``.

    Returns
    -------
    (..., 3, 3) float64
        ``R`` with ``R @ a_rest/|a_rest| == a_target/|a_target|``.
    """
    def frame(a: ArrayLike, b: ArrayLike) -> FloatArray:
        a = _normalize(np.asarray(a, dtype=np.float64))
        b = np.asarray(b, dtype=np.float64)
        b = _normalize(b - np.sum(a * b, axis=-1, keepdims=True) * a)
        c = np.cross(a, b)
        return np.stack([a, b, c], axis=-1)  # columns

    fr = frame(a_rest, b_rest)
    ft = frame(a_target, b_target)
    return ft @ np.swapaxes(fr, -1, -2)
