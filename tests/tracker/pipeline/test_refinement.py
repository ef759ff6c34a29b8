"""The published pose's local refinement toward the appearance cue's joints: the rotations' algebra,
the walk down the kinematic tree (numba kernel held equal to the numpy reference), its limits
(s = 0: unchanged; s large and an exact reading: the reading's pose) and its guards."""

from __future__ import annotations

import numpy as np
import pytest

from protocol import fk
from protocol.kinematics import fk_global
from protocol.rotations import rotation_angle_between, rotvec_to_matrix
from protocol.skeleton import JOINT_INDEX, PARENTS, POSE_SIZE, default_body, standing_pose
from tracker_service.pipeline.refinement import RefineParams, kabsch_rotation, refine_pose, swing_rotation


def _poses(rng: np.random.Generator, spread: float = 0.4) -> tuple[np.ndarray, np.ndarray]:
    base = np.asarray(standing_pose(), np.float64)
    a, b = base.copy(), base.copy()
    a[3:] += rng.normal(0, 0.2, POSE_SIZE - 3)
    b[3:] += rng.normal(0, spread, POSE_SIZE - 3)
    return a, b


def _reading(pose: np.ndarray, body, cam_rot: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]
    j = fk(pose, body)
    return ((j - j[0]) @ cam_rot) / body.height


def _rel(pose: np.ndarray, body) -> np.ndarray:  # type: ignore[no-untyped-def]
    j = fk(pose, body)
    return j - j[0]


@pytest.mark.parametrize("seed", range(4))
def test_swing_turns_a_onto_b_by_the_smallest_angle(seed: int) -> None:
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=3), rng.normal(size=3)
    r = swing_rotation(a, b)
    assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)
    assert np.allclose(r @ (a / np.linalg.norm(a)), b / np.linalg.norm(b))
    axis = np.cross(a, b)  # the axis perpendicular to both stays put: no twist
    assert np.allclose(r @ axis, axis)
    assert np.allclose(swing_rotation(a, 3 * a), np.eye(3))
    assert np.allclose(swing_rotation(np.zeros(3), b), np.eye(3))
    flip = swing_rotation(a, -a)  # antiparallel: a half turn
    assert np.allclose(flip @ a, -a) and np.isclose(np.linalg.det(flip), 1.0)


def test_kabsch_recovers_a_rotation_and_never_reflects(rng: np.random.Generator) -> None:
    r = rotvec_to_matrix(rng.normal(0, 1.0, 3))
    a = rng.normal(size=(3, 3))
    assert np.allclose(kabsch_rotation(a, a @ r.T, np.ones(3)), r)
    mirrored = a * np.array([1.0, 1.0, -1.0])  # the best orthogonal map is a reflection; a rotation is returned
    k = kabsch_rotation(a, mirrored, np.array([1.0, 2.0, 0.5]))
    assert np.isclose(np.linalg.det(k), 1.0)


@pytest.mark.parametrize("seed", range(6))
def test_kernel_equals_the_numpy_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    body = default_body()
    a, b = _poses(rng)
    cam = rotvec_to_matrix(rng.normal(0, 0.3, 3))
    mu = _reading(b, body, cam) + rng.normal(0, 0.02, (len(PARENTS), 3))
    var = rng.uniform(1e-4, 4e-3, mu.shape)
    params = RefineParams((0.05 + rng.uniform(0, 0.1), 0.08, 0.2), turn_prior=(0.0, 0.3)[seed % 2])
    ref = refine_pose(a, body, cam, mu, var, body.height, params, use_kernel=False)
    ker = refine_pose(a, body, cam, mu, var, body.height, params, use_kernel=True)
    assert np.abs(fk(ref, body) - fk(ker, body)).max() < 1e-9


