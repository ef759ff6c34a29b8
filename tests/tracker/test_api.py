"""The public API: the README's example runs as written and tracks the built-in scene."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[2] / "README.md"


def _readme_example() -> str:
    text = README.read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    found = [b for b in blocks if "from tracker_service import Tracker" in b]
    assert found, "README.md has no Python example importing Tracker"
    return found[0]


def test_the_readme_example_is_short() -> None:
    assert len(_readme_example().strip().splitlines()) <= 15


@pytest.mark.slow
def test_the_readme_example_runs_and_tracks(small_db, capsys: pytest.CaptureFixture[str],
                                            monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[no-untyped-def]
    """The example as written, on the test database: it prints poses near the scene's person."""
    import tracker_service.api as api

    db_dir = small_db[-1]
    real = api.ensure_db
    monkeypatch.setattr(api, "ensure_db", lambda path, *a, **k: real(str(db_dir)))
    exec(compile(_readme_example(), "README.md", "exec"), {})
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("t=")]
    assert len(lines) >= 20
    pelvis = np.array([[float(x) for x in re.search(r"\[(.*?)\]", ln).group(1).split()] for ln in lines])  # type: ignore[union-attr]
    assert np.all(np.abs(pelvis[:, 0]) < 1.0) and np.all((pelvis[:, 1] > 0.5) & (pelvis[:, 1] < 1.3))


def test_tracker_is_exported_lazily() -> None:
    import subprocess
    import sys

    code = "import sys, tracker_service; assert 'numpy' not in sys.modules; print(tracker_service.Tracker.__name__)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "Tracker"
