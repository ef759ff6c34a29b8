import re
from pathlib import Path

import numpy as np
import pytest

from protocol import fk
from protocol.formats.bvh import BvhError, bvh_fk, read_bvh, write_bvh
from protocol.formats.load import load_motion
from protocol.formats.mocap_data import IndexEntry
from protocol.motion import is_native
from protocol.rotations import axis_rotation, rotvec_to_matrix

CHAIN = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Xrotation Yrotation Zrotation
  JOINT Knee
  {
    OFFSET 0 -40 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -40 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
10 90 0 0 0 0 0 0 0
0 100 0 0 90 0 0 90 0
"""


def test_hand_made_chain_fk() -> None:
    b = read_bvh("chain.bvh", text=CHAIN)
    assert b.offset_mode == "add"
    assert b.fps == 30.0
    assert b.joints[0].rotation_order == "XYZ"
    assert b.joints[1].rotation_order == "ZXY"
    pos, rot = bvh_fk(b, 0.01)
    np.testing.assert_allclose(pos[0, 0], [0.1, 0.9, 0])
    np.testing.assert_allclose(pos[0, 1], [0.1, 0.5, 0])
    # frame 1: root turned 90 deg about Y, knee 90 deg about X (ZXY order -> middle angle is X)
    np.testing.assert_allclose(pos[1, 1], [0, 0.6, 0], atol=1e-12)
    expected = axis_rotation("Y", np.pi / 2) @ axis_rotation("X", np.pi / 2)
    np.testing.assert_allclose(rot[1, 1], expected, atol=1e-12)


def test_replace_convention_detected() -> None:
    text = CHAIN.replace("CHANNELS 3 Zrotation Xrotation Yrotation",
                         "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation")
    text = text.replace("10 90 0 0 0 0 0 0 0", "10 90 0 0 0 0 0 -40 0 0 0 0")
    text = text.replace("0 100 0 0 90 0 0 90 0", "0 100 0 0 90 0 0 -40 0 0 90 0")
    b = read_bvh("r.bvh", text=text)
    assert b.offset_mode == "replace"
    pos, _ = bvh_fk(b, 0.01)
    np.testing.assert_allclose(pos[0, 1], [0.1, 0.5, 0])  # not doubled
    assert read_bvh("r.bvh", "add", text=text).offset_mode == "add"


@pytest.mark.parametrize(
    ("mutate", "line", "what"),
    [
        (lambda t: t.replace("HIERARCHY", "HIER"), 1, "HIERARCHY"),
        (lambda t: t.replace("MOTION", "MOTON"), None, "MOTION"),
        (lambda t: t.replace("OFFSET 0 -40 0\n    CHANNELS", "OFFSET 0 -4x0 0\n    CHANNELS"), 8, "number"),
        (lambda t: t.replace("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 3 Zrotation Xrotation Wrotation"), 9,
         "channel"),
        (lambda t: t.replace("0 100 0 0 90 0 0 90 0", "0 100 0 0 90 0 0 90"), 20, "expected 9 values"),
        (lambda t: t.replace("0 100 0 0 90 0 0 90 0", "0 100 0 0 abc 0 0 90 0"), 20, "non-numeric"),
        (lambda t: t.replace("0 100 0 0 90 0 0 90 0", "0 100 0 0 nan 0 0 90 0"), 20, "NaN"),
        (lambda t: t.replace("Frames: 2", "Frames: 5"), 21, "truncated"),
        (lambda t: t.replace("Frames: 2", "Frames: 1"), 20, "more data"),
        (lambda t: t.replace("Frame Time: 0.0333333", "Frame Time: 0"), 18, "Frame Time"),
        (lambda t: t.replace("  }\n}\nMOTION", "  }\nMOTION"), None, "not closed"),
    ],
)
def test_malformed_files_name_file_and_line(mutate, line, what, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    p = tmp_path / "bad.bvh"
    p.write_text(mutate(CHAIN))
    with pytest.raises(BvhError, match=re.escape(what)) as info:
        read_bvh(p)
    assert str(p) in str(info.value)
    if line is not None:
        assert info.value.line == line, str(info.value)


def test_missing_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="no such motion file"):
        load_motion(tmp_path / "nope.bvh")


def test_every_shared_file_reads(mocap_index: list[IndexEntry], mocap_dir: Path) -> None:
    assert len(mocap_index) >= 250
    for e in mocap_index:
        b = read_bvh(mocap_dir / e.path)
        assert b.n_frames == e.frames, e.path
        assert len(b.joints) == e.joints, e.path
        assert abs(b.fps - e.fps) < 0.01 * e.fps, e.path
        assert b.offset_mode == ("replace" if e.path.startswith("bandai/") else "add"), e.path


def test_units_are_detected_per_source(mocap_dir: Path) -> None:
    from protocol.formats.retarget import source_skeleton

    for rel, scale in [("bandai/dataset-1_walk_normal_001.bvh", 0.01), ("cmu/01_01.bvh", 0.0254 / 0.45),
                       ("cmu/60_10_scaled.bvh", 1.0), ("cmu/02_03.bvh", 0.01)]:
        src = source_skeleton(read_bvh(mocap_dir / rel))
        assert src.scale == pytest.approx(scale), rel
        assert 0.6 < src.leg_length < 1.05
    # 102_01cc: bones ~9x CMU units and the root translation in yet other units: both detected
    src = source_skeleton(read_bvh(mocap_dir / "cmu/102_01cc.bvh"))
    assert 8 < src.root_translation_scale / src.scale < 12
    pelvis_h = np.median(src.positions[:, 0, 1])
    assert 0.8 * src.leg_length < pelvis_h < 1.3 * src.leg_length


def test_wrong_frame_time_of_makehuman_files_corrected(mocap_dir: Path) -> None:
    m = load_motion(mocap_dir / "cmu/02_03.bvh")
    assert m.fps == 120.0
    assert read_bvh(mocap_dir / "cmu/02_03.bvh").fps == 25.0


def test_writer_round_trip_is_lossless(mocap_dir: Path, tmp_path: Path) -> None:
    m = load_motion(mocap_dir / "bandai/dataset-1_kick_normal_001.bvh")
    out = tmp_path / "kick.bvh"
    write_bvh(out, m.poses, m.body, m.fps)
    b = read_bvh(out)
    assert is_native(b)
    m2 = load_motion(out)
    assert m2.fps == m.fps and m2.n_frames == m.n_frames
    np.testing.assert_allclose(m2.body.offsets, m.body.offsets, atol=1e-6)
    np.testing.assert_allclose(m2.poses[:, :3], m.poses[:, :3], atol=1e-4)
    r1 = rotvec_to_matrix(m.poses[:, 3:].reshape(m.n_frames, -1, 3))
    r2 = rotvec_to_matrix(m2.poses[:, 3:].reshape(m.n_frames, -1, 3))
    np.testing.assert_allclose(r2, r1, atol=1e-4)
    np.testing.assert_allclose(fk(m2.poses, m2.body), fk(m.poses, m.body), atol=1e-4)
    # and a second generation is identical text
    out2 = tmp_path / "kick2.bvh"
    write_bvh(out2, m2.poses, m2.body, m2.fps)
    m3 = load_motion(out2)
    np.testing.assert_allclose(fk(m3.poses, m3.body), fk(m.poses, m.body), atol=1e-4)
