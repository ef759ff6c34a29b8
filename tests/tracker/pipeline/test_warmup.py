"""The warm-up clip drives the pipeline through every phase, and a signal cuts it short."""

import numpy as np

from tracker_service.cues.shoes import ShoeParams, band_pixels, learn_shoes
from tracker_service.cues.skin import SkinModel, observe_skin
from tracker_service.estimators.tree_filter.model import FilterParams
from tracker_service.pipeline.process import TrackerConfig, new_state, process_frame
from tracker_service.pipeline.warmup import warm_up, warm_up_frames
from tracker_service.templates.database import load_db


def test_the_warm_up_reaches_tracking_with_every_cue(small_db) -> None:  # type: ignore[no-untyped-def]
    loaded = load_db(small_db[4], verify=False)
    cfg = TrackerConfig(distance="xor", background_frames=4, init_frames=2, body_candidates=("mSA", "mMA"))
    frames = warm_up_frames(loaded.db, loaded.body, loaded.camera, cfg, tracking_frames=2)
    assert len(frames) == 4 + 2 + 2 + 1
    assert all(f.shape == (loaded.camera.height, loaded.camera.width, 3) and f.dtype == np.uint8 for f in frames)
    # the person's colours switch the skin and shoe cues on
    st = new_state(loaded.body)
    for i, f in enumerate(frames[:6]):
        st, res = process_frame(st, f, loaded.db, loaded.body, loaded.camera, cfg, i / 30)
    assert res.silhouette is not None and res.silhouette.sum() > 500
    skin = observe_skin(frames[-1], res.silhouette, SkinModel())
    assert skin.mask.sum() > 50 and 0.0 < skin.fraction < FilterParams().skin_max_fraction  # head and hands
    assert learn_shoes(*band_pixels(frames[-1], res.silhouette, ShoeParams()), ShoeParams()) is not None
    out = warm_up(loaded.db, loaded.body, loaded.camera, cfg, tracking_frames=2)
    assert out.phase == "tracking" and out.frames == len(frames) and out.seconds > 0


def test_a_stop_request_ends_the_warm_up(small_db) -> None:  # type: ignore[no-untyped-def]
    loaded = load_db(small_db[4], verify=False)
    cfg = TrackerConfig(distance="xor", background_frames=4, init_frames=2)
    calls: list[int] = []

    def stop() -> bool:
        calls.append(1)
        return len(calls) > 3

    out = warm_up(loaded.db, loaded.body, loaded.camera, cfg, should_stop=stop)
    assert out.frames == 3 and out.phase == "learning"


def test_a_daemon_stopped_while_warming_up_opens_no_session(small_db, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    import threading

    from tracker_service.app import daemon as tracker_app

    loaded = load_db(small_db[4], verify=False)

    class Source:
        closed = False

        def __iter__(self):  # type: ignore[no-untyped-def]
            raise AssertionError("no frame is read after a stop during the warm-up")

        def close(self) -> None:
            Source.closed = True

    def no_session(*a, **kw):  # type: ignore[no-untyped-def]
        raise AssertionError("the session opened after a stop during the warm-up")

    monkeypatch.setattr(tracker_app, "open_session", no_session)
    stop = threading.Event()
    stop.set()
    cfg = TrackerConfig(distance="xor", background_frames=4, init_frames=2)
    out = tracker_app.run_tracker(Source(), loaded, cfg, None, tracker_app.RunOptions(), stop)  # type: ignore[arg-type]
    assert out["frames_in"] == 0 and Source.closed


def test_a_file_source_is_played_at_its_own_frame_rate(small_db) -> None:  # type: ignore[no-untyped-def]
    """The daemon paces a file or synthetic source by its frames' time stamps: 24 frames stamped at
    60 Hz take 23/60 s (0.38 s), not the 0.77 s of the 30 Hz fallback."""
    import threading
    import time

    import numpy as np

    from tracker_service.app import daemon as tracker_app

    loaded = load_db(small_db[4], verify=False)
    cam = loaded.camera
    blank = np.full((cam.height, cam.width, 3), 120, np.uint8)

    class Pub:
        matching_status = False  # no viewer: no previews

        def put(self, payload: bytes) -> None:
            pass

    cfg = TrackerConfig(distance="xor", background_frames=30, init_frames=2)  # learning the room throughout
    run = tracker_app._Run("pace", loaded, cfg, tracker_app.RunOptions(realtime=True))
    t0 = time.monotonic()
    run.track([(k / 60.0, blank) for k in range(24)], Pub(), Pub(), Pub(), threading.Event())  # type: ignore[arg-type]
    elapsed = time.monotonic() - t0
    assert 23 / 60 - 0.02 <= elapsed < 0.65
