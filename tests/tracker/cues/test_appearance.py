"""The appearance cue: crop, numpy forward pass (held equal to PyTorch's), leaf scoring, the network
file's checks, its training on a toy problem and on rendered views, and its wiring into the filter."""

from __future__ import annotations

import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import constant_reading_net

from protocol import fk
from protocol.skeleton import JOINT_INDEX, MIRROR_JOINTS, N_JOINTS
from tracker_service.body.family import body_model
from tracker_service.camera import default_camera
from tracker_service.cues.appearance import (
    APPEARANCE_VERSION,
    AppearanceError,
    AppearanceNet,
    Layer,
    camera_joints,
    forward,
    joints_cost,
    load_appearance,
    net_input,
    person_crop,
    predict_joints,
    save_appearance,
)

torch = pytest.importorskip("torch")  # a dev dependency: training needs it, the tracker does not

NOUT = 2 * N_JOINTS * 3


def _random_bn_model(size: int, width: int):  # type: ignore[no-untyped-def]
    from tracker_service.build.appearance_train import _model

    torch.manual_seed(3)
    m = _model(torch, size, width)
    with torch.no_grad():  # batch norms with non-trivial statistics, so that folding them is tested
        for mod in m.modules():
            if isinstance(mod, torch.nn.BatchNorm2d):
                mod.running_mean.uniform_(-0.5, 0.5)
                mod.running_var.uniform_(0.5, 2.0)
                mod.weight.uniform_(0.5, 1.5)
                mod.bias.uniform_(-0.2, 0.2)
    return m.eval()


@pytest.mark.parametrize("size,width", [(32, 4), (64, 8)])
def test_numpy_forward_equals_pytorch(size: int, width: int, rng: np.random.Generator) -> None:
    from tracker_service.build.appearance_train import _batch_input, export_layers

    model = _random_bn_model(size, width)
    net = AppearanceNet(size, export_layers(model), {})
    for _ in range(3):
        crop = rng.integers(0, 256, (size, size, 3), dtype=np.uint8)
        mask = rng.random((size, size)) < 0.6
        x = net_input(crop, mask)
        with torch.no_grad():
            ref = model(torch.from_numpy(x).permute(2, 0, 1)[None]).numpy()[0]
            batch = model(_batch_input(torch, crop[None], mask[None], None)).numpy()[0]
        got = forward(net, x)
        assert got.shape == (NOUT,)
        scale = float(np.abs(ref).max())
        assert np.abs(got - ref).max() <= 1e-5 * max(scale, 1.0)
        assert np.array_equal(batch, ref)  # training feeds the network what inference does


def test_person_crop_centres_and_scales_the_silhouette() -> None:
    frame = np.zeros((240, 320, 3), np.uint8)
    mask = np.zeros((240, 320), bool)
    assert person_crop(frame, mask, 32) is None
    mask[60:160, 140:180] = True  # 100 rows x 40 columns
    frame[mask] = (10, 200, 30)
    crop, cm = person_crop(frame, mask, 64)  # type: ignore[misc]
    assert crop.shape == (64, 64, 3) and crop.dtype == np.uint8 and cm.shape == (64, 64)
    rows, cols = np.flatnonzero(cm.any(axis=1)), np.flatnonzero(cm.any(axis=0))
    # the longer side spans 1 / 1.15 of the crop, centred
    assert abs((rows[-1] - rows[0] + 1) - 64 / 1.15) <= 2
    assert abs(0.5 * (rows[0] + rows[-1]) - 31.5) <= 1 and abs(0.5 * (cols[0] + cols[-1]) - 31.5) <= 1
    inner = cm & np.roll(cm, 1, 0) & np.roll(cm, -1, 0) & np.roll(cm, 1, 1) & np.roll(cm, -1, 1)
    assert inner.sum() > 0.8 * cm.sum() and np.all(crop[inner] == (10, 200, 30))  # the edge pixels are mixed
    x = net_input(crop, cm)
    assert x.shape == (64, 64, 4) and x.dtype == np.float32
    assert np.all(x[~cm, :3] == 0) and np.all(x[..., 3] == cm)


def test_camera_joints_are_pelvis_relative_in_camera_axes_over_height() -> None:
    body = body_model("mMA").body
    cam = default_camera()
    poses = np.zeros((3, 3 + 3 * 19), np.float32)
    poses[:, :3] = [[0.5, 0.9, -1.0], [0.0, 1.0, 0.0], [2.0, 0.8, 1.0]]  # the root's place does not matter
    poses[1, 4] = 0.7  # turned about the vertical
    out = camera_joints(fk(poses, body), cam, body.height)
    assert out.shape == (3, N_JOINTS, 3) and out.dtype == np.float32
    assert np.allclose(out[:, 0], 0)
    assert np.allclose(out[0], out[2], atol=1e-6)
    p = poses[1].astype(np.float64)
    p[:3] = 0
    j = fk(p, body)
    want = (j - j[0]) @ cam.pose[:3, :3] / body.height
    assert np.allclose(out[1], want, atol=1e-6)
    # standing: the head is up (y) about half the height above the pelvis
    assert 0.3 < out[0, JOINT_INDEX["head_top"], 1] < 0.6


