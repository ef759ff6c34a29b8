"""Fast capsule silhouettes: numba kernels vs the numpy references, runs, batches, part labels and
their depth order."""

from __future__ import annotations

import numpy as np
import pytest

from protocol.formats.load import load_motion
from protocol.formats.mocap_data import mocap_root
from protocol.kinematics import fk
from protocol.rotations import matrix_to_rotvec, rotvec_to_matrix
from protocol.skeleton import CAPSULE_JOINTS, CAPSULE_PART, N_PARTS, PARTS, standing_pose
from tracker_service.body.family import body_model
from tracker_service.body.raster import (
    project_capsules,
    render_labels,
    render_labels_reference,
    render_labels_with_areas,
    render_silhouette,
    render_silhouette_cv2,
    render_silhouette_reference,
    render_silhouettes,
    silhouette_runs,
    silhouette_runs_batch,
)
from tracker_service.camera import default_camera
from tracker_service.silhouette.distance import mask_to_runs

CAM = default_camera()


def _yawed(poses: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    p = np.array(poses, copy=True)
    ry = rotvec_to_matrix(np.stack([np.zeros_like(yaw), yaw, np.zeros_like(yaw)], axis=1))
    p[:, 3:6] = matrix_to_rotvec(ry @ rotvec_to_matrix(p[:, 3:6]))
    return p


@pytest.fixture(scope="module")
def database_joints() -> tuple[np.ndarray, np.ndarray]:
    """60 recorded poses (kick, dance) on mMA, centred, random headings: joints and radii."""
    body = body_model("mMA").body
    rng = np.random.default_rng(7)
    poses = np.concatenate([load_motion(mocap_root() / f, body=body).poses for f in
                            ("bandai/dataset-1_kick_normal_001.bvh", "bandai/dataset-1_dance-short_normal_001.bvh")])
    poses = poses[rng.choice(len(poses), 60, replace=False)]
    poses[:, [0, 2]] = 0.0
    poses = _yawed(poses, rng.uniform(-np.pi, np.pi, len(poses)))
    return fk(poses, body), body.capsule_radii


def test_kernel_matches_the_dense_reference_exactly(database_joints: tuple[np.ndarray, np.ndarray]) -> None:
    joints, radii = database_joints
    for j in joints[:25]:
        fast = render_silhouette(j, radii, CAM)
        ref = render_silhouette_reference(j, radii, CAM)
        assert fast.dtype == np.bool_ and fast.shape == (240, 320)
        assert np.array_equal(fast, ref)
        assert 1500 < fast.sum() < 12000


def test_opencv_polygons_agree(database_joints: tuple[np.ndarray, np.ndarray]) -> None:
    joints, radii = database_joints
    for j in joints[:10]:
        a, b = render_silhouette(j, radii, CAM), render_silhouette_cv2(j, radii, CAM)
        assert (a & b).sum() / (a | b).sum() > 0.95


def test_batch_and_runs_agree_with_single_masks(database_joints: tuple[np.ndarray, np.ndarray]) -> None:
    joints, radii = database_joints
    masks = render_silhouettes(joints, radii, CAM)
    data, ptr = silhouette_runs_batch(joints, radii, CAM)
    assert masks.shape == (len(joints), 240, 320) and ptr.shape == (len(joints) + 1,)
    for k in range(len(joints)):
        m = render_silhouette(joints[k], radii, CAM)
        assert np.array_equal(masks[k], m)
        runs = mask_to_runs(m)
        assert np.array_equal(silhouette_runs(joints[k], radii, CAM), runs)
        assert np.array_equal(data[ptr[k]:ptr[k + 1]], runs)
    # capsule end points work as input too, and a reused buffer is cleared
    ends = joints[0][CAPSULE_JOINTS]
    out = np.ones((240, 320), bool)
    assert np.array_equal(render_silhouette(ends, radii, CAM, out=out), masks[0])


def test_labels_match_reference_and_counts(database_joints: tuple[np.ndarray, np.ndarray]) -> None:
    joints, radii = database_joints
    for j in joints[:12]:
        labels, counts = render_labels(j, radii, CAM)
        ref_l, ref_c = render_labels_reference(j, radii, CAM)
        assert labels.dtype == np.int8 and counts.shape == (N_PARTS,)
        assert np.array_equal(labels, ref_l) and np.array_equal(counts, ref_c)
        mask = render_silhouette(j, radii, CAM)
        assert np.array_equal(labels >= 0, mask)
        _, vis, area = render_labels_with_areas(j, radii, CAM)
        assert np.array_equal(vis, counts)
        assert np.all(area >= vis) and counts.sum() == mask.sum()


def test_batch_run_and_area_kernels_equal_the_dense_reference(database_joints: tuple[np.ndarray, np.ndarray]
                                                              ) -> None:
    """The batch fill, the run kernels and the label kernel's areas, each against the dense reference
    directly: runs are the reference mask's runs, a part's area is the reference silhouette of its
    capsules alone."""
    joints, radii = database_joints
    sub = joints[25:33]
    refs = [render_silhouette_reference(j, radii, CAM) for j in sub]
    np.testing.assert_array_equal(render_silhouettes(sub, radii, CAM), np.stack(refs))
    data, ptr = silhouette_runs_batch(sub, radii, CAM)
    for k, (j, ref) in enumerate(zip(sub, refs, strict=True)):
        runs = mask_to_runs(ref)
        assert len(runs) > 50
        np.testing.assert_array_equal(silhouette_runs(j, radii, CAM), runs)
        np.testing.assert_array_equal(data[ptr[k]:ptr[k + 1]], runs)
    part = np.asarray(CAPSULE_PART)
    for j in sub[:3]:
        ends = j[CAPSULE_JOINTS]
        _, _, area = render_labels_with_areas(j, radii, CAM)
        want = [int(render_silhouette_reference(ends[part == p], radii[part == p], CAM).sum()) if np.any(part == p)
                else 0 for p in range(N_PARTS)]
        np.testing.assert_array_equal(area, want)
        assert (area > 0).sum() > N_PARTS // 2


def _side_view(yaw_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    body = body_model("mMA").body
    pose = standing_pose(body)
    pose[4] = np.radians(yaw_deg)
    return render_labels_with_areas(fk(pose, body), body.capsule_radii, CAM)


def test_labels_follow_depth_order_in_side_views() -> None:
    """Turned +90 deg the person's right side faces the camera: the right arm hides part of the
    torso and the left arm hides behind it; turned -90 deg the other way round."""
    lu, ru = PARTS.index("l_upper_arm"), PARTS.index("r_upper_arm")
    torso = PARTS.index("torso")
    lab_r, vis_r, area_r = _side_view(90.0)
    _, vis_l, area_l = _side_view(-90.0)
    assert vis_r[ru] > 0.7 * area_r[ru] and vis_r[lu] < 0.3 * area_r[lu]  # near arm: only the shoulder hides it
    assert vis_l[lu] > 0.7 * area_l[lu] and vis_l[ru] < 0.3 * area_l[ru]
    assert abs(int(area_r[lu]) - int(area_l[ru])) < 0.1 * area_r[lu]  # occlusion changes visibility, not area
    assert np.sum(lab_r == ru) > 0 and vis_r[torso] < area_r[torso]


def test_labels_are_the_nearest_capsule_along_each_ray(database_joints: tuple[np.ndarray, np.ndarray]) -> None:
    """Ray-cast the capsules (as dense chains of spheres) and check the label is the nearest part
    wherever the nearest two parts are clearly separated in depth."""
    joints, radii = database_joints
    rays = CAM.pixel_rays()
    origin = CAM.position
    checked = agree = 0
    for j in joints[:8]:
        labels, _ = render_labels(j, radii, CAM)
        ii, jj = np.nonzero(labels >= 0)
        sel = np.arange(0, len(ii), 7)
        d = rays[ii[sel], jj[sel]]  # (M, 3)
        t = np.linspace(0, 1, 40)
        ends = j[CAPSULE_JOINTS]
        centres = ends[:, None, 0] + t[None, :, None] * (ends[:, None, 1] - ends[:, None, 0])  # (C, T, 3)
        rad = radii[:, None, 0] + t[None, :] * (radii[:, None, 1] - radii[:, None, 0])
        oc = centres - origin
        b = np.einsum("mk,ctk->mct", d, oc)
        disc = b * b - (np.sum(oc * oc, axis=-1) - rad * rad)[None]
        hit = np.where(disc >= 0, b - np.sqrt(np.maximum(disc, 0)), np.inf).min(axis=2)  # (M, C)
        part_depth = np.full((len(sel), N_PARTS), np.inf)
        for c, p in enumerate(CAPSULE_PART):
            part_depth[:, p] = np.minimum(part_depth[:, p], hit[:, c])
        order = np.sort(part_depth, axis=1)
        clear = (order[:, 1] - order[:, 0] > 0.03) & np.isfinite(order[:, 0])
        checked += clear.sum()
        agree += (np.argmin(part_depth, axis=1) == labels[ii[sel], jj[sel]])[clear].sum()
    assert checked > 500
    assert agree / checked > 0.97


def test_capsules_behind_the_camera_are_skipped() -> None:
    body = body_model("mMA").body
    pose = standing_pose(body)
    pose[2] = 3.5  # the person stands behind the camera
    caps = project_capsules(fk(pose, body), body.capsule_radii, CAM)
    assert caps.shape == (18, 10) and np.all(caps[:, 2] < 0)
    assert not render_silhouette(fk(pose, body), body.capsule_radii, CAM).any()
    labels, counts = render_labels(fk(pose, body), body.capsule_radii, CAM)
    assert (labels < 0).all() and counts.sum() == 0
    assert len(silhouette_runs(fk(pose, body), body.capsule_radii, CAM)) == 0


def test_shapes_are_checked() -> None:
    with pytest.raises(ValueError):
        render_silhouette(np.zeros((5, 3)), np.ones((18, 2)), CAM)
    body = body_model("mMA").body
    with pytest.raises(ValueError):
        render_silhouettes(fk(standing_pose(body), body), body.capsule_radii, CAM)
