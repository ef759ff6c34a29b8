"""The per-frame pipeline: observe (:mod:`.observe`) -> estimate (an estimator of
:mod:`tracker_service.estimators`) -> publish (:mod:`.publish`), as a pure state machine with its
phases (:mod:`.process`, configuration in :mod:`.config`); body selection, pose refinement,
smoothing and the warm-up beside it."""
