"""The tracker's configuration: which silhouette distance, cues, estimator tuning and publishing stages."""

from __future__ import annotations

from dataclasses import dataclass, field

from protocol.skeleton import Body
from tracker_service.body.proportions import ProportionParams
from tracker_service.cues.appearance import AppearanceNet
from tracker_service.cues.reading_filter import ReadingFilterParams
from tracker_service.cues.shoes import ShoeParams
from tracker_service.cues.skin import SkinModel
from tracker_service.estimators.tree_filter.model import FilterParams
from tracker_service.pipeline.floor_contact import FloorParams
from tracker_service.pipeline.refinement import RefineParams
from tracker_service.pipeline.smoothing import OneEuroParams
from tracker_service.silhouette.background import BackgroundParams
from tracker_service.silhouette.features import Distance
from tracker_service.silhouette.ghost import GhostParams

__all__ = ["TrackerConfig"]


@dataclass(frozen=True)
class TrackerConfig:
    """Pipeline options (paper defaults: nwXOR, alpha = 5, beta = 1, m = 5).

    Attributes
    ----------
    distance : {'nwxor', 'cwxor', 'xor'}
    alpha, beta : float
        Weights of eq. 9 and eq. 10.
    occlusion : bool
        Occlusion-aware dynamics (eq. 14, "DM2"); False is "DM1".
    filter : FilterParams
    background : BackgroundParams
    background_frames : int
        Empty frames learned before tracking (0: the caller provides the model).
    background_rate, background_guard_px : float, int
        Adaptive update of the background model (running mean and variance, this rate a frame; 0:
        off) while a person is tracked, everywhere but their silhouette dilated by
        ``background_guard_px`` pixels (its blurred fringe and the shadow at its feet stay out of
        the model); not before (a person standing in a background learned with them would be
        absorbed, and their ghost never seen). Follows changing light and
        exposure drift: the robustness matrix's ``lights`` row 10.54 -> 9.58 cm, ``compression``
        10.63 -> 10.09, ``default`` 9.49 -> 9.49 (without the guard the default row lost 0.48 cm).
    start_radius : float
        Tracking starts when the silhouette's centre is within this fraction of the image width
        from the image centre.
    init_frames : int
        Frames of the initialising phase (body-model selection averages over them).
    body_candidates : tuple of str
        Body models considered by the selection (empty: keep the database's body).
    body : Body or None
        A given body (the user's measurements, :mod:`tracker_service.body.measured`) used from the
        end of the initialisation instead of a selection: templates scaled by its height over the
        database body's, its skeleton in the published joints. Not together with
        ``body_candidates``.
    use_mean_pose : bool
        Publish the posterior-mean pose (tempered, ``FilterParams.mean_temperature``) rather than
        the MAP leaf's pose: on an ambiguous silhouette the mean hedges between the modes.
    depth_from_feet : bool
        Take the subject's depth from the silhouette's feet line (scaled for the body model)
        rather than from the scale of the best template fit.
    skin : SkinModel or None
        Skin colour locus of the hand cue (:mod:`tracker_service.cues.skin`); None: silhouettes only
        (the paper's observation model).
    shoes : ShoeParams or None
        The shoe cue (:mod:`tracker_service.cues.shoes`): the shoes' colour learned while initialising;
        each frame's shoe pixels weigh the leaves in the filter (``FilterParams.shoe_weight``) and
        re-weight the published pose's legs (``ShoeParams.weight``); None: off.
    appearance : AppearanceNet or None
        The appearance cue's network (:mod:`tracker_service.cues.appearance`): the joints' depth read from
        the person's colour image weighs the leaves in the filter (``FilterParams.appearance_weight``);
        None: off.
    appearance_mirror : bool
        Read the person's crop flipped left-right too and pool both readings
        (:func:`tracker_service.cues.appearance.predict_joints`; one batch of two per network of the
        ensemble: it doubles the networks' cost, ~0.8 ms a frame per network).
    refine : RefineParams or None
        With the appearance cue: the published pose's joints are turned toward the network's
        reading, fused with the filter's pose by their variances (:mod:`tracker_service.pipeline.refinement`,
        ELMO's local refinement); None: the filter's pose as it is.
    proportions : ProportionParams or None
        With the appearance cue: after the first frames of tracking, the published skeleton's torso,
        arm and leg bones take the lengths the network reads (:mod:`tracker_service.body.proportions`;
        once per session, ``body_changed`` set; not with a given ``body`` (``--measurements``); only
        from frames where the person is not cut by the image border); None: the selected model's
        proportions. Refinement and proportions use the cue's reading whether or not the filter
        weighs leaves by it (``filter.appearance_weight``); without ``appearance`` both are off.
    reading_filter : ReadingFilterParams or None
        With the refinement: the network's readings are filtered over time by a constant-velocity
        Kalman filter (:mod:`tracker_service.cues.reading_filter`) before the published pose is refined
        toward them (restarted with every tracking session; kept through a re-initialisation);
        None: each frame's raw reading.
    floor : FloorParams or None
        Floor contact (:mod:`tracker_service.pipeline.floor_contact`): a leg whose ankle the
        refinement put through the floor is bent back onto it, hip kept; None: off.
    smoothing : OneEuroParams or None
        One Euro filter of the published pose (:mod:`tracker_service.pipeline.smoothing`); None: the raw
        per-frame estimate.
    fps : float
        Frame rate assumed when :func:`process_frame` is given no time stamp.
    estimator : {'tree', 'condensation', 'drs', 'srs'}
        The pose estimator (:func:`tracker_service.estimators.make_estimator`).
    estimator_seed : int
        The particle filters' random stream (reproducible runs).
    min_confidence : float
        Poses whose confidence (the silhouette match, ``exp(-d^2 / 2c^2)``) is below this are
        withheld: no pose rather than a pose without grounds (0: publish every estimate). 0.01 is
        the confidence of the distance at which the tree filter counts a frame as a miss
        (``FilterParams.lost_distance`` 0.15 at ``confidence_scale`` 0.05).
    relearn_after : int
        After this many consecutive withheld frames the background is learned again, robustly
        (:func:`tracker_service.silhouette.background.learn_background_robust`): a person in view
        when the tracker started was learned into the background (0: never).
    relearn_frames, relearn_every : int
        The robust learning takes every ``relearn_every``-th frame until it has ``relearn_frames``.
    ghost : GhostParams or None
        Ghost detection (:mod:`tracker_service.silhouette.ghost`): a silhouette whose outline lies on
        the background model's edges rather than the frame's is a person learned into the
        background; its pose is withheld, and after ``ghost.frames`` such frames in a row the
        background is learned again, robustly; None: off.
    confirm_frames : int
        After the background is learned, the first pose is published only once this many frames in
        a row gave a pose the checks accept (the ones before are withheld as ``'confirming'``): a
        background with a person in it can pass the ghost test for a frame or two (measured: one
        pose 2.5 m off on a start in view). 1: publish at once.
    estimate_camera : bool
        Measure the camera's tilt and roll from the room's vertical edges when the background is
        first learned, and its height from the person while initialising
        (:mod:`tracker_service.pipeline.camera_estimate`); logged (a warning when it is clearly not
        the given camera) and kept in ``TrackerState.camera_estimate``.
    """

    distance: Distance = "nwxor"
    alpha: float = 5.0
    beta: float = 1.0
    occlusion: bool = True
    filter: FilterParams = field(default_factory=FilterParams)
    background: BackgroundParams = field(default_factory=BackgroundParams)
    background_frames: int = 10
    background_rate: float = 0.02
    background_guard_px: int = 15
    start_radius: float = 0.25
    init_frames: int = 5
    body_candidates: tuple[str, ...] = ()
    body: Body | None = None
    use_mean_pose: bool = True
    depth_from_feet: bool = True
    skin: SkinModel | None = field(default_factory=SkinModel)
    shoes: ShoeParams | None = field(default_factory=ShoeParams)
    appearance: AppearanceNet | None = None
    appearance_mirror: bool = True
    refine: RefineParams | None = field(default_factory=RefineParams)
    proportions: ProportionParams | None = field(default_factory=ProportionParams)
    reading_filter: ReadingFilterParams | None = field(default_factory=ReadingFilterParams)
    floor: FloorParams | None = field(default_factory=FloorParams)
    smoothing: OneEuroParams | None = field(default_factory=OneEuroParams)
    fps: float = 30.0
    min_confidence: float = 0.01
    estimator: str = "tree"
    estimator_seed: int = 0
    relearn_after: int = 45
    relearn_frames: int = 21
    relearn_every: int = 4
    ghost: GhostParams | None = field(default_factory=GhostParams)
    estimate_camera: bool = True
    confirm_frames: int = 5

    def __post_init__(self) -> None:
        if self.body is not None and self.body_candidates:
            raise ValueError("give either a body or body candidates to choose from, not both")
