from pathlib import Path

import numpy as np
import pytest

from protocol import fk
from protocol.formats.gesture_script import ScriptError, load_script, parse_script, script_poses
from protocol.formats.load import load_motion
from protocol.rotations import euler_to_matrix, rotvec_to_matrix
from protocol.skeleton import JOINT_INDEX as J
from protocol.skeleton import ROT_JOINTS, default_body, standing_pose

EXAMPLE = Path(__file__).resolve().parents[2] / "protocol" / "scripts" / "crouch.toml"

SIMPLE = """
fps = 10
base = "tpose"
[[key]]
t = 0.0
[[key]]
t = 1.0
ease = "linear"
root = { x = 1.0, yaw = 90 }
joints.l_elbow = { y = -90 }
[[key]]
t = 2.0
joints.r_knee = [60, 0, 0]
"""


def _rot(poses: np.ndarray, joint: str) -> np.ndarray:
    k = ROT_JOINTS.index(joint)
    return rotvec_to_matrix(poses[..., 3 + 3 * k: 6 + 3 * k])


def test_shipped_example_loads_and_crouches() -> None:
    m = load_motion(EXAMPLE)
    assert m.name == "crouch" and m.fps == 30
    j = fk(m.poses, m.body)
    assert j[:, J["pelvis"], 1].min() < j[0, J["pelvis"], 1] - 0.3  # crouches by > 30 cm
    # feet planted: ankles stay put and on the floor
    ank = j[:, [J["l_ankle"], J["r_ankle"]]]
    assert np.abs(ank[..., 1] - ank[0, :, 1]).max() < 0.01
    assert np.abs(ank.mean(axis=1)[:, [0, 2]] - ank[0].mean(axis=0)[[0, 2]]).max() < 1e-9
    np.testing.assert_allclose(m.poses[-1], m.poses[0], atol=1e-9)  # back to standing


def test_keys_interpolate_and_inherit() -> None:
    s = parse_script(SIMPLE)
    p = script_poses(s, default_body())
    assert p.shape == (21, 60)
    # at key 2 (t = 1 s): elbow exactly -90 about Y, root moved 1 m and turned 90 deg
    np.testing.assert_allclose(_rot(p[10], "l_elbow"), euler_to_matrix(np.radians([-90, 0, 0]), "YXZ"), atol=1e-9)
    assert p[10, 0] == pytest.approx(1.0)
    np.testing.assert_allclose(_rot(p[10], "pelvis") @ [0, 0, 1], [1, 0, 0], atol=1e-9)
    # halfway, linear easing: 45 degrees
    np.testing.assert_allclose(_rot(p[5], "l_elbow"), euler_to_matrix(np.radians([-45, 0, 0]), "YXZ"), atol=1e-9)
    # the last key inherits the elbow and adds the knee
    np.testing.assert_allclose(_rot(p[20], "l_elbow"), _rot(p[10], "l_elbow"), atol=1e-9)
    np.testing.assert_allclose(_rot(p[20], "r_knee"), euler_to_matrix(np.radians([60, 0, 0]), "XYZ"), atol=1e-9)
    # any output rate
    assert script_poses(s, default_body(), fps=120).shape == (241, 60)


def test_stand_base_and_easing_in_out() -> None:
    s = parse_script(SIMPLE.replace('base = "tpose"', 'base = "stand"').replace('ease = "linear"', 'ease = "in_out"'))
    p = script_poses(s, default_body())
    np.testing.assert_allclose(p[0, 3:], standing_pose()[3:], atol=1e-12)
    assert p[3, 0] == pytest.approx(0.3 * 0.3 * (3 - 0.6))  # smoothstep at 0.3


def test_noise_is_deterministic_for_a_seed() -> None:
    s = parse_script(SIMPLE + "\n[noise]\nrotation_deg = 2.0\nposition_m = 0.01\nseed = 4\n")
    a, b = script_poses(s, default_body()), script_poses(s, default_body())
    np.testing.assert_array_equal(a, b)
    clean = script_poses(parse_script(SIMPLE), default_body())
    assert 0.01 < np.std(a[:, 6:] - clean[:, 6:]) < 0.06
    c = script_poses(s, default_body(), rng=np.random.default_rng(99))
    assert not np.array_equal(a, c)


@pytest.mark.parametrize(
    ("text", "what"),
    [
        ("[[key]]\nt = 0\njoints.l_elbo = { y = 1 }", "unknown joint"),
        ("[[key]]\nt = 1\n[[key]]\nt = 0.5", "increase"),
        ("[[key]]\nt = 0\nease = 'wobble'", "ease"),
        ("[[key]]\nt = 0\njoints.l_elbow = { y = 'x' }", "number"),
        ("[[key]]\nt = 0\njoints.l_elbow = [1, 2]", "3 angles"),
        ("[[key]]\nt = 0\nroot = { q = 1 }", "root"),
        ("colour = 3\n[[key]]\nt = 0", "unknown top-level"),
        ("fps = 30", "at least one"),
        ("[[key]\nt = 0", "invalid TOML"),
        ("feet = 'glued'\n[[key]]\nt = 0", "feet"),
    ],
)
def test_bad_scripts_are_clear_errors(text: str, what: str) -> None:
    with pytest.raises(ScriptError, match=what):
        parse_script(text, "bad.toml")


def test_bad_body_and_missing_file(tmp_path: Path) -> None:
    p = tmp_path / "b.toml"
    p.write_text("[body]\nheight_m = 9.0\n[[key]]\nt = 0\n")
    with pytest.raises(ScriptError, match="body"):
        load_script(p)
    with pytest.raises(FileNotFoundError):
        load_motion(tmp_path / "missing.toml")
