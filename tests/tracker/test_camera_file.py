"""Camera files in OpenCV's terms: the conversion against cv2.projectPoints, bad files, the shorthands."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from tracker_service.app import cli
from tracker_service.camera import (
    Camera,
    CameraFileError,
    default_camera,
    load_camera_file,
    look_at,
    placed_camera,
    same_camera,
    save_camera_file,
)


def _points(rng: np.random.Generator) -> np.ndarray:
    return rng.uniform([-1.0, 0.0, -0.8], [1.0, 2.0, 0.8], (200, 3))  # where the person is


CAMERAS = {
    "default": default_camera(),
    "tilted, off-axis, 640x480": default_camera(640, 480).moved(look_at((0.7, 2.1, 2.6), (0.1, 0.8, 0.0))),
    "rolled": default_camera().moved(look_at((0.0, 1.5, 3.0), (0.0, 1.0, 0.0), up=(0.2, 1.0, 0.0))),
    "radial": Camera(320, 240, 270.0, 268.0, 161.2, 118.3, pose=look_at((0.3, 1.4, 3.2), (0, 1, 0)),
                     dist=(-0.21, 0.07)),
    "full": Camera(640, 480, 530.0, 528.0, 322.0, 241.0, pose=look_at((-0.4, 1.3, 2.9), (0, 0.9, 0)),
                   dist=(-0.18, 0.05, 0.002, -0.0015, -0.01)),
}


@pytest.mark.parametrize("name", list(CAMERAS))
def test_opencv_projection_equals_camera_projection(name: str, tmp_path: Path) -> None:
    cam = CAMERAS[name]
    pts = _points(np.random.default_rng(7))
    d = cam.to_opencv()
    rvec, _ = cv2.Rodrigues(np.array(d["rotation"]))
    uv_cv, _ = cv2.projectPoints(pts, rvec, np.array(d["translation"]), np.array(d["camera_matrix"]),
                                 np.array(d["dist_coeffs"]))
    np.testing.assert_allclose(uv_cv.reshape(-1, 2), cam.project(pts), atol=1e-6)
    # and back, through a file
    back = load_camera_file(save_camera_file(cam, tmp_path / "camera.json"))
    np.testing.assert_allclose(back.project(pts), cam.project(pts), atol=1e-6)
    assert back.size == cam.size and back.digest() == cam.digest()
    # OpenCV's axes: the optical axis is R's third row, image down is minus world up for a level camera
    r = np.array(d["rotation"])
    np.testing.assert_allclose(r[2], -cam.pose[:3, 2], atol=1e-12)


def test_opencv_axes_of_the_default_camera_written_out() -> None:
    d = default_camera().to_opencv()
    assert d["image_size"] == [320, 240]
    np.testing.assert_allclose(d["camera_matrix"], [[262.5, 0, 159.5], [0, 262.5, 119.5], [0, 0, 1]])
    # OpenCV: x right = world +X, y down = world -Y, z forward = world -Z; t = -R C with C = (0, 1.2, 3)
    np.testing.assert_allclose(d["rotation"], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    np.testing.assert_allclose(d["translation"], [0.0, 1.2, 3.0], atol=1e-12)
    assert d["dist_coeffs"] == [0.0] * 5
    cam = Camera.from_opencv(d)
    np.testing.assert_allclose(cam.pose, default_camera().pose, atol=1e-12)
    assert cam.dist.shape == (2,)  # zero tangential terms: stored as (k1, k2)
    rvec = Camera.from_opencv(d | {"rotation": cv2.Rodrigues(np.array(d["rotation"]))[0].ravel().tolist()})
    np.testing.assert_allclose(rvec.pose, cam.pose, atol=1e-9)


GOOD = default_camera().to_opencv()


@pytest.mark.parametrize(("change", "message"), [
    ({"rotation": None}, "missing key(s) rotation"),
    ({"camera_matrix": [[262.5, 0, 159.5], [0, 262.5, 119.5]]}, "camera_matrix must have shape [3, 3]"),
    ({"camera_matrix": [[float("nan"), 0, 159.5], [0, 262.5, 119.5], [0, 0, 1]]}, "non-finite"),
    ({"camera_matrix": [[262.5, 3, 159.5], [0, 262.5, 119.5], [0, 0, 1]]}, "no skew"),
    ({"camera_matrix": [[-262.5, 0, 159.5], [0, 262.5, 119.5], [0, 0, 1]]}, "must be positive"),
    ({"rotation": [[1, 0, 0], [0, 1, 0.1], [0, 0, 1]]}, "not orthonormal"),
    ({"rotation": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}, "reflection"),
    ({"rotation": [[1, 0], [0, 1]]}, "rotation must be a 3x3"),
    ({"translation": [0, 1.2]}, "translation must be [tx, ty, tz]"),
    ({"translation": [0, "x", 3]}, "translation must be numbers"),
    ({"translation": [0, float("inf"), 3]}, "non-finite"),
    ({"dist_coeffs": [0.1, 0.2, 0.3]}, "dist_coeffs must have 4 or 5 values"),
    ({"dist_coeffs": [0, 0, 0, 0, 0, 0.1, 0, 0]}, "only the distortion model"),
    ({"image_size": [320.5, 240]}, "two positive integers"),
])
def test_bad_camera_files_give_one_line_errors(change: dict, message: str, tmp_path: Path) -> None:
    data = {k: v for k, v in (GOOD | change).items() if v is not None}
    f = tmp_path / "camera.json"
    f.write_text(json.dumps(data))
    with pytest.raises(CameraFileError) as exc:
        load_camera_file(f)
    assert message in str(exc.value) and str(f) in str(exc.value) and "\n" not in str(exc.value)


def test_unreadable_camera_files(tmp_path: Path) -> None:
    with pytest.raises(CameraFileError, match="no such file"):
        load_camera_file(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(CameraFileError, match="not valid JSON"):
        load_camera_file(tmp_path / "bad.json")
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(CameraFileError, match="expected a JSON object"):
        load_camera_file(tmp_path / "list.json")


@pytest.mark.parametrize("command", [["run"], ["eval", "--script", "x.toml"]])
def test_cli_rejects_a_bad_camera_file_with_status_2(command: list[str], tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "camera.json"
    f.write_text(json.dumps(GOOD | {"rotation": [[1, 0, 0], [0, 2, 0], [0, 0, 1]]}))
    with pytest.raises(SystemExit) as exc:
        cli.main([*command, "--camera", str(f)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith(f"camera file {f}: rotation is not orthonormal (|R^T R - I| = 3)")
    with pytest.raises(SystemExit) as exc:
        cli.main([*command, "--camera", str(tmp_path / "camera.json"), "--fov", "70"])
    assert exc.value.code == 2
    assert "drop --fov" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        cli.main([*command, "--camera-tilt", "95"])
    assert exc.value.code == 2


def test_camera_options_reach_the_tracker_options(tmp_path: Path) -> None:
    f = save_camera_file(default_camera(640, 480), tmp_path / "camera.json")
    parser = cli.build_parser()
    run = cli._BY_NAME["run"]
    opts = run.options_from_args(parser.parse_args(["run", "--camera", str(f)]))
    assert opts.tracker.camera_file == str(f) and opts.tracker.fov_deg is None
    opts = run.options_from_args(parser.parse_args(["run", "--camera-height", "1.6", "--camera-tilt", "12",
                                                    "--fov", "75"]))
    t = opts.tracker
    assert (t.camera_file, t.camera_height_m, t.camera_tilt_deg, t.fov_deg) == (None, 1.6, 12.0, 75.0)
    plain = run.options_from_args(parser.parse_args(["run"])).tracker
    assert (plain.camera_file, plain.camera_height_m, plain.camera_tilt_deg, plain.fov_deg) == (None,) * 4
    from tracker_service.app.resources import requested_camera

    assert requested_camera(plain) is None  # the default path stays as it was
    cam = requested_camera(t)
    assert cam is not None
    assert cam.height_m == pytest.approx(1.6) and cam.tilt_deg == pytest.approx(12.0)
    assert cam.hfov_deg == pytest.approx(75.0, abs=1e-9)


def test_shorthands_build_the_expected_camera() -> None:
    assert same_camera(placed_camera(), default_camera(), tol_px=1e-9)
    np.testing.assert_allclose(placed_camera().pose, default_camera().pose)
    cam = placed_camera(height_m=1.5, tilt_deg=15.0, hfov_deg=70.0)
    assert cam.size == (320, 240) and cam.fx == cam.fy
    assert cam.fx == pytest.approx(160.0 / np.tan(np.radians(35.0)))
    assert cam.height_m == pytest.approx(1.5) and cam.tilt_deg == pytest.approx(15.0)
    assert cam.hfov_deg == pytest.approx(70.0) and cam.roll_deg == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(cam.position, [0.0, 1.5, 3.0])
    # looking down 15 degrees: the floor point straight ahead at depth 1.5 / tan(15) is the image centre
    np.testing.assert_allclose(cam.project([0.0, 0.0, 3.0 - 1.5 / np.tan(np.radians(15.0))]), [159.5, 119.5],
                               atol=1e-9)
    assert default_camera().hfov_deg == pytest.approx(62.72, abs=0.01)
    for bad in ({"height_m": 0.0}, {"tilt_deg": 85.0}, {"hfov_deg": 179.0}):
        with pytest.raises(ValueError):
            placed_camera(**bad)  # type: ignore[arg-type]


def test_fitted_camera_is_the_camera_of_fit_frame() -> None:
    from tracker_service.sources.frame_source import fit_frame

    assert same_camera(default_camera(640, 480).fitted((320, 240)), default_camera(), tol_px=1e-9)
    wide = Camera(1280, 720, 900.0, 900.0, 639.5, 359.5, pose=default_camera().pose)
    fitted = wide.fitted((320, 240))
    # a dot drawn at a projected point lands where the fitted camera projects it
    p = np.array([0.35, 1.6, 0.0])
    u, v = wide.project(p)
    img = np.zeros((720, 1280, 3), np.uint8)
    cv2.circle(img, (round(u * 16), round(v * 16)), 6 * 16, (255, 255, 255), -1, cv2.LINE_AA, 4)
    small = fit_frame(img, (320, 240))[..., 0].astype(np.float64)
    yy, xx = np.mgrid[0:240, 0:320]
    centroid = np.array([(xx * small).sum(), (yy * small).sum()]) / small.sum()
    np.testing.assert_allclose(centroid, fitted.project(p), atol=0.05)
    assert fitted.fx == pytest.approx(900.0 / 3) and fitted.size == (320, 240)  # the centre 960 x 720, a third
