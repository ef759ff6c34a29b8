"""Local refinement of the published pose toward the appearance cue's joints.

The tree filter chooses among the database's leaves: however good the likelihood, the published
pose (the support's tempered mean) is never closer to the truth than the database's nearest leaf,
and the mean of a few leaves is a compromise between them. ELMO (``elmo_likelihood_modes.txt``)
retrieves hypotheses and then *refines them locally* against the observation; this module is that
second step for the appearance cue of :mod:`tracker_service.cues.appearance`.

The network reads every joint's position relative to the pelvis with a variance ``v`` per camera
axis. The filter's pose is treated as a Gaussian estimate of the same joints with a standard
deviation ``s`` per camera axis (:class:`RefineParams`), and the two are fused joint by joint down
the kinematic tree:

1. Visit the joints parents first. A joint's global rotation is its parent's (already refined)
   times its own local rotation, so its children sit where the refined ancestors put them.
2. Each child ``c`` gets a target: the precision-weighted mean of where the pose puts it, ``p_c``,
   and where the network reads it, ``mu_c`` (per camera axis):
   ``t_c = p_c + s^2 / (s^2 + v_c) (mu_c - p_c)``.
3. The joint turns so that its children move toward their targets: the smallest rotation (a swing:
   the bone's twist is kept) that points the bone at ``t_c`` for one child; for several (pelvis,
   chest) the weighted least-squares rotation (Kabsch) of the child offsets onto the targets, each
   child weighted by ``1 / (s^2 + mean v_c)``.

The bone lengths stay the body model's, so the result is a pose of the same skeleton; its root
position is not changed (the network is pelvis-relative). With ``s -> 0`` the pose is unchanged;
with ``s -> inf`` every bone points at the network's reading.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from protocol.rotations import matrix_to_rotvec, rotvec_to_matrix
from protocol.skeleton import N_JOINTS, PARENTS, POSE_SIZE, ROT_SLOT, Body
from tracker_service.pipeline._kernels import refine_rotations_kernel

__all__ = ["RefineParams", "kabsch_rotation", "refine_pose", "refine_rotations", "swing_rotation"]

#: Children of every joint (empty for end joints), parents first.
CHILDREN: tuple[tuple[int, ...], ...] = tuple(
    tuple(c for c in range(N_JOINTS) if PARENTS[c] == j) for j in range(N_JOINTS))
_PARENTS = np.array(PARENTS, np.int64)
_SLOTS = np.array(ROT_SLOT, np.int64)
_CHILD_PTR = np.cumsum([0, *(len(c) for c in CHILDREN)]).astype(np.int64)
_CHILD_IDX = np.array([c for cs in CHILDREN for c in cs], np.int64)


@dataclass(frozen=True)
class RefineParams:
    """How far the published pose moves toward the appearance cue's joints.

    Attributes
    ----------
    pose_sd : (3,) tuple of float
        Standard deviation (metres) of the filter's joint positions along the camera's x (right),
        y (up) and z (towards the camera) axes: the filter pose's weight against the network's
        variance. Depth is the silhouette's weak axis, hence the larger value. With one network,
        8 / 8 / 16 cm (5-20 cm measured flat); with the ensemble of two networks and its
        readings Kalman-filtered, 12 / 12 / 24 cm leans more on the reading: frames within 10 cm
        0.943 -> 0.950 on 17 held-out takes of the tall subject (seed 11), unchanged on seed 7.
    turn_prior : float
        For the joints with several children (pelvis, chest): the pull toward no turn, relative to
        the children's spread (:func:`kabsch_rotation`). The chest's children (neck, clavicles)
        are nearly parallel, so without it a few centimetres of reading noise twist the chest by
        tens of degrees (and the clavicles back), right joints from wrong rotations.
    """

    pose_sd: tuple[float, float, float] = (0.12, 0.12, 0.24)
    turn_prior: float = 0.3

    def __post_init__(self) -> None:
        if len(self.pose_sd) != 3 or not all(np.isfinite(s) and s >= 0 for s in self.pose_sd):
            raise ValueError(f"pose_sd must be three finite values >= 0, got {self.pose_sd}")
        if not (np.isfinite(self.turn_prior) and self.turn_prior >= 0):
            raise ValueError(f"turn_prior must be finite and >= 0, got {self.turn_prior}")


def swing_rotation(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """The smallest rotation turning direction ``a`` onto direction ``b``.

    Parameters
    ----------
    a, b : (3,) float64
        Non-zero vectors (their lengths do not matter).

    Returns
    -------
    (3, 3) float64
        Rotation matrix ``R`` with ``R a / |a| = b / |b|``; the identity when either is zero or they
        are parallel. Antiparallel vectors turn by pi about an axis perpendicular to ``a``.
    """
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if not (na > 1e-12 and nb > 1e-12):
        return np.eye(3)
    u, w = a / na, b / nb
    axis = np.cross(u, w)
    s, c = float(np.linalg.norm(axis)), float(u @ w)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(u, np.eye(3)[int(np.argmin(np.abs(u)))])
        k = perp / np.linalg.norm(perp)
        return 2.0 * np.outer(k, k) - np.eye(3)
    k = axis / s
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + s * kx + (1.0 - c) * (kx @ kx)


def kabsch_rotation(a: NDArray[np.float64], b: NDArray[np.float64], w: NDArray[np.float64],
                    prior: float = 0.0) -> NDArray[np.float64]:
    """The rotation ``R`` minimising ``sum_i w_i |R a_i - b_i|^2 + 2 lam (3 - tr R)`` (weighted
    Kabsch, no reflection, pulled toward no turn), ``lam = prior * sum_i w_i |a_i|^2``.

    Parameters
    ----------
    a, b : (n, 3) float64
        Vectors before and their targets.
    w : (n,) float64
        Non-negative weights.
    prior : float
        Strength of the pull toward the identity relative to the vectors' spread: about an axis the
        vectors barely turn (nearly parallel vectors say little about the twist about them), a
        rotation costs more than the fit gains, so noise cannot spin it.

    Returns
    -------
    (3, 3) float64
    """
    h = (a * w[:, None]).T @ b + prior * float(w @ np.einsum("ij,ij->i", a, a)) * np.eye(3)
    u, _, vt = np.linalg.svd(h)
    d = 1.0 if np.linalg.det(vt.T @ u.T) >= 0 else -1.0
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def refine_rotations(local: NDArray[np.float64], cam_rot: NDArray[np.float64], offsets: NDArray[np.float64],
                     target: NDArray[np.float64], gain: NDArray[np.float64], weight: NDArray[np.float64],
                     prior: float) -> NDArray[np.float64]:
    """Steps 1-3 of the module docstring on rotation matrices (numpy reference of
    :func:`tracker_service.pipeline._kernels.refine_rotations_kernel`).

    Parameters
    ----------
    local : (R, 3, 3) float64
        Local rotation of each joint of ``ROT_JOINTS`` (the root's is global, world axes).
    cam_rot : (3, 3) float64
        ``Camera.pose[:3, :3]``.
    offsets : (J, 3) float64
        ``Body.offsets``.
    target : (J, 3) float64
        The network's joints relative to the pelvis, camera axes, metres.
    gain : (J, 3) float64
        ``s^2 / (s^2 + v)`` per joint and camera axis.
    weight : (J,) float64
        Each joint's weight as one of several children (Kabsch).
    prior : float
        :attr:`RefineParams.turn_prior`.

    Returns
    -------
    (R, 3, 3) float64
        The refined local rotations.
    """
    r = cam_rot
    out = local.copy()
    glob_c = np.empty((N_JOINTS, 3, 3))  # global rotations in camera axes: r.T @ world rotation
    pos = np.zeros((N_JOINTS, 3))
    for j in range(N_JOINTS):
        par = PARENTS[j]
        slot = ROT_SLOT[j]
        if par < 0:
            glob_c[j] = r.T @ local[slot]
        else:
            pos[j] = pos[par] + glob_c[par] @ offsets[j]
            # the parent may have turned: this joint keeps its local rotation
            glob_c[j] = glob_c[par] @ local[slot] if slot >= 0 else glob_c[par]
        kids = list(CHILDREN[j])
        if not kids:
            continue
        a = (glob_c[j] @ offsets[kids].T).T  # (n, 3) child offsets in camera axes
        tgt = a + gain[kids] * (target[kids] - (pos[j] + a))
        turn = swing_rotation(a[0], tgt[0]) if len(kids) == 1 else kabsch_rotation(a, tgt, weight[kids], prior)
        glob_c[j] = turn @ glob_c[j]
        # the root's rotation is global (world axes: r @ g); the others are relative to the parent
        out[slot] = r @ glob_c[j] if par < 0 else glob_c[par].T @ glob_c[j]
    return out


def refine_pose(pose: NDArray[np.float64], body: Body, cam_rot: NDArray[np.float64], mu: NDArray[np.float64],
                var: NDArray[np.float64], height: float, params: RefineParams, use_kernel: bool = True
                ) -> NDArray[np.float64]:
    """Turn the joints of ``pose`` toward the network's joint positions (see the module docstring).

    Parameters
    ----------
    pose : (P,) float64
        World pose (layout of :mod:`protocol.skeleton`).
    body : Body
        The skeleton the pose is published with.
    cam_rot : (3, 3) float64
        The camera's orientation (``Camera.pose[:3, :3]``): ``v_cam = v_world @ cam_rot``.
    mu, var : (J, 3) float64
        :func:`tracker_service.cues.appearance.predict_joints`: joints relative to the pelvis in the
        camera's axes, and their variances, in units of ``height``.
    height : float
        The person's height (metres) that scales the network's reading.
    params : RefineParams
    use_kernel : bool
        The numba kernel (default) or the numpy reference :func:`refine_rotations`.

    Returns
    -------
    (P,) float64
        A new pose: the same root position and bone lengths, rotations refined. A copy of ``pose``
        when the reading is not finite or every ``pose_sd`` is 0.
    """
    pose = np.asarray(pose, np.float64)
    if pose.shape != (POSE_SIZE,):
        raise ValueError(f"pose must have shape ({POSE_SIZE},), got {pose.shape}")
    if not (np.isfinite(mu).all() and np.isfinite(var).all() and np.isfinite(height) and height > 0):
        return pose.copy()
    s2 = np.square(np.asarray(params.pose_sd, np.float64))
    if not s2.any() or not np.isfinite(pose).all():
        return pose.copy()
    target = np.asarray(mu, np.float64) * height
    v = np.maximum(np.asarray(var, np.float64), 0.0) * height * height
    gain = s2 / (s2 + v + 1e-12)
    weight = 1.0 / (s2.mean() + v.mean(axis=1) + 1e-12)
    local = rotvec_to_matrix(pose[3:].reshape(-1, 3))
    r = np.ascontiguousarray(cam_rot, np.float64)
    if use_kernel:
        new = refine_rotations_kernel(local, r, body.offsets, _PARENTS, _SLOTS, _CHILD_PTR, _CHILD_IDX,
                                      target, gain, weight, params.turn_prior)
    else:
        new = refine_rotations(local, r, body.offsets, target, gain, weight, params.turn_prior)
    out = pose.copy()
    out[3:] = matrix_to_rotvec(new).ravel()
    return out
