"""The appearance network ships in the package, loads by default and is the network its card describes."""

from __future__ import annotations

import json

from tracker_service.build.model_card import MODELS_DIR, check_card
from tracker_service.cues.appearance import shipped_appearance_path


def test_the_network_ships_with_its_card() -> None:
    path = shipped_appearance_path()
    assert path is not None and path.parent == MODELS_DIR
    assert path.stat().st_size < 8e6  # small enough to version
    card = json.loads(path.with_suffix(".json").read_text())
    for key in ("sha256", "training_command", "training_data_sha256", "validation", "probe", "version"):
        assert key in card
    assert card["file"] == path.name


def test_the_shipped_network_is_the_one_its_card_measured() -> None:
    """sha256, the outputs on the card's probe input and the validation figures all agree."""
    path = shipped_appearance_path()
    assert path is not None
    card = json.loads(path.with_suffix(".json").read_text())
    assert check_card(card, path) == []
    for member in card["validation"]:  # the validation error the training reported, % of the height
        assert 0 < member["val_rms_z"] < 0.1 and 0 < member["val_rms_x"] < 0.05


def test_the_tracker_loads_it_by_default() -> None:
    from tracker_service.app.resources import ensure_appearance

    net = ensure_appearance(None, train_if_missing=False)
    assert net is not None and len(net.members) + 1 == json.loads(
        shipped_appearance_path().with_suffix(".json").read_text())["members"]  # type: ignore[union-attr]


def test_the_shipped_network_is_not_used_on_a_camera_placement_it_reads_badly() -> None:
    from tracker_service.app.options import TrackerOptions
    from tracker_service.app.tracker_config import tracker_config
    from tracker_service.camera import default_camera, placed_camera
    from tracker_service.cues.appearance import appearance_unfit

    assert appearance_unfit(default_camera()) is None
    assert appearance_unfit(placed_camera(distance_m=4.5, hfov_deg=50.0)) is None  # distance and lens are free
    # the reading is turned into a tilted camera's axes (cues/level_frame.py): within the measured range
    assert appearance_unfit(placed_camera(height_m=1.8, tilt_deg=15.0)) is None
    assert appearance_unfit(placed_camera(height_m=0.6, tilt_deg=-10.0)) is None
    assert appearance_unfit(placed_camera(height_m=1.8, tilt_deg=20.0, hfov_deg=80.0, distance_m=2.5)) is None
    assert "tilted" in (appearance_unfit(placed_camera(height_m=1.3, tilt_deg=30.0)) or "")
    assert "high" in (appearance_unfit(placed_camera(height_m=2.4, tilt_deg=15.0)) or "")
    assert tracker_config(TrackerOptions()).appearance is not None
    assert tracker_config(TrackerOptions(camera_height_m=1.8, camera_tilt_deg=15.0)).appearance is not None
    assert tracker_config(TrackerOptions(camera_height_m=1.2, camera_tilt_deg=35.0)).appearance is None
