"""On-disk template database: a folder of ``.npy`` arrays (memory-mappable) and a ``manifest.json``
that records the format version, every array's shape, dtype and CRC-32, the body model, the camera
and how the database was built.

Loading checks all of it: a missing, truncated, corrupt or stale (older format) database raises
:class:`DatabaseError` whose message says how to rebuild it.
"""

from __future__ import annotations

import ctypes
import json
import tokenize
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from protocol.kinematics import fk
from protocol.skeleton import N_JOINTS, Body
from tracker_service.camera import Camera
from tracker_service.cues.appearance import camera_joints
from tracker_service.cues.skin import leaf_joint_points
from tracker_service.estimators.tree_filter.filter import FilterDB
from tracker_service.paths import out_dir
from tracker_service.silhouette.distance import RunSet
from tracker_service.silhouette.placement import placement_columns, placement_rows
from tracker_service.templates.tree import TemplateTree

__all__ = ["DB_FORMAT", "DB_VERSION", "DatabaseError", "LoadedDatabase", "camera_db_dir", "db_camera", "default_db_dir",
           "load_db", "save_db"]

DB_FORMAT = "mocap-template-db"
#: Bump on any change of the arrays' meaning; older folders are then reported as stale.
DB_VERSION = 2
_REBUILD = "rebuild it with: mocap-tracker build-db --out {path}"


class DatabaseError(RuntimeError):
    """A database folder that cannot be used; the message says why and how to rebuild it."""


def default_db_dir(body: str = "mMA") -> Path:
    """``out/db/<body>`` (:func:`tracker_service.paths.out_dir`): where ``build-db`` writes and
    ``run``/``eval`` look by default."""
    return out_dir() / "db" / body


def camera_db_dir(body: str, camera: Camera) -> Path:
    """``out/db/<body>-cam<digest>``: where the database of ``body`` rendered for ``camera`` (a camera
    other than the default one, :meth:`tracker_service.camera.Camera.digest`) is cached."""
    return out_dir() / "db" / f"{body}-cam{camera.digest()}"


def db_camera(path: str | Path) -> tuple[Camera, str]:
    """The camera a database was rendered for and its body model's name, from its manifest alone
    (cheap: no template arrays are read or checked).

    Raises
    ------
    DatabaseError
        No readable manifest, or one without a usable camera.
    """
    p = Path(path)
    hint = _REBUILD.format(path=p)
    mpath = p / "manifest.json"
    if not mpath.is_file():
        raise DatabaseError(f"no template database at {p} (manifest.json missing); {hint}")
    try:
        man = json.loads(mpath.read_text())
        if man.get("format") != DB_FORMAT or man.get("version") != DB_VERSION:
            raise DatabaseError(f"{p} is not a template database of format v{DB_VERSION}; {hint}")
        pose = np.load(p / "camera_pose.npy", allow_pickle=False)
        cam = Camera(**man["camera"] | {"pose": np.array(pose), "dist": np.array(man["camera"]["dist"])})
        return cam, str(man["body"]["name"])
    except DatabaseError:
        raise
    except (OSError, KeyError, TypeError, ValueError) as e:
        raise DatabaseError(f"cannot read the camera of the template database at {p} ({e}); {hint}") from None


@dataclass(frozen=True)
class LoadedDatabase:
    """A database read back from disk.

    Attributes
    ----------
    db : FilterDB
    body : Body
        The body model the templates were rendered with.
    camera : Camera
        The full-resolution camera of the templates.
    meta : dict
        Build configuration and statistics (``manifest.json`` ``meta``).
    path : Path
    """

    db: FilterDB
    body: Body
    camera: Camera
    meta: dict[str, Any]
    path: Path


