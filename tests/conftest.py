"""Shared fixtures: the shared recordings (read from ../shared/mocap or $MOCAP_DATA), seeded RNGs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from protocol.mocap_data import IndexEntry, index_entries, mocap_root


@pytest.fixture(scope="session")
def mocap_dir() -> Path:
    return mocap_root()


@pytest.fixture(scope="session")
def mocap_index() -> list[IndexEntry]:
    return index_entries()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)
