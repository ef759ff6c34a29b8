"""``bench/bench_cloth.py --param``: solver and driver overrides parsed to their fields' types."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

from cloth_client.solver.cloth import ClothParams
from cloth_client.solver.driver import DriverConfig

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_cloth.py"


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_cloth_under_test", BENCH)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.path.insert(0, str(BENCH.parent))  # the script's folder, as when it is run
    try:
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(BENCH.parent))
    return mod


def test_param_and_config_overrides_are_split_and_typed(bench: ModuleType) -> None:
    over = bench.parse_overrides(["extra_rounds=20", "release_straddles=0", "cfg.slide_fraction=0",
                                  "cfg.keep_seam_length=False"])
    assert over == {"extra_rounds": 20, "release_straddles": False, "cfg.slide_fraction": 0.0,
                    "cfg.keep_seam_length": False}
    assert isinstance(over["cfg.slide_fraction"], float)
    params, config = bench.split_overrides(over)
    assert params == ClothParams(extra_rounds=20, release_straddles=False)
    assert config == DriverConfig(slide_fraction=0.0, keep_seam_length=False)
    assert bench.split_overrides(None) == (ClothParams(), DriverConfig())


@pytest.mark.parametrize("item", ["cfg.bogus=1", "bogus=1", "extra_rounds", "cfg.slide_fraction=x",
                                  "release_straddles=maybe"])
def test_bad_overrides_exit_with_the_field_named(bench: ModuleType, item: str) -> None:
    with pytest.raises(SystemExit, match="--param"):
        bench.parse_overrides([item])
