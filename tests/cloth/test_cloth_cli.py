"""``mocap-cloth simulate`` and the offscreen renderer (EGL)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from cloth_client.app.cli import main
from cloth_client.solver.garment import make_cape
from protocol.skeleton import default_body, standing_pose

REPO = Path(__file__).resolve().parents[2]
CROUCH = REPO / "protocol" / "scripts" / "crouch.toml"


@pytest.mark.parametrize("garment", ["cape", "skirt"])
def test_simulate_script_json(garment: str, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["simulate", "--script", str(CROUCH), "--garment", garment, "--particles", "400", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0
    for key in ("steps_per_s", "particles", "realtime_factor", "max_penetration_mm", "mean_penetration_mm",
                "max_strain", "energy_drift", "nan"):
        assert key in out, key
    assert out["nan"] is False and out["garment"] == garment
    assert abs(out["particles"] - 400) < 80
    assert out["frames"] == 73 and out["sim_time_s"] == pytest.approx(72 / 30, abs=1e-6)
    assert out["steps_per_s"] > 0 and out["realtime_factor"] > 0
    assert out["energy_drift"] < 0.01
    if garment == "cape":
        assert out["max_penetration_mm"] < 10.0 and out["max_strain"] < 0.10
    # (a deep crouch brings the thighs up under the skirt's waistband: see docs/CLOTH.md, limitations)


def test_simulate_renders_a_gif(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gif = tmp_path / "cape.gif"
    rc = main(["simulate", "--script", str(CROUCH), "--particles", "300", "--max-frames", "12", "--video", str(gif),
               "--size", "96x80", "--video-fps", "15"])
    assert rc == 0 and gif.stat().st_size > 1000
    assert "video:" in capsys.readouterr().out
    import imageio.v2 as imageio

    frames = imageio.mimread(gif)
    assert 5 <= len(frames) <= 7 and frames[0].shape[:2] == (80, 96)
    from PIL import Image

    with Image.open(gif) as im:  # simulated at 30 Hz, drawn at 15 frames a second: 67 ms each
        assert abs(im.info.get("duration", 0) - 1000 / 15) <= 10  # GIF times are in 10 ms steps


def test_bad_input_exits_nonzero(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "--bvh", str(tmp_path / "missing.bvh")]) == 1
    assert "not found" in capsys.readouterr().err
    bad = tmp_path / "bad.bvh"
    bad.write_text("not a bvh\n")
    assert main(["simulate", "--bvh", str(bad)]) == 1
    assert "cannot read" in capsys.readouterr().err
    for argv in (["simulate"], ["simulate", "--script", str(CROUCH), "--garment", "hat"],
                 ["simulate", "--script", str(CROUCH), "--particles", "5"], ["run", "--id", "a/b"]):
        with pytest.raises(SystemExit) as err:
            main(argv)
        assert err.value.code == 2


def test_renderer_draws_avatar_and_cloth(tmp_path: Path) -> None:
    from cloth_client.app.render import ClothRenderer, FrameWriter

    body = default_body()
    g = make_cape(body, 300)
    with ClothRenderer(body, g, 120, 100) as r:
        rgb = r.render(standing_pose(body), g.rest)
    assert rgb.shape == (100, 120, 3) and rgb.dtype == np.uint8
    red = (rgb[..., 0] > 1.6 * rgb[..., 1]) & (rgb[..., 0] > 60)  # the cape's dark red
    skin = (np.abs(rgb.astype(int) - [204, 173, 148]).sum(axis=2) < 90)
    assert red.sum() > 50 and skin.sum() > 50
    for name in ("a.mp4", "frames"):
        with FrameWriter(tmp_path / name, 10) as w:
            for _ in range(3):
                w.write(rgb)
    assert len(list((tmp_path / "frames").glob("frame_*.png"))) == 3
    cap = cv2.VideoCapture(str(tmp_path / "a.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 3
    cap.release()
