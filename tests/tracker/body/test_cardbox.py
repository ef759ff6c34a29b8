"""The cardbox paper's 3D cardbox model (``body/cardbox.py``) and its size initialisation
(``body/cardbox_fit.py``, Algorithm 1)."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.kinematics import fk
from protocol.skeleton import CAPSULE_INDEX, default_body, standing_pose
from tracker_service.body.cardbox import (
    N_PATCHES,
    CardboxModel,
    cardbox_masks_reference,
    cardbox_quads,
    cardbox_sums,
    cardbox_sums_reference,
)
from tracker_service.body.cardbox_fit import FitParams, fit_sizes
from tracker_service.body.raster import render_silhouette
from tracker_service.camera import default_camera
from tracker_service.estimators.likelihood import CardboxLikelihood
from tracker_service.silhouette.features import preprocess

BODY = default_body()
CAM = default_camera()


def test_the_kernel_equals_the_dense_reference(rng: np.random.Generator) -> None:
    poses = np.repeat(standing_pose(BODY)[None], 12, axis=0)
    poses[:, 3:] += rng.normal(0.0, 0.4, size=(12, poses.shape[1] - 3))
    poses[:, :3] += rng.normal(0.0, 0.5, size=(12, 3))
    quads = cardbox_quads(CardboxModel.from_body(BODY), poses, CAM)
    assert quads.shape == (12, N_PATCHES, 4, 2)
    a = rng.normal(size=(CAM.height, CAM.width))
    mark = np.zeros(a.shape, bool)
    np.testing.assert_allclose(cardbox_sums(quads, a, mark), cardbox_sums_reference(quads, a), rtol=0, atol=1e-9)
    assert not mark.any()  # the work buffer is left clean


def test_the_standing_cardbox_covers_the_capsule_silhouette() -> None:
    p = standing_pose(BODY)
    box = cardbox_masks_reference(cardbox_quads(CardboxModel.from_body(BODY), p[None], CAM), (CAM.height, CAM.width))[0]
    cap = render_silhouette(fk(p, BODY), BODY.capsule_radii, CAM)
    assert (box & cap).sum() / (box | cap).sum() > 0.85  # the same body; the cardbox lacks the capsules' round ends
    # two patches per part (three for the abdomen and thorax): a patch seen edge-on adds no area
    assert N_PATCHES == 2 * len(BODY.capsule_radii) + 2


def test_a_patch_behind_the_camera_is_not_drawn() -> None:
    p = standing_pose(BODY)
    p[2] = 10.0  # the camera is 3 m in front of the origin: the person is behind it
    quads = cardbox_quads(CardboxModel.from_body(BODY), p[None], CAM)
    assert np.isnan(quads).all()
    assert cardbox_sums(quads, np.ones((CAM.height, CAM.width)), np.zeros((CAM.height, CAM.width), bool))[0] == 0.0


def test_algorithm_1_fits_the_sizes_to_the_reference_images() -> None:
    """A person broader than the initial guess (torso and head 35 % wider, arms 30 %), seen in two
    known postures: each step of Algorithm 1 lowers the cost and the fitted widths move at least a
    third of the way to the truth (the abdomen's front patch is half hidden by the pelvis's and the
    thorax's)."""
    guess = CardboxModel.from_body(BODY)
    truth_w = guess.widths.copy()
    torso = [CAPSULE_INDEX[n] for n in ("abdomen", "thorax")]
    arms = [CAPSULE_INDEX[n] for n in ("l_upper_arm", "r_upper_arm")]
    truth_w[torso, 0] *= 1.35
    truth_w[arms] *= 1.3
    truth = guess.with_widths(truth_w)
    refs = []
    for arms_up in (0.0, 1.2):
        p = standing_pose(BODY)
        p[3 + 3 * 6 + 2] += arms_up  # the left shoulder raised
        mask = cardbox_masks_reference(cardbox_quads(truth, p[None], CAM), (CAM.height, CAM.width))[0]
        refs.append((preprocess(mask), p))
    fitted, costs = fit_sizes(guess, refs, CAM, np.random.default_rng(0), FitParams(hypotheses=20, rounds=3),
                              groups=["torso and head, front view", "arms"])
    assert costs["arms"] <= costs["torso and head, front view"] < costs["initial"]
    for parts, k in ((torso, 0), (arms, 0)):
        before = np.abs(guess.widths[parts, k] - truth_w[parts, k]).mean()
        after = np.abs(fitted.widths[parts, k] - truth_w[parts, k]).mean()
        assert after < 0.7 * before
    lik = CardboxLikelihood(fitted, CAM, level=1)
    assert lik(refs[0][1][None], refs[0][0]).distance[0] < CardboxLikelihood(guess, CAM, 1)(
        refs[0][1][None], refs[0][0]).distance[0]


def test_sizes_are_checked() -> None:
    with pytest.raises(ValueError, match="widths"):
        CardboxModel(BODY, np.zeros((3, 2, 2)))
    guess = CardboxModel.from_body(BODY)
    same, costs = fit_sizes(guess, [], CAM, np.random.default_rng(0))
    assert same is guess and costs == {}
