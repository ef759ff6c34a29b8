"""What the tracker commands load or make once and cache: the template database (``out/db``) and the
appearance cue's network (``out/appearance``), and the gesture scripts the database adds.

The heavy imports (database building, rendering, PyTorch) happen inside the functions.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tracker_service.app.gesture_files import gesture_scripts, scripts_digest
from tracker_service.app.options import BuildDbOptions, TrackerOptions, TrainAppearanceOptions
from tracker_service.paths import REPO_ROOT

if TYPE_CHECKING:
    from tracker_service.camera import Camera

__all__ = [
    "DEFAULT_BODY",
    "DEFAULT_SCRIPT",
    "DEFAULT_SCRIPT_DIRS",
    "build_database",
    "default_script_dirs",
    "ensure_appearance",
    "ensure_db",
    "requested_camera",
    "resolve_db",
]

log = logging.getLogger(__name__)

#: Motion of ``--source synthetic`` without a file: a shipped gesture script.
DEFAULT_SCRIPT = REPO_ROOT / "protocol" / "scripts" / "crouch.toml"
#: Gesture scripts added to the default database: motions the recordings lack (crouch, side-steps,
#: the game's gestures and near-misses). Data files only: the tracker does not import the game.
DEFAULT_SCRIPT_DIRS = (REPO_ROOT / "protocol" / "scripts", REPO_ROOT / "game_client" / "scripts")
#: Body model of the default database.
DEFAULT_BODY = "mMA"


def default_script_dirs() -> tuple[str, ...]:
    """:data:`DEFAULT_SCRIPT_DIRS` as strings (the folders build-db and train-appearance use
    without ``--scripts`` / ``--no-scripts``)."""
    return tuple(str(d) for d in DEFAULT_SCRIPT_DIRS)


def build_database(body_name: str, out: Path, options: BuildDbOptions, camera: Camera | None = None
                   ) -> dict[str, Any]:
    """Build the template database of one body model into ``out`` (recordings, gesture scripts and
    limits from ``options``) for ``camera`` (None: the default camera); returns its build metadata
    (``stats``, ``takes``, ``scripts``, ``build_s``)."""
    from tracker_service.body.family import body_model
    from tracker_service.build.database import DbBuildConfig, build_filter_db, is_held_out, training_motions
    from tracker_service.camera import default_camera
    from tracker_service.templates.database import save_db

    if options.mocap:
        os.environ["MOCAP_DATA"] = options.mocap
    from protocol.formats.mocap_data import index_entries

    body = body_model(body_name).body
    entries = [e for i, e in enumerate(index_entries()) if not is_held_out(i)]
    if options.takes:
        entries = entries[:options.takes]
    script_files = gesture_scripts(options.scripts)
    t0 = time.perf_counter()
    motions = training_motions(body, entries, scripts=script_files, progress=True)
    cam = camera or default_camera()
    db, stats = build_filter_db(motions, body, cam, DbBuildConfig(max_poses=options.max_poses), progress=True)
    meta = {"stats": stats, "takes": [e.path for e in entries], "scripts": [str(s) for s in script_files],
            "build_s": time.perf_counter() - t0,
            # what a cached default database is checked against (_stale_reason)
            "options": {"takes": options.takes, "max_poses": options.max_poses,
                        "script_dirs": [_dir_name(d) for d in options.scripts]},
            "scripts_digest": scripts_digest(options.scripts)}
    save_db(out, db, body, cam, meta)
    return meta


def _dir_name(d: str | Path) -> str:
    """A script folder as the manifest records it: relative to the repository when inside it."""
    p = Path(d).resolve()
    try:
        return p.relative_to(REPO_ROOT.resolve()).as_posix()
    except ValueError:
        return str(p)


def _build_meta(p: Path) -> dict[str, Any]:
    """The ``meta`` of the manifest at ``p`` (empty when unreadable)."""
    import json

    try:
        meta = json.loads((p / "manifest.json").read_text()).get("meta")
    except (OSError, ValueError, AttributeError):
        return {}
    return meta if isinstance(meta, dict) else {}


def _stale_reason(p: Path) -> str | None:
    """Why the cached database at ``p`` no longer matches the bundled gesture scripts it was built
    from (None: it does, it was built from other folders, or it has no readable manifest).

    A database built from :data:`DEFAULT_SCRIPT_DIRS` records their digest
    (:func:`~tracker_service.app.gesture_files.scripts_digest`); one built before digests were
    recorded is compared by the scripts' names.
    """
    return _stale(_build_meta(p))


def _stale(meta: dict[str, Any]) -> str | None:
    """:func:`_stale_reason` of a manifest's ``meta``."""
    default_dirs = [_dir_name(d) for d in DEFAULT_SCRIPT_DIRS]
    if "scripts_digest" in meta:
        dirs = (meta.get("options") or {}).get("script_dirs")
        if sorted(dirs or []) != sorted(default_dirs) or meta["scripts_digest"] == scripts_digest(
                default_script_dirs()):
            return None
        return "the bundled gesture scripts changed since it was built"

    def where(f: str | Path) -> str:  # a script by its folder's last two names (checkouts move)
        return "/".join(Path(f).parts[-3:])

    default_tails = {"/".join(Path(d).parts[-2:]) for d in DEFAULT_SCRIPT_DIRS}
    recorded = {where(f) for f in meta.get("scripts") or []}
    if not recorded or not all(r.rsplit("/", 1)[0] in default_tails for r in recorded):
        return None
    current = {where(f) for f in gesture_scripts(default_script_dirs(), quiet=True)}
    if recorded == current:
        return None
    return f"it was built from {len(recorded)} bundled gesture scripts, the package now has {len(current)}"