def test_joints_cost_is_the_gaussian_negative_log_likelihood(rng: np.random.Generator) -> None:
    mu = rng.normal(0, 0.2, (N_JOINTS, 3))
    var = rng.uniform(0.001, 0.01, (N_JOINTS, 3))
    leaves = (mu[None] + rng.normal(0, 0.05, (5, N_JOINTS, 3))).astype(np.float32)
    leaves[0] = mu
    c = joints_cost(mu, var, leaves)
    want = 0.5 * (((leaves.astype(np.float64) - mu) ** 2) / var).sum(axis=(1, 2))
    assert np.allclose(c, want) and c[0] == pytest.approx(0.0, abs=1e-6) and np.all(c[1:] > 0)
    cz = joints_cost(mu, var, leaves, coords=(2,))
    assert np.allclose(cz, 0.5 * (((leaves[..., 2].astype(np.float64) - mu[:, 2]) ** 2) / var[:, 2]).sum(axis=1))


def test_proposals_are_the_cheapest_leaves_by_joints_cost(rng: np.random.Generator) -> None:
    from tracker_service.cues.appearance import propose_leaves

    leaves = rng.normal(0, 0.2, (500, N_JOINTS, 3)).astype(np.float32)
    mu = leaves[17].astype(np.float64) + rng.normal(0, 0.01, (N_JOINTS, 3))
    var = rng.uniform(0.001, 0.01, (N_JOINTS, 3))
    cost = joints_cost(mu, var, leaves)
    got = propose_leaves(mu, var, leaves, 10)
    assert got.dtype == np.int64 and got[0] == 17
    assert np.array_equal(got, np.argsort(cost)[:10])
    allowed = np.arange(500) % 2 == 0
    got = propose_leaves(mu, var, leaves, 10, allowed)
    assert np.array_equal(got, np.flatnonzero(allowed)[np.argsort(cost[allowed])[:10]])
    assert len(propose_leaves(mu, var, leaves, 10, np.zeros(500, bool))) == 0
    assert len(propose_leaves(mu, var, leaves, 900)) == 500


def test_heading_window_is_an_arc_on_the_circle() -> None:
    from tracker_service.cues.appearance import HeadingWindow

    h = np.radians(np.array([-179.0, -100.0, -60.0, 0.0, 60.0, 100.0, 179.0], np.float32))
    assert HeadingWindow(0.0, np.radians(90)).mask(h).tolist() == [False, False, True, True, True, False, False]
    # across +-180 degrees
    assert HeadingWindow(np.pi, np.radians(30)).mask(h).tolist() == [True, False, False, False, False, False, True]
    assert HeadingWindow(0.0, np.pi, np.radians(70)).mask(h).tolist() == [False, False, True, True, True, False, False]


@pytest.mark.parametrize("centre,half,max_abs", [(0.0, np.pi / 2, np.inf), (2.9, 1.0, np.inf), (-0.4, 1.0, 0.6)])
def test_proposal_kernel_equals_the_numpy_reference(centre: float, half: float, max_abs: float,
                                                    rng: np.random.Generator) -> None:
    from tracker_service.cues._kernels import proposal_cost_kernel
    from tracker_service.cues.appearance import HeadingWindow, propose_leaves, propose_leaves_in_window

    n = 3000
    leaves = rng.normal(0, 0.2, (n, N_JOINTS, 3)).astype(np.float32)
    heading = rng.uniform(-np.pi, np.pi, n).astype(np.float32)
    mu = leaves[5].astype(np.float64) + rng.normal(0, 0.05, (N_JOINTS, 3))
    var = rng.uniform(0.001, 0.01, (N_JOINTS, 3))
    window = HeadingWindow(centre, half, max_abs)
    inside = window.mask(heading)
    assert 0 < inside.sum() < n
    c = proposal_cost_kernel(leaves.reshape(n, -1), (1.0 / var).ravel(), mu.ravel(), heading, centre, half, max_abs)
    assert np.array_equal(np.isfinite(c), inside)
    want = 2.0 * joints_cost(mu, var, leaves) - float((mu * mu / var).sum())  # the same cost without its constant
    assert np.allclose(c[inside], want[inside], rtol=1e-4, atol=1e-3)
    got = propose_leaves_in_window(mu, var, leaves, 32, heading, window)
    assert np.array_equal(got, propose_leaves(mu, var, leaves, 32, inside))
    depth_only = np.where(np.arange(3) == 2, var, np.inf)  # an infinite variance leaves a coordinate out
    want_z = joints_cost(mu, var, leaves, coords=(2,))
    got = propose_leaves_in_window(mu, depth_only, leaves, 8, heading, window)
    assert np.array_equal(got, np.flatnonzero(inside)[np.argsort(want_z[inside])[:8]])
    assert np.array_equal(got, propose_leaves(mu, depth_only, leaves, 8, inside))