def test_limits_unchanged_at_zero_and_the_reading_at_infinity(rng: np.random.Generator) -> None:
    body = default_body()
    a, b = _poses(rng)
    cam = rotvec_to_matrix(np.array([0.1, 0.6, -0.05]))
    mu, tiny = _reading(b, body, cam), np.full((len(PARENTS), 3), 1e-10)
    same = refine_pose(a, body, cam, mu, tiny, body.height, RefineParams((0.0, 0.0, 0.0)))
    assert np.array_equal(same, a)
    out = refine_pose(a, body, cam, mu, tiny, body.height, RefineParams((100.0, 100.0, 100.0), turn_prior=0.0))
    assert np.abs(_rel(a, body) - _rel(b, body)).max() > 0.2
    assert np.abs(_rel(out, body) - _rel(b, body)).max() < 1e-6  # every joint where the network reads it
    assert np.array_equal(out[:3], a[:3])  # the root's position is the filter's


def test_the_fusion_moves_part_way_by_the_variances(rng: np.random.Generator) -> None:
    """Between the limits the pose moves toward the reading, more for a confident network; bone
    lengths stay the body's."""
    body = default_body()
    a, b = _poses(rng, spread=0.25)
    cam = np.eye(3)
    mu = _reading(b, body, cam)
    err = {}
    for var in (1e-2, 1e-3):
        out = refine_pose(a, body, cam, mu, np.full(mu.shape, var), body.height, RefineParams())
        err[var] = float(np.linalg.norm(_rel(out, body) - _rel(b, body), axis=1).mean())
        j = fk(out, body)
        bones = np.linalg.norm(j[1:] - j[list(PARENTS[1:])], axis=1)
        assert np.allclose(bones, np.linalg.norm(body.offsets[1:], axis=1))
    before = float(np.linalg.norm(_rel(a, body) - _rel(b, body), axis=1).mean())
    assert err[1e-3] < err[1e-2] < before


def test_bad_readings_leave_the_pose_alone(rng: np.random.Generator) -> None:
    body = default_body()
    a, b = _poses(rng)
    mu, var = _reading(b, body, np.eye(3)), np.full((len(PARENTS), 3), 1e-3)
    for m, v, h in ((np.where(np.arange(mu.size).reshape(mu.shape) == 5, np.nan, mu), var, body.height),
                    (mu, np.full(var.shape, np.inf), body.height), (mu, var, 0.0), (mu, var, np.nan)):
        assert np.array_equal(refine_pose(a, body, np.eye(3), m, v, h, RefineParams()), a)
    with pytest.raises(ValueError, match="shape"):
        refine_pose(a[:-1], body, np.eye(3), mu, var, body.height, RefineParams())
    with pytest.raises(ValueError, match="pose_sd"):
        RefineParams((0.1, -0.1, 0.1))
    with pytest.raises(ValueError, match="pose_sd"):
        RefineParams((0.1, np.nan, 0.1))
    with pytest.raises(ValueError, match="turn_prior"):
        RefineParams(turn_prior=-1.0)


def test_the_turn_prior_keeps_reading_noise_from_twisting_the_chest() -> None:
    """The chest's children (neck, clavicles) are nearly parallel: without the prior a few
    centimetres of noise in the reading spin the chest about them (right joints from wrong
    rotations); with it the chest's rotation stays near the truth and the joints are no worse."""
    rng = np.random.default_rng(5)
    body = default_body()
    chest = JOINT_INDEX["chest"]
    rot_err: dict[float, list[float]] = {0.0: [], 0.3: []}
    joint_err: dict[float, list[float]] = {0.0: [], 0.3: []}
    for _ in range(40):
        a, b = _poses(rng, spread=0.3)
        a[3:] = b[3:] + rng.normal(0, 0.1, POSE_SIZE - 3)
        noise = 0.02  # of the height: 3.4 cm
        mu = _reading(b, body, np.eye(3)) + rng.normal(0, noise, (len(PARENTS), 3))
        var = np.full(mu.shape, noise ** 2)
        _, rb = fk_global(b, body)
        for prior in rot_err:
            out = refine_pose(a, body, np.eye(3), mu, var, body.height, RefineParams(turn_prior=prior))
            _, ro = fk_global(out, body)
            rot_err[prior].append(float(np.degrees(rotation_angle_between(ro[chest], rb[chest]))))
            joint_err[prior].append(float(np.linalg.norm(_rel(out, body) - _rel(b, body), axis=1).mean()))
    assert np.median(rot_err[0.3]) < 0.6 * np.median(rot_err[0.0])
    assert np.mean(joint_err[0.3]) <= 1.05 * np.mean(joint_err[0.0])