def _refresh_if_stale(p: Path, body: str, build_if_missing: bool, camera: Camera | None = None) -> None:
    """Rebuild the cached database at ``p`` (built from the bundled scripts) when they have changed,
    with the options it was built with; without ``build_if_missing`` only warn."""
    meta = _build_meta(p)
    reason = _stale(meta)
    if reason is None:
        return
    if not build_if_missing:
        log.warning("the database at %s is out of date (%s); rebuild it with: mocap-tracker build-db", p, reason)
        return
    opts = meta.get("options") or {}
    log.warning("the database at %s is out of date (%s); rebuilding it (a few minutes, cached)", p, reason)
    build_database(body, p, BuildDbOptions(bodies=(body,), scripts=default_script_dirs(), takes=opts.get("takes"),
                                           max_poses=opts.get("max_poses")), camera=camera)


def requested_camera(tracker: TrackerOptions) -> Camera | None:
    """The camera ``--camera FILE`` or the shorthands (``--camera-height``, ``--camera-tilt``,
    ``--fov``) ask for; None when none is given (the default camera and database, unchanged).

    Raises
    ------
    tracker_service.camera.CameraFileError
        The camera file cannot be used.
    """
    from tracker_service.camera import DEFAULT_HEIGHT_M, load_camera_file, placed_camera

    if tracker.camera_file is not None:
        return load_camera_file(tracker.camera_file)
    if tracker.camera_height_m is None and tracker.camera_tilt_deg is None and tracker.fov_deg is None:
        return None
    return placed_camera(height_m=DEFAULT_HEIGHT_M if tracker.camera_height_m is None else tracker.camera_height_m,
                         tilt_deg=tracker.camera_tilt_deg or 0.0, hfov_deg=tracker.fov_deg)