def _arrays(db: FilterDB, body: Body, camera: Camera) -> dict[str, NDArray[Any]]:
    out: dict[str, NDArray[Any]] = {}
    t = db.tree
    for lvl in range(t.n_levels):
        out[f"tree_node_template_{lvl}"] = t.node_template[lvl]
        out[f"tree_node_parent_{lvl}"] = t.node_parent[lvl]
        out[f"tree_child_ptr_{lvl}"] = t.child_ptr[lvl]
        out[f"runs_data_{lvl}"] = db.level_runs[lvl].data
        out[f"runs_ptr_{lvl}"] = db.level_runs[lvl].ptr
    out["tree_template_leaf"] = t.template_leaf
    for name in ("leaf_poses", "leaf_visible", "leaf_anc", "leaf_heading", "trans_ptr", "trans_idx", "trans_p",
                 "nbr_idx", "nbr_dpart", "sigma_part"):
        out[name] = np.asarray(getattr(db, name))
    out["body_offsets"] = body.offsets
    out["body_capsule_radii"] = body.capsule_radii
    out["camera_pose"] = camera.pose
    return out


def save_db(path: str | Path, db: FilterDB, body: Body, camera: Camera, meta: dict[str, Any]) -> Path:
    """Write a database folder (replacing an existing one atomically enough: manifest last).

    Parameters
    ----------
    path : str or Path
        Folder to create.
    db : FilterDB
    body : Body
    camera : Camera
    meta : dict
        JSON-serialisable build information.

    Returns
    -------
    Path
    """
    p = Path(path)
    p.mkdir(parents=True, exist_ok=True)
    manifest_path = p / "manifest.json"
    if manifest_path.exists():
        manifest_path.unlink()  # an interrupted write leaves no valid manifest behind
    entries = {}
    for name, arr in _arrays(db, body, camera).items():
        a = np.ascontiguousarray(arr)
        np.save(p / f"{name}.npy", a, allow_pickle=False)
        entries[name] = {"shape": list(a.shape), "dtype": a.dtype.str, "crc32": zlib.crc32(a.tobytes())}
    manifest = {
        "format": DB_FORMAT, "version": DB_VERSION, "arrays": entries,
        "n_levels": db.tree.n_levels, "thresholds": list(db.tree.thresholds),
        "level_scale": list(db.level_scale), "center": list(db.center),
        "body": {"name": body.name, "measurements": body.measurements},
        "camera": {k: v for k, v in asdict(camera).items() if k not in ("pose", "dist")}
        | {"dist": [float(x) for x in camera.dist]},
        # the same camera in OpenCV's terms (the camera file's format) and the digest that names
        # out/db/<body>-cam<digest>: for people reading the manifest; loading uses "camera" above
        "camera_opencv": camera.to_opencv(),
        "camera_digest": camera.digest(),
        "meta": meta,
    }
    manifest_path.write_text(json.dumps(manifest, indent=1, default=float))
    return p