def test_proposal_kernel_edge_headings(rng: np.random.Generator) -> None:
    """NaN headings or centres are outside the window (and return: no hang); a centre beyond +-pi
    wraps; headings at exactly +-pi are the same direction."""
    from tracker_service.cues._kernels import proposal_cost_kernel
    from tracker_service.cues.appearance import HeadingWindow

    leaves = rng.normal(0, 0.2, (6, 6)).astype(np.float32)
    heading = np.array([np.pi, -np.pi, 0.0, np.nan, 3.0, -3.0], np.float32)
    inv, mu = np.ones(6), np.zeros(6)
    for centre, half in ((np.pi, 0.5), (-np.pi, 0.5), (7 * np.pi, 0.5), (0.0, 0.5), (1e12, 0.5), (np.nan, 0.5)):
        c = proposal_cost_kernel(leaves, inv, mu, heading, centre, half, np.inf)
        assert np.array_equal(np.isfinite(c), HeadingWindow(centre, half).mask(heading)), centre
    assert not np.isfinite(proposal_cost_kernel(leaves, inv, mu, heading, np.nan, 0.5, np.inf)).any()
    assert np.isfinite(proposal_cost_kernel(leaves, inv, mu, heading, np.pi, 0.5, np.inf)[[0, 1, 4, 5]]).all()


def test_predict_joints_reads_the_network(rng: np.random.Generator) -> None:
    mu = rng.normal(0, 0.2, (N_JOINTS, 3))
    net = constant_reading_net(mu, log_var=-5.0)
    frame = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    mask = np.zeros((240, 320), bool)
    assert predict_joints(net, frame, mask) is None
    mask[50:170, 140:190] = True
    got = predict_joints(net, frame, mask)
    assert got is not None
    assert np.allclose(got[0], mu, atol=1e-6) and np.allclose(got[1], np.exp(-5.0))


def test_network_file_round_trip_and_errors(tmp_path: Path, rng: np.random.Generator) -> None:
    net = constant_reading_net(rng.normal(0, 0.2, (N_JOINTS, 3)))
    p = save_appearance(tmp_path / "net.npz", net)
    back = load_appearance(p)
    x = net_input(rng.integers(0, 256, (16, 16, 3), dtype=np.uint8), rng.random((16, 16)) < 0.5)
    assert back.size == 16 and back.meta == net.meta == {"fixture": "constant"}
    assert np.array_equal(forward(back, x), forward(net, x))
    with pytest.raises(AppearanceError, match="train-appearance"):
        load_appearance(tmp_path / "missing.npz")
    raw = p.read_bytes()
    (tmp_path / "cut.npz").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(AppearanceError, match="truncated or corrupt"):
        load_appearance(tmp_path / "cut.npz")
    with np.load(p) as z:  # a changed weight: the checksum catches it
        arrays = {k: z[k] for k in z.files}
    good_w0 = arrays["w0"]
    arrays["w0"] = good_w0.copy()
    arrays["w0"].flat[0] += 1.0
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(AppearanceError, match="checksum"):
        load_appearance(tmp_path / "bad.npz")
    import json

    header = json.loads(str(arrays["header"]))
    arrays["w0"] = good_w0
    for change, msg in (({"version": APPEARANCE_VERSION + 1}, "stale"), ({"format": "x"}, "not an appearance"),
                        ({"size": 20}, "inconsistent")):
        np.savez(tmp_path / "h.npz", **(arrays | {"header": np.array(json.dumps(header | change))}))
        with pytest.raises(AppearanceError, match=msg):
            load_appearance(tmp_path / "h.npz")
    small = AppearanceNet(16, (net.layers[0], Layer("dense", np.zeros((5, 32), np.float32), np.zeros(5, np.float32),
                                                         1, False, False)), {})
    save_appearance(tmp_path / "small.npz", small)
    with pytest.raises(AppearanceError, match="outputs 5 values"):
        load_appearance(tmp_path / "small.npz")
    # an array file under the network's name, a layer's stride of 0, weights of a diverged training
    np.save(tmp_path / "array.npy", np.zeros(3))
    (tmp_path / "array.npy").rename(tmp_path / "array.npz")
    with pytest.raises(AppearanceError, match="truncated or corrupt"):
        load_appearance(tmp_path / "array.npz")
    zero_stride = header | {"layers": [header["layers"][0] | {"stride": 0}, *header["layers"][1:]]}
    np.savez(tmp_path / "s.npz", **(arrays | {"header": np.array(json.dumps(zero_stride))}))
    with pytest.raises(AppearanceError, match="stride 0"):
        load_appearance(tmp_path / "s.npz")
    c0 = net.layers[0]
    nan_net = AppearanceNet(16, (Layer("conv", np.full_like(c0.weight, np.nan), c0.bias, c0.stride, c0.pool, c0.relu),
                                 *net.layers[1:]), {})
    save_appearance(tmp_path / "nan.npz", nan_net)
    with pytest.raises(AppearanceError, match="non-finite"):
        load_appearance(tmp_path / "nan.npz")
    assert zlib.crc32(raw) == zlib.crc32(p.read_bytes())  # nothing above touched the good file


