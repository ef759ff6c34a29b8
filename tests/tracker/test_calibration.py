"""Checkerboard calibration on boards rendered with a known camera's projection."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from tracker_service.app import cli
from tracker_service.calibration import CalibrationError, calibrate_checkerboard, parse_pattern
from tracker_service.camera import Camera, load_camera_file, placed_camera

PATTERN, SQUARE = (9, 6), 0.1


def _rot(yaw: float, pitch: float) -> np.ndarray:
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    return np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]]) @ np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])


def render_board(cam: Camera, r_bw: np.ndarray, centre: np.ndarray, ss: int = 8) -> np.ndarray:
    """A grey image of the board (inner corners PATTERN, white margin) whose centre is at world
    ``centre`` with its axes ``r_bw`` (columns: board x, y, normal in world), drawn at ``ss`` times
    the size with cv2.fillPoly at the projected corners and area-averaged down (anti-aliased)."""
    cols, rows = PATTERN
    t = centre - r_bw @ np.array([(cols - 1) * SQUARE / 2, (rows - 1) * SQUARE / 2, 0.0])
    img = np.full((cam.height * ss, cam.width * ss), 110, np.uint8)

    def quad(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
        b = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], float)
        uv = (cam.project(b @ r_bw.T + t) + 0.5) * ss - 0.5
        assert np.all(np.isfinite(uv))
        return np.round(uv * 16).astype(np.int32)

    s = SQUARE
    cv2.fillPoly(img, [quad(-1.6 * s, -1.6 * s, (cols + 0.6) * s, (rows + 0.6) * s)], 235, cv2.LINE_8, 4)
    for a in range(-1, cols):
        for b in range(-1, rows):
            if (a + b) % 2 == 0:
                cv2.fillPoly(img, [quad(a * s, b * s, (a + 1) * s, (b + 1) * s)], 20, cv2.LINE_8, 4)
    return np.asarray(cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA), np.uint8)


@pytest.fixture(scope="module")
def boards(tmp_path_factory: pytest.TempPathFactory) -> tuple[Camera, Path, Path]:
    """A 640x480 camera 1.2 m high looking down 20 degrees; seven held-up board views in a folder and
    one board lying on the floor 2.2 m ahead (0.2 m to the side)."""
    cam = placed_camera(1.2, 20.0, width=640, height=480)
    folder = tmp_path_factory.mktemp("boards")
    facing = np.diag([1.0, -1.0, -1.0])  # board x = world X, y = down, normal away from the camera
    views = [(0, 0, 0, 0, 0), (0.5, 0, -0.3, 0.1, 0.3), (-0.5, 0.1, 0.3, -0.1, 0), (0.2, 0.5, 0.1, 0.2, -0.3),
             (-0.2, -0.5, -0.2, -0.1, 0.2), (0.6, 0.3, 0.3, 0.1, 0.5), (-0.4, -0.4, -0.3, 0.2, 0.6)]
    for k, (yaw, pitch, dx, dy, dz) in enumerate(views):
        centre = np.array([dx, 1.2 - 2.2 * np.tan(np.radians(20.0)) + dy, 0.8 + dz])
        cv2.imwrite(str(folder / f"view{k}.png"), render_board(cam, _rot(yaw, pitch) @ facing, centre))
    cv2.imwrite(str(folder / "notes.png"), np.full((480, 640), 128, np.uint8))  # no board: skipped
    on_floor = np.stack([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]], axis=1)
    floor = tmp_path_factory.mktemp("floor") / "floor.png"
    cv2.imwrite(str(floor), render_board(cam, on_floor, np.array([0.2, 0.0, 0.8])))
    return cam, folder, floor


def test_calibration_recovers_the_camera(boards: tuple[Camera, Path, Path]) -> None:
    cam, folder, floor = boards
    res = calibrate_checkerboard(sorted(folder.glob("*.png")), PATTERN, SQUARE, floor)
    got = res.camera
    assert got.size == (640, 480)
    assert got.fx == pytest.approx(cam.fx, rel=0.01) and got.fy == pytest.approx(cam.fy, rel=0.01)
    assert got.height_m == pytest.approx(1.2, abs=0.02)
    assert got.tilt_deg == pytest.approx(20.0, abs=0.5) and abs(got.roll_deg) < 0.5
    assert res.distance_m == pytest.approx(2.2, abs=0.03)  # the board's centre, straight ahead
    np.testing.assert_allclose(got.position, [0.0, got.height_m, res.distance_m], atol=1e-9)
    assert res.rms_px < 0.2 and res.floor_rms_px is not None and res.floor_rms_px < 0.2
    assert len(res.used) == 8 and res.skipped == (str(folder / "notes.png"),)
    # the calibrated world is the true one moved so that the point on the floor straight ahead at the
    # board's distance, true (0, 0, 0.8), is the origin: points of the person's space project alike
    pts = np.random.default_rng(3).uniform([-0.8, 0.0, 0.3], [0.8, 1.8, 1.3], (50, 3))
    np.testing.assert_allclose(got.project(pts - [0.0, 0.0, 0.8]), cam.project(pts), atol=4.0)  # 0.6 % of 640 px


def test_calibrate_command_writes_the_camera_file(boards: tuple[Camera, Path, Path], tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    cam, folder, floor = boards
    out = tmp_path / "camera.json"
    rc = cli.main(["calibrate", "--checkerboard", "9x6", "--square", "0.1", "--images", str(folder / "view*.png"),
                   "--floor-image", str(floor), "--out", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "height          1.1" in text or "height          1.2" in text
    assert "reprojection    RMS" in text
    loaded = load_camera_file(out)
    assert loaded.height_m == pytest.approx(1.2, abs=0.02) and loaded.fx == pytest.approx(cam.fx, rel=0.01)
    data = json.loads(out.read_text())
    assert {"image_size", "camera_matrix", "dist_coeffs", "rotation", "translation", "reprojection_rms_px"} <= set(data)
    # without a floor image the placement is the one given
    rc = cli.main(["calibrate", "--checkerboard", "9x6", "--square", "0.1", "--images", str(folder),
                   "--camera-height", "1.5", "--camera-tilt", "10", "--out", str(out), "--json"])
    assert rc == 0
    s = json.loads(capsys.readouterr().out)
    assert s["height_m"] == pytest.approx(1.5) and s["tilt_deg"] == pytest.approx(10.0)
    assert s["floor_rms_px"] is None


def test_calibrate_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["calibrate", "--checkerboard", "9by6", "--square", "0.1", "--images", str(tmp_path),
                  "--out", str(tmp_path / "c.json")])
    assert exc.value.code == 2 and "COLSxROWS" in capsys.readouterr().err
    with pytest.raises(CalibrationError, match="square one is ambiguous"):
        parse_pattern("7x7")
    rc = cli.main(["calibrate", "--checkerboard", "9x6", "--square", "0.1", "--images", str(tmp_path),
                   "--out", str(tmp_path / "c.json")])
    assert rc == 1 and "no images found" in capsys.readouterr().err
    for k in range(2):
        cv2.imwrite(str(tmp_path / f"{k}.png"), np.full((48, 64), 128, np.uint8))
    with pytest.raises(CalibrationError, match="found in 0 of 2 images; at least 3"):
        calibrate_checkerboard(sorted(tmp_path.glob("*.png")), PATTERN, SQUARE)