def resolve_db(path: str | None, camera: Camera, body: str = DEFAULT_BODY, build_if_missing: bool = True,
               build_options: BuildDbOptions | None = None) -> Path:
    """The database folder to track ``camera``'s frames with, built first when needed.

    The frames are brought to the database's working size by
    :func:`tracker_service.sources.frame_source.fit_frame`, so ``camera`` is compared at that size
    (:meth:`~tracker_service.camera.Camera.fitted`): the same camera up to a uniform scale reuses
    the database. Otherwise the database rendered for it, ``out/db/<body>-cam<digest>``, is used,
    and built there when missing (``build_options``: what to build it from; default the same as
    the default database).

    Parameters
    ----------
    path : str, optional
        ``--db`` (None: ``out/db/<body>``, built on first use).
    camera : Camera
        The requested camera, at its own image size.

    Raises
    ------
    tracker_service.templates.database.DatabaseError
        ``--db`` unreadable, or no database for the camera and ``build_if_missing`` false.
    """
    from tracker_service.camera import default_camera, same_camera
    from tracker_service.templates.database import DatabaseError, camera_db_dir, db_camera, default_db_dir

    base = Path(path) if path else default_db_dir(body)
    try:
        base_cam, body = db_camera(base)
    except DatabaseError:
        if path or (base / "manifest.json").exists():
            raise
        base_cam = default_camera()  # what the default database, once built, is rendered for
    work = camera.fitted(base_cam.size)
    if camera.size != base_cam.size:
        how = ("scaled" if camera.width * base_cam.height == camera.height * base_cam.width
               else "scaled and centre-cropped")
        log.info("the camera's %dx%d frames are %s to the database's working size %dx%d",
                 camera.width, camera.height, how, base_cam.width, base_cam.height)
    if not path and (base / "manifest.json").exists():
        _refresh_if_stale(base, body, build_if_missing, camera=base_cam)
    if same_camera(work, base_cam):
        log.info("the camera matches the database's (%s): using %s", base_cam.summary(), base)
        if not (base / "manifest.json").exists():
            ensure_db(None, body, build_if_missing)
        return base
    target = camera_db_dir(body, work)
    try:
        if same_camera(db_camera(target)[0], work):
            _refresh_if_stale(target, body, build_if_missing, camera=work)
            log.info("using the database rendered for this camera (%s) at %s", work.summary(), target)
            return target
    except DatabaseError:
        pass
    if not build_if_missing:
        raise DatabaseError(f"the database at {base} was rendered for camera {base_cam.summary()}; none for camera "
                            f"{work.summary()} at {target} yet")
    log.warning("the database at %s was rendered for camera %s; building one for camera %s at %s (a few "
                "minutes, cached)", base, base_cam.summary(), work.summary(), target)
    build_database(body, target, build_options or BuildDbOptions(bodies=(body,), scripts=default_script_dirs()),
                   camera=work)
    return target


def ensure_db(path: str | None, body: str = DEFAULT_BODY, build_if_missing: bool = True,
              camera: Camera | None = None, build_options: BuildDbOptions | None = None) -> Any:
    """Load a database, building the default one first when it is missing; with ``camera``, the
    database rendered for that camera (:func:`resolve_db`)."""
    from tracker_service.templates.database import DatabaseError, default_db_dir, load_db

    if camera is not None:
        return load_db(resolve_db(path, camera, body, build_if_missing, build_options))
    p = Path(path) if path else default_db_dir(body)
    if not path and (p / "manifest.json").exists():
        _refresh_if_stale(p, body, build_if_missing)
    try:
        return load_db(p)
    except DatabaseError as exc:
        if path or not build_if_missing or (p / "manifest.json").exists():
            raise
        log.warning("%s; building it now (a few minutes, cached for next time)", exc)
        build_database(body, p, BuildDbOptions(bodies=(body,), scripts=default_script_dirs()))
        return load_db(p)


def ensure_appearance(spec: str | None, train_if_missing: bool) -> Any:
    """The appearance network ``spec`` names (a path, ``off``, or None for the default: the network
    shipped in the package, else ``out/appearance/net.npz``).

    A missing default file is trained first when ``train_if_missing`` (some minutes, cached), else
    the cue is off with a warning; a named file that cannot be read, or a corrupt default one,
    raises :class:`tracker_service.cues.appearance.AppearanceError`.
    """
    from tracker_service.cues.appearance import default_appearance_path, load_appearance, shipped_appearance_path

    if spec == "off":
        return None
    # default: the network shipped in the package, else the one train-appearance made
    p = Path(spec) if spec else (shipped_appearance_path() or default_appearance_path())
    if spec or p.exists():
        net = load_appearance(p)
        if not net.members:
            log.warning("the appearance network %s is one network; the tracker's defaults are tuned for the "
                        "ensemble of two that mocap-tracker train-appearance makes (docs/TRACKER.md)", p)
        return net
    if not train_if_missing:
        log.warning("no appearance network at %s: the appearance cue is off (train it once with: "
                    "mocap-tracker train-appearance)", p)
        return None
    log.warning("no appearance network at %s; training it now (some minutes, cached for next time)", p)
    from tracker_service.app.appearance_training import train_appearance

    train_appearance(p, TrainAppearanceOptions(jobs=os.cpu_count() or 1, scripts=default_script_dirs()))
    return load_appearance(p)