def _check_indices(p: Path, arrays: dict[str, NDArray[Any]], n_levels: int, hint: str) -> None:
    """Every index array within the bounds of what it indexes (a tampered database whose checksums
    were recomputed must not reach the filter's unchecked indexing)."""

    def fail(name: str, what: str) -> None:
        raise DatabaseError(f"{p / (name + '.npy')}: {what}; {hint}")

    def in_range(name: str, lo: int, hi: int) -> None:
        a = arrays[name]
        if a.dtype.kind not in "iu":
            fail(name, f"index array has dtype {a.dtype}, expected integers")
        if a.size and (int(a.min()) < lo or int(a.max()) >= hi):
            fail(name, f"indices out of range [{lo}, {hi}) (found {int(a.min())}..{int(a.max())})")

    def csr(name: str, n_rows: int, n_items: int) -> None:
        a = arrays[name]
        if a.dtype.kind not in "iu":
            fail(name, f"pointer array has dtype {a.dtype}, expected integers")
        if a.ndim != 1 or len(a) != n_rows + 1:
            fail(name, f"pointer array has shape {a.shape}, expected ({n_rows + 1},)")
        if int(a[0]) != 0 or int(a[-1]) != n_items or (len(a) > 1 and bool(np.any(np.diff(a) < 0))):
            fail(name, f"pointers must rise from 0 to {n_items}")

    if n_levels < 1:
        raise DatabaseError(f"inconsistent template database at {p} (n_levels = {n_levels}); {hint}")
    sizes = [len(arrays[f"tree_node_template_{lvl}"]) for lvl in range(n_levels)]
    n_templates = len(arrays["tree_template_leaf"])
    n_leaves = sizes[-1]
    for lvl in range(n_levels):
        in_range(f"tree_node_template_{lvl}", 0, n_templates)
        parent = f"tree_node_parent_{lvl}"
        if len(arrays[parent]) != sizes[lvl]:
            fail(parent, f"{len(arrays[parent])} entries for {sizes[lvl]} nodes")
        if lvl == 0:
            in_range(parent, -1, 0)
        else:
            in_range(parent, 0, sizes[lvl - 1])
        ptr = f"tree_child_ptr_{lvl}"
        if lvl < n_levels - 1:
            csr(ptr, sizes[lvl], sizes[lvl + 1])
        elif arrays[ptr].size:
            fail(ptr, "the leaf level must have no child pointers")
        csr(f"runs_ptr_{lvl}", sizes[lvl], len(arrays[f"runs_data_{lvl}"]))
    in_range("tree_template_leaf", 0, n_leaves)
    for name in ("leaf_poses", "leaf_visible", "leaf_heading", "nbr_idx", "nbr_dpart"):
        if len(arrays[name]) != n_leaves:
            fail(name, f"{len(arrays[name])} rows for {n_leaves} leaves")
    anc = arrays["leaf_anc"]
    if anc.shape != (n_levels, n_leaves):
        fail("leaf_anc", f"shape {anc.shape}, expected ({n_levels}, {n_leaves})")
    if anc.dtype.kind not in "iu":
        fail("leaf_anc", f"index array has dtype {anc.dtype}, expected integers")
    for lvl in range(n_levels):
        row = anc[lvl]
        if row.size and (int(row.min()) < 0 or int(row.max()) >= sizes[lvl]):
            fail("leaf_anc", f"level {lvl} ancestors out of range [0, {sizes[lvl]})")
    csr("trans_ptr", n_leaves, len(arrays["trans_idx"]))
    in_range("trans_idx", 0, n_leaves)
    if len(arrays["trans_p"]) != len(arrays["trans_idx"]):
        fail("trans_p", f"{len(arrays['trans_p'])} entries for {len(arrays['trans_idx'])} transitions")
    in_range("nbr_idx", 0, n_leaves)


