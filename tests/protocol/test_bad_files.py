"""Bad gesture scripts and BVH files raise the module's error naming the file, before any large
allocation or endless loop."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from protocol.formats.bvh import BvhError, read_bvh, write_bvh
from protocol.formats.gesture_script import ScriptError, load_script, parse_script
from protocol.motion import Motion, load_bvh_motion, resample
from protocol.skeleton import default_body, standing_pose

SCRIPT = """
fps = 30
{extra}
[[key]]
t = {t}
joints.l_shoulder = [0, 0, 40]
"""


def _bvh(frame_time: str = "0.033333", root: str = "0 90 0") -> str:
    return ("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition "
            "Zrotation Xrotation Yrotation\n End Site\n {\n  OFFSET 0 10 0\n }\n}\nMOTION\nFrames: 2\n"
            f"Frame Time: {frame_time}\n0 90 0 0 0 0\n{root} 0 0 0\n")


def test_script_huge_duration(tmp_path: Path) -> None:
    f = tmp_path / "long.toml"
    f.write_text(SCRIPT.format(extra="duration = 1e9", t=1.0))
    with pytest.raises(ScriptError, match=r"long\.toml.*duration.*1 hour"):
        load_script(f)


def test_script_huge_key_time(tmp_path: Path) -> None:
    f = tmp_path / "late.toml"
    f.write_text(SCRIPT.format(extra="", t="1e9"))
    with pytest.raises(ScriptError, match=r"late\.toml.*key 1.*1 hour"):
        load_script(f)


def test_script_hour_is_fine() -> None:
    s = parse_script(SCRIPT.format(extra="duration = 3600", t=1.0), "ok.toml")
    assert s.duration == 3600


@pytest.mark.parametrize("ft", ["1e-300", "1e-5", "11", "1e300"])
def test_bvh_absurd_frame_time(tmp_path: Path, ft: str) -> None:
    f = tmp_path / "fast.bvh"
    f.write_text(_bvh(frame_time=ft))
    with pytest.raises(BvhError, match=r"fast\.bvh:\d+: Frame Time .* outside"):
        read_bvh(f)


def test_bvh_sane_frame_time(tmp_path: Path) -> None:
    f = tmp_path / "ok.bvh"
    f.write_text(_bvh(frame_time="0.0083333"))
    assert read_bvh(f).n_frames == 2


@pytest.mark.parametrize("root", ["1e308 90 0", "0 -2e4 0"])
def test_bvh_absurd_root_position(tmp_path: Path, root: str) -> None:
    f = tmp_path / "far.bvh"
    f.write_text(_bvh(root=root))
    with pytest.raises(BvhError, match=r"far\.bvh:\d+: absurd value .* Hips"):
        read_bvh(f)


def test_bvh_absurd_rotation(tmp_path: Path) -> None:
    f = tmp_path / "spin.bvh"
    f.write_text(_bvh().replace("0 90 0 0 0 0\n0 90 0 0 0 0", "0 90 0 0 0 0\n0 90 0 1e300 0 0"))
    with pytest.raises(BvhError, match=r"spin\.bvh:\d+: absurd value .* Zrotation"):
        read_bvh(f)


def test_bvh_overflowing_number(tmp_path: Path) -> None:
    f = tmp_path / "inf.bvh"
    f.write_text(_bvh(root="1e999 90 0"))
    with pytest.raises(BvhError, match=r"inf\.bvh"):
        read_bvh(f)


def test_motion_fps_bounds(tmp_path: Path) -> None:
    body = default_body()
    m = Motion(poses=np.repeat(standing_pose(body)[None], 3, axis=0), fps=30.0, body=body)
    with pytest.raises(ValueError, match="fps"):
        resample(m, 1e300)
    with pytest.raises(ValueError, match="fps"):
        Motion(poses=m.poses, fps=1e300)
    f = tmp_path / "native.bvh"
    write_bvh(f, m.poses, body, 30.0)
    with pytest.raises(ValueError, match=r"native\.bvh.*source_fps"):
        load_bvh_motion(f, source_fps=1e300)