def test_a_network_that_outputs_nan_is_ignored(rng: np.random.Generator) -> None:
    """predict_joints gives None (the cue sits the frame out) instead of NaNs that would poison the posterior."""
    net = constant_reading_net(rng.normal(0, 0.2, (N_JOINTS, 3)))
    last = net.layers[-1]
    bias = last.bias.copy()
    bias[3] = np.nan
    bad = AppearanceNet(net.size, (*net.layers[:-1], Layer(last.kind, last.weight, bias, 1, False, False)), {})
    frame = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    mask = np.zeros((60, 80), bool)
    mask[10:50, 30:50] = True
    assert predict_joints(net, frame, mask) is not None
    assert predict_joints(bad, frame, mask) is None


def test_in_view_skips_people_cut_by_the_border() -> None:
    from tracker_service.cues.appearance import in_view

    mask = np.zeros((60, 80), bool)
    mask[10:50, 30:50] = True
    assert in_view(mask)
    assert not in_view(mask, min_pixels=801)
    for cut in (np.s_[0, 35], np.s_[59, 35], np.s_[30, 0], np.s_[30, 79]):
        m = mask.copy()
        m[cut] = True
        assert not in_view(m)


def test_training_learns_a_toy_depth_and_mirrors_the_joints(rng: np.random.Generator) -> None:
    """Crops whose shade encodes the depth of the right hand: training must find it, and mirrored
    samples must swap the hands (the left hand's depth is then read from the mirrored shade)."""
    from tracker_service.build.appearance_train import Samples, TrainConfig, _mirror, train_network

    n, size = 384, 32
    z = rng.uniform(-0.2, 0.2, n).astype(np.float32)
    crops = np.zeros((n, size, size, 3), np.uint8)
    masks = np.zeros((n, size, size), bool)
    masks[:, 4:28, 8:24] = True
    crops[:, 4:28, 8:16] = (128 + 500 * z)[:, None, None, None].astype(np.uint8)  # the left half of the image
    crops[:, 4:28, 16:24] = 128
    joints = np.zeros((n, N_JOINTS, 3), np.float32)
    joints[:, JOINT_INDEX["r_hand_tip"], 2] = z
    c, m, j = _mirror(crops, masks, joints, np.ones(n, bool))
    assert np.array_equal(m[:, :, ::-1], masks)
    assert np.array_equal(c[:, :, ::-1], crops) and np.array_equal(j[:, JOINT_INDEX["l_hand_tip"], 2], z)
    assert np.array_equal(np.asarray(MIRROR_JOINTS)[np.asarray(MIRROR_JOINTS)], np.arange(N_JOINTS))
    cfg = TrainConfig(size=size, width=4, epochs=6, batch=32, lr=3e-3, validation_every=2)
    samples = Samples(crops, masks, joints, np.arange(n) % 8)
    seen: list[dict[str, float]] = []
    net = train_network(samples, cfg, threads=1, progress=lambda e, t, f: seen.append(f))
    assert len(seen) == 6 and net.size == size and net.meta["validation_samples"] == n // 2
    pred = np.array([forward(net, net_input(crops[i], masks[i]))[3 * JOINT_INDEX["r_hand_tip"] + 2]
                     for i in range(n)])
    assert np.corrcoef(pred, z)[0, 1] > 0.8
    assert seen[-1]["val_rms_z"] < seen[0]["val_rms_z"]


@pytest.mark.slow
def test_rendered_training_views(tmp_path: Path) -> None:
    """A gesture script played by the synthetic scene: crops of the person, joints over the height."""
    from tracker_service.app.resources import DEFAULT_SCRIPT
    from tracker_service.build.appearance_train import render_samples, render_take

    s = render_take(DEFAULT_SCRIPT, seed=5, every=20, size=32)
    assert len(s) >= 3 and s.crops.shape[1:] == (32, 32, 3) and s.masks.mean() > 0.1
    assert np.allclose(s.joints[:, 0], 0) and np.all(s.joints[:, JOINT_INDEX["head_top"], 1] > 0.25)
    assert np.all(np.abs(s.joints) < 1.0)
    # cached per take and pass: the second call renders nothing
    calls: list[tuple[int, int]] = []
    a = render_samples([(7, str(DEFAULT_SCRIPT))], [(100, 25)], 32, tmp_path, 1, lambda d, t: calls.append((d, t)))
    b = render_samples([(7, str(DEFAULT_SCRIPT))], [(100, 25)], 32, tmp_path, 1, lambda d, t: calls.append((d, t)))
    assert calls[0] == (0, 1) and calls[-1] == (1, 1) and len(a) == len(b) and np.array_equal(a.crops, b.crops)
    assert np.all(a.take == 7) and (tmp_path / "100_25_32" / "007.npz").is_file()


def test_randomised_training_takes_cover_every_axis() -> None:
    """Each randomised training take varies one or two axes, the same for the same seed, and over a
    pass's takes every axis is seen alone; the varied scene is what the take renders."""
    from collections import Counter

    from tracker_service.build.appearance_train import vary_axes
    from tracker_service.scene.variation import AXES

    draws = [vary_axes(9000 + row) for row in range(220)]
    assert draws == [vary_axes(9000 + row) for row in range(220)]
    assert all(1 <= len(d) <= 2 and len(set(d)) == len(d) and set(d) <= set(AXES) for d in draws)
    alone = Counter(d[0] for d in draws if len(d) == 1)
    assert set(alone) == set(AXES) and min(alone.values()) >= 5
    assert 0.2 < sum(len(d) == 2 for d in draws) / len(draws) < 0.5