def load_db(path: str | Path, verify: bool = True, mmap: bool = True) -> LoadedDatabase:
    """Read and check a database folder.

    Parameters
    ----------
    path : str or Path
    verify : bool
        Check every array's CRC-32 (reads everything once; ~0.1 s per 100 MB).
    mmap : bool
        Memory-map the arrays instead of reading them.

    Raises
    ------
    DatabaseError
        Missing, truncated, corrupt or stale database (with a rebuild hint).
    """
    p = Path(path)
    hint = _REBUILD.format(path=p)
    mpath = p / "manifest.json"
    if not mpath.is_file():
        raise DatabaseError(f"no template database at {p} (manifest.json missing); {hint}")
    try:
        man = json.loads(mpath.read_text())
    except (OSError, ValueError) as e:
        raise DatabaseError(f"corrupt manifest {mpath}: {e}; {hint}") from None
    if man.get("format") != DB_FORMAT:
        raise DatabaseError(f"{p} is not a template database; {hint}")
    if man.get("version") != DB_VERSION:
        raise DatabaseError(f"stale template database at {p} (format v{man.get('version')}, this program "
                            f"needs v{DB_VERSION}); {hint}")
    arrays: dict[str, NDArray[Any]] = {}
    try:
        for name, info in man["arrays"].items():
            f = p / f"{name}.npy"
            try:
                a = np.load(f, mmap_mode="r" if mmap else None, allow_pickle=False)
            except (OSError, ValueError, EOFError, SyntaxError, tokenize.TokenError) as e:
                raise DatabaseError(f"cannot read {f} (truncated or corrupt: {e}); {hint}") from None
            if list(a.shape) != info["shape"] or a.dtype.str != info["dtype"]:
                raise DatabaseError(f"{f} has shape {a.shape} {a.dtype.str}, manifest says {info['shape']} "
                                    f"{info['dtype']}; {hint}")
            if verify and zlib.crc32(np.ascontiguousarray(a).tobytes()) != info["crc32"]:
                raise DatabaseError(f"{f} is corrupt (checksum mismatch); {hint}")
            arrays[name] = np.asarray(a)  # plain ndarray view of the mapping: no np.memmap overhead per index
        n_levels = int(man["n_levels"])
        _check_indices(p, arrays, n_levels, hint)
        tree = TemplateTree(
            node_template=[arrays[f"tree_node_template_{lvl}"] for lvl in range(n_levels)],
            node_parent=[arrays[f"tree_node_parent_{lvl}"] for lvl in range(n_levels)],
            child_ptr=[arrays[f"tree_child_ptr_{lvl}"] for lvl in range(n_levels)],
            template_leaf=arrays["tree_template_leaf"], thresholds=tuple(man["thresholds"]),
        )
        runs = tuple(RunSet(data=arrays[f"runs_data_{lvl}"], ptr=arrays[f"runs_ptr_{lvl}"]) for lvl in range(n_levels))
        body = Body(name=man["body"]["name"], offsets=np.array(arrays["body_offsets"]),
                    capsule_radii=np.array(arrays["body_capsule_radii"]), measurements=man["body"]["measurements"])
        cam = Camera(**man["camera"] | {"pose": np.array(arrays["camera_pose"]),
                                        "dist": np.array(man["camera"]["dist"])})
        level_scale = tuple(float(v) for v in man["level_scale"])
        level_column, ref_column = placement_columns(runs, level_scale, cam)
        level_bottom, level_top, ref_bottom = placement_rows(runs, level_scale, cam)
        leaf_points, leaf_joints3d = _leaf_joint_tables(arrays["leaf_poses"], body, cam)
        db = FilterDB(tree=tree, level_runs=runs, level_scale=level_scale,
                      center=(float(man["center"][0]), float(man["center"][1])),
                      **{k: arrays[k] for k in ("leaf_poses", "leaf_visible", "leaf_anc", "leaf_heading", "trans_ptr",
                                                "trans_idx", "trans_p", "nbr_idx", "nbr_dpart", "sigma_part")},
                      level_column=level_column, ref_column=ref_column,
                      level_bottom=level_bottom, level_top=level_top, ref_bottom=ref_bottom,
                      leaf_points=leaf_points, leaf_joints3d=leaf_joints3d)
    except DatabaseError:
        raise
    except (KeyError, TypeError, ValueError) as e:
        raise DatabaseError(f"inconsistent template database at {p} ({type(e).__name__}: {e}); {hint}") from None
    _return_freed_memory()
    return LoadedDatabase(db=db, body=body, camera=cam, meta=dict(man.get("meta", {})), path=p)


def _leaf_joint_tables(leaf_poses: NDArray[np.floating], body: Body, camera: Camera, chunk: int = 4096
                       ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The leaves' joints for the skin and appearance cues, derived once at load: image points
    :func:`~tracker_service.cues.skin.leaf_joint_points` ``(NL, J, 2)`` and camera-axis joints
    :func:`~tracker_service.cues.appearance.camera_joints` ``(NL, J, 3)``, both float32. The forward
    kinematics run ``chunk`` leaves at a time: on the whole database at once its float64 rotations
    alone took ~250 MB at the load's peak."""
    n = len(leaf_poses)
    points = np.empty((n, N_JOINTS, 2), np.float32)
    joints3d = np.empty((n, N_JOINTS, 3), np.float32)
    for a in range(0, n, chunk):
        j = fk(np.asarray(leaf_poses[a: a + chunk], np.float64), body)
        points[a: a + chunk] = leaf_joint_points(j, camera)
        joints3d[a: a + chunk] = camera_joints(j, camera, body.height)
    return points, joints3d


def _return_freed_memory() -> None:
    """Give the memory the load's temporaries freed back to the system (glibc's ``malloc_trim``; it
    otherwise stays in the process: ~30 MB here). A no-op on other C libraries."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
