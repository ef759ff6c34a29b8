"""Shared fixtures: the shared recordings (read from ../shared/mocap or $MOCAP_DATA), seeded RNGs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from protocol.formats.mocap_data import IndexEntry, index_entries, mocap_root


@pytest.fixture(scope="session")
def mocap_dir() -> Path:
    return mocap_root()


@pytest.fixture(scope="session")
def mocap_index() -> list[IndexEntry]:
    return index_entries()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


TAKES = ("dataset-2_raise-up-both-hands_normal_001.bvh", "dataset-2_raise-up-both-hands_active_062.bvh",
         "dataset-2_raise-up-right-hand_normal_001.bvh", "dataset-1_bye_normal_001.bvh")


@pytest.fixture(scope="session")
def small_db(mocap_index: list[IndexEntry], tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """A small template database (4 real takes, body mMA) saved to a temporary folder:
    ``(FilterDB, Body, motions, stats, path)``."""
    from tracker_service.body.family import body_model
    from tracker_service.build.database import DbBuildConfig, build_filter_db, training_motions
    from tracker_service.camera import default_camera
    from tracker_service.templates.database import save_db

    body = body_model("mMA").body
    entries = [e for e in mocap_index if e.path.split("/")[-1] in TAKES]
    motions = training_motions(body, entries)
    cfg = DbBuildConfig(yaw_offsets_deg=(0.0,), level_thresholds=(0.02, 0.008, 0.004))
    db, stats = build_filter_db(motions, body, default_camera(), cfg, rng=np.random.default_rng(1))
    path = save_db(tmp_path_factory.mktemp("db") / "mMA", db, body, default_camera(), {"stats": stats})
    return db, body, motions, stats, path


def constant_reading_net(mu: np.ndarray, log_var: float = -6.0, size: int = 16):  # type: ignore[no-untyped-def]
    """An appearance network (:class:`tracker_service.cues.appearance.AppearanceNet`) that reads ``mu``
    (``(J, 3)``, camera axes over the height) with log variance ``log_var`` whatever it sees: one
    convolution, then a dense layer that ignores it and answers its bias."""
    from protocol.skeleton import N_JOINTS
    from tracker_service.cues.appearance import AppearanceNet, Layer

    conv = Layer("conv", np.full((2, 4, 3, 3), 0.01, np.float32), np.zeros(2, np.float32), 2, True, True)
    bias = np.concatenate([np.asarray(mu).ravel(), np.full(N_JOINTS * 3, log_var)]).astype(np.float32)
    dense = Layer("dense", np.zeros((2 * N_JOINTS * 3, 2 * (size // 4) ** 2), np.float32), bias, 1, False, False)
    return AppearanceNet(size, (conv, dense), {"fixture": "constant"})


@pytest.fixture(scope="session")
def weak_appearance_net(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An appearance network file (:mod:`tracker_service.cues.appearance`) that always sees a person
    standing in the T-pose, with a wide variance (:func:`constant_reading_net`): the cue's whole
    path runs without the half hour of rendering and training a real network needs."""
    from dataclasses import replace

    from protocol import fk
    from protocol.skeleton import POSE_SIZE
    from tracker_service.body.family import body_model
    from tracker_service.camera import default_camera
    from tracker_service.cues.appearance import camera_joints, save_appearance

    body = body_model("mMA").body
    mu = camera_joints(fk(np.zeros(POSE_SIZE), body), default_camera(), body.height)
    net = constant_reading_net(mu, 0.0)
    return save_appearance(tmp_path_factory.mktemp("appearance") / "net.npz",
                           replace(net, meta={"fixture": "standing"}))