@pytest.mark.slow
def test_randomised_training_views_differ_from_plain_ones() -> None:
    """A take rendered with an axis varied gives other pixels for the same joints."""
    from tracker_service.app.resources import DEFAULT_SCRIPT
    from tracker_service.build.appearance_train import render_take

    plain = render_take(DEFAULT_SCRIPT, seed=5, every=20, size=32)
    varied = render_take(DEFAULT_SCRIPT, seed=5, every=20, size=32, axes=("lights", "sensor"))
    assert len(plain) == len(varied) and np.allclose(plain.joints, varied.joints)
    assert np.abs(plain.crops.astype(int) - varied.crops.astype(int)).mean() > 3


def test_a_training_configuration_is_checked() -> None:
    """A typo in code must not train on other masks than asked, nor on nothing."""
    from tracker_service.build.appearance_train import TrainConfig

    with pytest.raises(ValueError, match="masks must be one of subtracted, truth, not 'exact'"):
        TrainConfig(masks="exact")
    with pytest.raises(ValueError, match="must be positive"):
        TrainConfig(epochs=0)
    assert TrainConfig(masks="truth").masks == "truth"


@pytest.mark.slow
def test_training_views_masked_as_the_tracker_sees_them(tmp_path: Path) -> None:
    """The default training silhouette is the tracker's background subtraction: the same views and
    joints as with the renderer's exact silhouette, masks that mostly agree with it but not exactly,
    cached apart from the exact ones."""
    from tracker_service.app.resources import DEFAULT_SCRIPT
    from tracker_service.build.appearance_train import MASK_VERSION, TrainConfig, render_samples, render_take

    assert TrainConfig().masks == "subtracted"
    exact = render_take(DEFAULT_SCRIPT, seed=5, every=20, size=32)
    seen = render_take(DEFAULT_SCRIPT, seed=5, every=20, size=32, subtracted=True)
    assert len(seen) == len(exact) and np.allclose(seen.joints, exact.joints)
    iou = (seen.masks & exact.masks).sum(axis=(1, 2)) / (seen.masks | exact.masks).sum(axis=(1, 2))
    assert np.median(iou) > 0.8 and not np.array_equal(seen.masks, exact.masks)
    render_samples([(7, str(DEFAULT_SCRIPT))], [(100, 25)], 32, tmp_path, 1, subtracted=True)
    assert (tmp_path / f"100_25_32_sub{MASK_VERSION}" / "007.npz").is_file()


def test_gesture_scripts_join_the_training_takes(tmp_path: Path) -> None:
    """The scripts are numbered after the recordings and cached by name, not by number."""
    from tracker_service.app.resources import DEFAULT_SCRIPT
    from tracker_service.build.appearance_train import SCRIPT_ROW_BASE, render_samples, training_takes

    takes = training_takes([(3, "a.bvh"), (8, "b.bvh")], [DEFAULT_SCRIPT])
    assert takes == [(3, "a.bvh"), (8, "b.bvh"), (SCRIPT_ROW_BASE, str(DEFAULT_SCRIPT))]
    with pytest.raises(ValueError, match="below"):
        training_takes([(SCRIPT_ROW_BASE, "c.bvh")], [DEFAULT_SCRIPT])
    with pytest.raises(ValueError, match="at most"):
        training_takes([], [DEFAULT_SCRIPT] * (1000 - SCRIPT_ROW_BASE + 1))
    s = render_samples(takes[2:], [(100, 25)], 32, tmp_path, 1)
    assert len(s) >= 2 and np.all(s.take == SCRIPT_ROW_BASE)
    (name,) = [p.name for p in (tmp_path / "100_25_32").iterdir()]
    assert name.startswith(f"script_crouch_{SCRIPT_ROW_BASE}_")
    # the same name in another folder, or another number, is another file
    from tracker_service.build.appearance_train import _cache_name
    other = tmp_path / "elsewhere" / "crouch.toml"
    names = {name, _cache_name(SCRIPT_ROW_BASE, str(other)), _cache_name(SCRIPT_ROW_BASE + 1, str(DEFAULT_SCRIPT))}
    assert len(names) == 3


def test_default_posture_passes_fit_any_ensemble_size() -> None:
    from tracker_service.build.appearance_train import MEMBER_POSTURE_PASSES, member_extra_passes

    assert member_extra_passes(MEMBER_POSTURE_PASSES, 1) == MEMBER_POSTURE_PASSES[:1]
    assert member_extra_passes(MEMBER_POSTURE_PASSES, 2) == MEMBER_POSTURE_PASSES
    assert member_extra_passes(MEMBER_POSTURE_PASSES, 3) == (*MEMBER_POSTURE_PASSES, ())


