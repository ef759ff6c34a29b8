"""Damaged or tampered template databases raise DatabaseError naming the file."""

from __future__ import annotations

import json
import shutil
import zlib
from pathlib import Path

import numpy as np
import pytest

from tracker_service.templates.database import DatabaseError, load_db


@pytest.fixture(scope="module")
def tiny_db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A database of a few synthetic poses (no recordings needed)."""
    from protocol.motion import Motion
    from protocol.skeleton import standing_pose
    from tracker_service.body.family import body_model
    from tracker_service.build.database import DbBuildConfig, build_filter_db
    from tracker_service.camera import default_camera
    from tracker_service.templates.database import save_db

    body = body_model("mMA").body
    rng = np.random.default_rng(0)
    base = standing_pose(body)
    poses = np.repeat(base[None], 12, axis=0)
    poses[:, 3:] += rng.normal(0, 0.15, (12, poses.shape[1] - 3))
    cfg = DbBuildConfig(yaw_offsets_deg=(0.0,), level_thresholds=(0.02, 0.008, 0.004))
    db, stats = build_filter_db([Motion(poses=poses, fps=30.0, body=body)], body, default_camera(), cfg,
                                rng=np.random.default_rng(1))
    return save_db(tmp_path_factory.mktemp("db") / "tiny", db, body, default_camera(), {"stats": stats})


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _tamper(path: Path, name: str, change) -> None:  # type: ignore[no-untyped-def]
    """Change one array and update the manifest's checksum to match."""
    f = path / f"{name}.npy"
    a = np.array(np.load(f))
    change(a)
    np.save(f, a, allow_pickle=False)
    man = json.loads((path / "manifest.json").read_text())
    man["arrays"][name]["crc32"] = zlib.crc32(np.ascontiguousarray(a).tobytes())
    (path / "manifest.json").write_text(json.dumps(man))


def test_tiny_db_loads(tiny_db: Path) -> None:
    assert load_db(tiny_db).db.n_leaves > 0


def test_damaged_npy_header(tiny_db: Path, tmp_path: Path) -> None:
    p = _copy(tiny_db, tmp_path / "db")
    f = p / "leaf_anc.npy"
    raw = bytearray(f.read_bytes())
    end = raw.index(b"}")
    raw[end] = ord("(")  # an unclosed bracket: tokenize.TokenError inside numpy's header parser
    f.write_bytes(bytes(raw))
    with pytest.raises(DatabaseError, match=r"leaf_anc\.npy"):
        load_db(p)


@pytest.mark.parametrize(("name", "change"), [
    ("tree_child_ptr_0", lambda a: a.__setitem__(-1, a[-1] + 1000)),
    ("leaf_anc", lambda a: a.__setitem__((0, 0), 10**6)),
    ("tree_node_template_1", lambda a: a.__setitem__(0, 10**6)),
    ("tree_template_leaf", lambda a: a.__setitem__(0, -5)),
    ("nbr_idx", lambda a: a.__setitem__((0, 0), 10**6)),
    ("trans_idx", lambda a: a.__setitem__(0, 10**6)),
    ("runs_ptr_2", lambda a: a.__setitem__(1, 10**9)),
])
def test_out_of_range_indices(tiny_db: Path, tmp_path: Path, name: str, change) -> None:  # type: ignore[no-untyped-def]
    p = _copy(tiny_db, tmp_path / "db")
    _tamper(p, name, change)
    with pytest.raises(DatabaseError, match=name):
        load_db(p)