def test_the_cue_weighs_the_filter_towards_what_the_network_sees(small_db, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    """A network that always sees one pose pulls the filter's support towards it; weight 0 changes
    nothing at all."""
    from protocol.motion import ground
    from tracker_service.body.raster import render_silhouette
    from tracker_service.estimators.tree_filter.model import FilterParams
    from tracker_service.pipeline.process import TrackerConfig, new_state, process_frame
    from tracker_service.templates.database import load_db

    _, _, motions, _, path = small_db
    loaded = load_db(path)
    db, cam = loaded.db, loaded.camera
    assert db.leaf_joints3d.shape == (db.n_leaves, N_JOINTS, 3)
    truth = fk(ground(motions[0].poses, loaded.body), loaded.body)
    room = np.full((cam.height, cam.width, 3), (170, 175, 160), np.float32)
    room[cam.height // 2:] = (90, 110, 140)

    def frame(mask: np.ndarray | None) -> np.ndarray:
        img = room.copy()
        if mask is not None:
            img[mask] = (40, 60, 200)
        return np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)

    frames = [frame(None) for _ in range(6)] + [frame(render_silhouette(truth[f], loaded.body.capsule_radii, cam))
                                                for f in range(0, 40, 2)]
    # the network "sees" the leaf whose arms are farthest in depth from the standing leaves' average
    z = db.leaf_joints3d[:, :, 2]
    target = int(np.argmax(np.abs(z - np.median(z, axis=0)).sum(axis=1)))
    net = constant_reading_net(db.leaf_joints3d[target], log_var=-6.0)

    def run(cfg: TrackerConfig) -> tuple[list[np.ndarray], list[float]]:
        st = new_state(loaded.body)
        weights, costs = [], []
        for i, img in enumerate(frames):
            st, res = process_frame(st, img, db, loaded.body, cam, cfg, i / 30)
            if res.phase == "tracking" and len(st.filter.leaves):
                weights.append(st.filter.weights.copy())
                c = joints_cost(db.leaf_joints3d[target].astype(np.float64), np.full((N_JOINTS, 3), np.exp(-6.0)),
                                db.leaf_joints3d[st.filter.leaves])
                costs.append(float(st.filter.weights @ c))
        assert len(weights) >= 10
        return weights, costs

    base = TrackerConfig(background_frames=6, init_frames=3)
    w0, c0 = run(base)
    w_off, _ = run(TrackerConfig(background_frames=6, init_frames=3, appearance=net,
                                 filter=FilterParams(appearance_weight=0.0)))
    assert all(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(w0, w_off, strict=True))
    _, c1 = run(TrackerConfig(background_frames=6, init_frames=3, appearance=net,
                              filter=FilterParams(appearance_weight=1.0)))
    assert np.mean(c1) < 0.9 * np.mean(c0)  # the support moved towards what the network sees


def test_proposed_leaves_are_evaluated_beside_the_trees_candidates(small_db) -> None:  # type: ignore[no-untyped-def]
    """A leaf the tree search does not reach is scored when proposed, and can win the frame."""

    from protocol.motion import ground
    from tracker_service.body.raster import render_silhouette
    from tracker_service.estimators.base import LeafCost, Observation
    from tracker_service.estimators.tree_filter.filter import initial_state, step
    from tracker_service.estimators.tree_filter.model import FilterParams
    from tracker_service.silhouette.features import preprocess
    from tracker_service.silhouette.placement import observed_placement
    from tracker_service.templates.database import load_db

    _, _, motions, _, path = small_db
    loaded = load_db(path)
    db, cam = loaded.db, loaded.camera
    truth = fk(ground(motions[0].poses, loaded.body), loaded.body)
    mask = render_silhouette(truth[30], loaded.body.capsule_radii, cam)
    feats, obs = preprocess(mask, "xor"), observed_placement(mask, cam)
    narrow = FilterParams(max_keep=(1, 1), keep_likelihood=(0, 0), keep_rel=1.0, support=4)
    _, est0 = step(initial_state(), db, Observation(feats, obs), narrow)
    outside = np.setdiff1d(np.arange(db.n_leaves), est0.support_leaves)
    # a leaf the narrow search did not score: the one nearest its MAP leaf in joint space
    j = db.leaf_joints3d[outside]
    near = int(outside[np.argmin(np.abs(j - db.leaf_joints3d[est0.leaf]).sum(axis=(1, 2)))])
    _, est1 = step(initial_state(), db, Observation(feats, obs, proposals=np.array([near, est0.leaf])), narrow)
    # one new leaf on the 3 x 3 grid (and, with few candidates, in the refinement of the best 6)
    assert est0.evaluations[-1] + 9 <= est1.evaluations[-1] <= est0.evaluations[-1] + 18
    assert near in est1.support_leaves
    mu = db.leaf_joints3d[near].astype(np.float64)  # and a network that sees it makes it the estimate
    sharp = np.full((N_JOINTS, 3), 1e-4)
    cue = LeafCost("appearance", 1.0, lambda lv, _p: joints_cost(mu, sharp, db.leaf_joints3d[lv]))
    _, est2 = step(initial_state(), db, Observation(feats, obs, leaf_costs=(cue,), proposals=np.array([near])), narrow)
    assert est2.leaf == near


def test_the_published_pose_is_refined_towards_the_reading(small_db, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    """With the cue, the published joints move toward what the network reads (ELMO's local
    refinement, ``pipeline/refinement.py``); ``refine=None`` publishes the filter's pose, and the filter
    itself (its posterior) is the same either way."""
    from protocol.motion import ground
    from tracker_service.body.raster import render_silhouette
    from tracker_service.pipeline.process import TrackerConfig, new_state, process_frame
    from tracker_service.templates.database import load_db

    _, _, motions, _, path = small_db
    loaded = load_db(path)
    db, cam = loaded.db, loaded.camera
    truth = fk(ground(motions[0].poses, loaded.body), loaded.body)
    room = np.full((cam.height, cam.width, 3), (170, 175, 160), np.float32)
    noise = [rng.normal(0, 2.0, room.shape) for _ in range(26)]

    def frame(i: int, mask: np.ndarray | None) -> np.ndarray:
        img = room.copy()
        if mask is not None:
            img[mask] = (40, 60, 200)
        return np.clip(img + noise[i], 0, 255).astype(np.uint8)

    masks = [render_silhouette(truth[f], loaded.body.capsule_radii, cam) for f in range(0, 40, 2)]
    frames = [frame(i, None) for i in range(6)] + [frame(6 + k, m) for k, m in enumerate(masks)]
    # the network reads the leaf with the left hand farthest towards the camera
    hand = JOINT_INDEX["l_hand_tip"]
    reading = db.leaf_joints3d[int(np.argmax(db.leaf_joints3d[:, hand, 2]))].astype(np.float64)
    net = constant_reading_net(reading, log_var=-7.0)

    carried: list[bool] = []

    def run(cfg: TrackerConfig) -> tuple[list[float], list[np.ndarray], list[float]]:
        st = new_state(loaded.body)
        dist, weights, hand_z = [], [], []
        carried.clear()
        for i, img in enumerate(frames):
            st, res = process_frame(st, img, db, loaded.body, cam, cfg, i / 30)
            carried.append(st.reading is not None)
            if res.phase != "tracking":
                assert st.reading is None  # the readings' history starts with the track
            if res.phase == "tracking" and res.joints is not None:
                seen = camera_joints(res.joints, cam, st.body.height).astype(np.float64)
                dist.append(float(np.linalg.norm(seen - reading, axis=1).mean()))
                weights.append(st.filter.weights.copy())
                hand_z.append(float(abs(seen[hand, 2] - reading[hand, 2])))
        assert len(dist) >= 10
        return dist, weights, hand_z

    base = TrackerConfig(background_frames=6, init_frames=3, appearance=net, smoothing=None)
    d_off, w_off, z_off = run(replace(base, refine=None))
    d_on, w_on, z_on = run(base)
    assert all(np.array_equal(a, b) for a, b in zip(w_off, w_on, strict=True))
    assert np.mean(d_on) < 0.3 * np.mean(d_off), (np.mean(d_on), np.mean(d_off))
    # the hand's depth, which the silhouette cannot see
    assert np.mean(z_on) < 0.5 * np.mean(z_off), (np.mean(z_on), np.mean(z_off))
    assert sum(carried) >= 10  # the readings were filtered over the track (reading_filter.py)
    # a steady reading is its own filtered value, with a variance shrunk by the frames before: the
    # pose is pulled toward it at least as far as by the raw reading
    d_raw, _, _ = run(replace(base, reading_filter=None))
    assert not any(carried)
    assert np.mean(d_on) < np.mean(d_raw), (np.mean(d_on), np.mean(d_raw))


def test_mirrored_reading_averages_both_views(rng: np.random.Generator) -> None:
    """``mirror=True``: the flipped crop's reading, mapped back (left and right swapped, x negated),
    averaged with the direct one; the variance widened by their disagreement. A network that ignores
    its input disagrees with its own mirror image exactly where the pose is asymmetric."""
    mu = rng.normal(0, 0.2, (N_JOINTS, 3))
    net = constant_reading_net(mu, log_var=-6.0)
    frame = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
    mask = np.zeros((120, 160), bool)
    mask[20:100, 60:100] = True
    direct = predict_joints(net, frame, mask)
    both = predict_joints(net, frame, mask, mirror=True)
    assert direct is not None and both is not None
    back = mu[list(MIRROR_JOINTS)] * np.array([-1.0, 1.0, 1.0])
    assert np.allclose(direct[0], mu, atol=1e-6)
    assert np.allclose(both[0], 0.5 * (mu + back), atol=1e-6)
    assert np.allclose(both[1], np.exp(-6.0) + np.square(0.5 * (mu - back)), rtol=1e-5, atol=1e-9)
    sym = 0.5 * (mu + back)  # a symmetric reading is its own mirror image: nothing changes
    s = predict_joints(constant_reading_net(sym, log_var=-6.0), frame, mask, mirror=True)
    assert s is not None and np.allclose(s[0], sym, atol=1e-6) and np.allclose(s[1], np.exp(-6.0), rtol=1e-5)



def test_a_batch_reads_like_single_inputs(rng: np.random.Generator) -> None:
    """``forward`` on a batch (the mirrored reading's two views) equals one input at a time."""
    def w(*shape: int) -> np.ndarray:
        return rng.normal(0, 0.3, shape).astype(np.float32)

    layers = (Layer("conv", w(4, 4, 3, 3), w(4), 2, True, True), Layer("conv", w(3, 4, 3, 3), w(3), 1, False, True),
              Layer("dense", w(NOUT, 3 * 4 * 4), w(NOUT), 1, False, False))
    net = AppearanceNet(size=16, layers=layers, meta={"test": True})
    x = rng.normal(0, 1, (3, 16, 16, 4)).astype(np.float32)
    batch = forward(net, x)
    assert batch.shape == (3, NOUT)
    for i in range(3):
        assert np.allclose(batch[i], forward(net, x[i]), atol=1e-5)
    assert not np.allclose(batch[0], forward(net, np.ascontiguousarray(x[0, :, ::-1])), atol=1e-3)


def test_an_ensemble_pools_its_networks_readings_and_round_trips(tmp_path: Path, rng: np.random.Generator) -> None:
    """``ensemble``: several networks in one file; ``predict_joints`` pools every network's reading
    (and, mirrored, every view's) as one Gaussian: the mean of the means, the mixture's variance."""
    from tracker_service.cues.appearance import ensemble, pool_readings

    a_mu, b_mu = rng.normal(0, 0.2, (N_JOINTS, 3)), rng.normal(0, 0.2, (N_JOINTS, 3))
    a, b = constant_reading_net(a_mu, log_var=-6.0), constant_reading_net(b_mu, log_var=-5.0)
    both = ensemble([a, b])
    assert len(both.networks) == 2 and both.meta == {"members": [{"fixture": "constant"}, {"fixture": "constant"}]}
    frame = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
    mask = np.zeros((120, 160), bool)
    mask[20:100, 60:100] = True
    got = predict_joints(both, frame, mask)
    assert got is not None
    mean = 0.5 * (a_mu + b_mu)
    assert np.allclose(got[0], mean, atol=1e-6)
    assert np.allclose(got[1], 0.5 * (np.exp(-6.0) + np.exp(-5.0)) + np.square(0.5 * (a_mu - b_mu)), rtol=1e-5)
    # mirrored: four readings pooled
    m = predict_joints(both, frame, mask, mirror=True)
    ma, mb = predict_joints(a, frame, mask, mirror=True), predict_joints(b, frame, mask, mirror=True)
    assert m is not None and ma is not None and mb is not None
    assert np.allclose(m[0], 0.5 * (ma[0] + mb[0]), atol=1e-6)
    # the file keeps every member; a member's changed weight is caught
    p = save_appearance(tmp_path / "ens.npz", ensemble([both, a]))
    back = load_appearance(p)
    assert len(back.networks) == 3 and len(back.meta["members"]) == 3
    x = net_input(frame[:16, :16], mask[:16, :16])
    for k in range(3):
        assert np.array_equal(forward(back, x, k), forward(ensemble([a, b, a]), x, k))
    with np.load(p) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["m2_b1"] = arrays["m2_b1"] + np.float32(1.0)
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(AppearanceError, match="member 2's layer 1"):
        load_appearance(tmp_path / "bad.npz")
    # pooling: non-finite readings are left out; one reading is itself; none is None
    r = (np.ones((2, 3)), np.full((2, 3), 0.5))
    assert pool_readings([None, r]) is r and pool_readings([None]) is None
    with pytest.raises(ValueError):
        ensemble([a, constant_reading_net(a_mu, size=32)])


def test_a_half_precision_file_reads_back_as_float32_with_the_same_outputs(tmp_path, rng: np.random.Generator) -> None:  # type: ignore[no-untyped-def]
    """The shipped file stores float16 weights (half the size); read back, the network computes in
    float32 and answers as the float32 file does, to float16's precision."""
    from protocol.skeleton import N_JOINTS
    from tracker_service.cues.appearance import AppearanceNet, Layer, forward, load_appearance, save_appearance

    size = 16
    conv = Layer("conv", rng.normal(0, 0.3, (4, 4, 3, 3)).astype(np.float32), rng.normal(0, 0.1, 4).astype(np.float32),
                 2, True, True)
    dense = Layer("dense", rng.normal(0, 0.1, (2 * N_JOINTS * 3, 4 * (size // 4) ** 2)).astype(np.float32),
                  rng.normal(0, 0.1, 2 * N_JOINTS * 3).astype(np.float32), 1, False, False)
    net = AppearanceNet(size, (conv, dense), {"test": "half"})
    full, half = save_appearance(tmp_path / "f.npz", net), save_appearance(tmp_path / "h.npz", net, half=True)
    assert half.stat().st_size < 0.7 * full.stat().st_size
    back = load_appearance(half)
    assert all(layer.weight.dtype == np.float32 for layer in back.layers)
    x = rng.uniform(-0.5, 0.5, (3, size, size, 4)).astype(np.float32)
    np.testing.assert_allclose(forward(back, x), forward(load_appearance(full), x), atol=5e-3)
