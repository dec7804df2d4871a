"""Backbone building blocks: soft-argmax, volumetric loss, metric crop, network shapes, the
training data, its augmentation and a resumable training run."""
import numpy as np
import pytest
import torch

from recon.backbone import crops
from recon.backbone import train as T
from recon.backbone.crop import Crop, grid_to_camera
from recon.backbone.hourglass import HourglassConfig, StackedHourglass
from recon.backbone.model import first_stack, inference_copy, traced
from recon.backbone.volumetric import local_mass, soft_argmax_3d, volumetric_ce, voxel_index
from recon.body import skeleton
from recon.errors import ReconError
from recon.synth.dataset import generate
from recon.synth.scene import SceneSampler


def test_soft_argmax_finds_a_sharp_peak():
    logits = torch.full((1, 2, 4, 8, 8), -1e4)
    logits[0, 0, 1, 2, 5] = 0.0  # depth 1, row 2, column 5
    logits[0, 1, 3, 7, 0] = 0.0
    c = soft_argmax_3d(logits)
    np.testing.assert_allclose(c[0, 0].numpy(), [5.5 / 8, 2.5 / 8, 1.5 / 4], atol=1e-6)
    np.testing.assert_allclose(c[0, 1].numpy(), [0.5 / 8, 7.5 / 8, 3.5 / 4], atol=1e-6)


def test_volumetric_ce_prefers_the_target_voxel_and_ignores_outside_points():
    coords = torch.tensor([[[5.5 / 8, 2.5 / 8, 1.5 / 4], [1.2, 0.5, 0.5]]])
    flat, valid = voxel_index(coords, (4, 8, 8))
    assert valid.tolist() == [[True, False]] and flat[0, 0] == (1 * 8 + 2) * 8 + 5
    good = torch.zeros(1, 2, 4, 8, 8)
    good[0, 0, 1, 2, 5] = 10.0
    assert volumetric_ce(good, coords) < volumetric_ce(torch.zeros(1, 2, 4, 8, 8), coords)


def test_local_mass_equals_a_box_filter_of_the_probabilities():
    """The 27-voxel gather is the zero-padded 3x3x3 box sum of the softmax, read at each point's
    voxel, including points on and beyond the volume's border."""
    torch.manual_seed(0)
    b, p, d, h, w = 2, 5, 4, 6, 8
    logits = 3 * torch.randn(b, p, d, h, w, dtype=torch.float64)
    coords = torch.rand(b, p, 3, dtype=torch.float64)
    coords[0, 0] = torch.tensor([0.01, 0.99, 0.0])  # corner voxel
    coords[0, 1] = torch.tensor([1.3, -0.2, 0.5])  # outside: clamped onto the border voxel
    prob = torch.softmax(logits.reshape(b, p, -1), -1).view(b * p, 1, d, h, w)
    box = (torch.nn.functional.avg_pool3d(prob, 3, stride=1, padding=1) * 27).view(b, p, -1)
    flat, _ = voxel_index(coords, (d, h, w))
    torch.testing.assert_close(local_mass(logits, coords), box.gather(-1, flat[..., None])[..., 0])
    sharp = torch.full((1, 1, d, h, w), -1e4, dtype=torch.float64)
    sharp[0, 0, 1, 2, 3] = 0
    assert local_mass(sharp, soft_argmax_3d(sharp)).item() == pytest.approx(1.0)


def test_inference_copy_and_trace_match_the_trained_network():
    torch.manual_seed(0)
    torch.set_num_threads(1)
    net = StackedHourglass(HourglassConfig(stacks=2, width=32, depth_bins=4, levels=2, input_size=32))
    for m in net.modules():  # non-trivial BatchNorm statistics, as after training
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.5, 0.5), m.running_var.uniform_(0.5, 2), m.weight.data.uniform_(0.5, 1.5)
    net.eval()
    fast = inference_copy(net)
    assert not any(isinstance(m, torch.nn.BatchNorm2d) and isinstance(prev, torch.nn.Conv2d)
                   for seq in fast.modules() if isinstance(seq, torch.nn.Sequential) for prev, m in zip(seq, seq[1:]))
    script = traced(fast, 32)
    assert isinstance(script, torch.jit.ScriptModule)
    for batch in (1, 3):  # traced at batch 1, valid for any batch
        x = torch.rand(batch, 32, 32, 3).permute(0, 3, 1, 2)
        with torch.no_grad():
            ref = net(x.contiguous())
            for out in (fast(x), script(x)):
                for a, r in zip(out, ref):
                    torch.testing.assert_close(a, r, atol=1e-4, rtol=1e-4)
            first = traced(first_stack(fast), 32)(x)  # the locating pass: the first stack's heads
            assert len(first) == 1
            torch.testing.assert_close(first[0], ref[0], atol=1e-4, rtol=1e-4)


def test_crop_round_trip_and_centre():
    k = np.array([[500.0, 0, 128], [0, 500.0, 120], [0, 0, 1]])
    pts = np.array([[0.1, -0.3, 3.0], [0.5, 0.4, 3.6], [-0.2, 0.0, 2.5]])
    crop = Crop.around(pts.mean(0), k)
    g = crop.to_grid(pts)
    np.testing.assert_allclose(crop.from_grid(g), pts, atol=1e-9)
    np.testing.assert_allclose(crop.to_grid(pts.mean(0)[None])[0], [0.5, 0.5, 0.5], atol=1e-9)
    assert crop.side == pytest.approx(500 * 2.5 / pts.mean(0)[2])
    img = np.zeros((240, 256, 3), np.uint8)
    img[113:128, 121:136] = 255  # a bright square around the principal point (128, 120)
    out = crop.image(img, 64)
    assert out.shape == (64, 64, 3)
    # it lands where the crop maps the principal point, and off-crop pixels are the border colour
    y, x = np.unravel_index(out[..., 0].argmax(), out.shape[:2])
    expect = (np.array([128.0, 120.0]) - [crop.u0, crop.v0]) * 64 / crop.side
    assert abs(x + 0.5 - expect[0]) <= 1.0 and abs(y + 0.5 - expect[1]) <= 1.0
    far = Crop(1000.0, 1000.0, 100.0, 3.0, k).image(img, 16, border=(7, 7, 7))
    assert (far == 7).all()


def test_hourglass_shapes_and_gradients():
    torch.manual_seed(0)
    cfg = HourglassConfig(stacks=2, width=32, depth_bins=4, levels=2, points=42, limbs=4, input_size=64)
    net = StackedHourglass(cfg)
    x = torch.rand(2, 3, 64, 64, requires_grad=True)
    outs = net(x)
    assert len(outs) == 2 and outs[-1].shape == (2, 46, 4, 16, 16)
    coords = soft_argmax_3d(outs[-1][:, :42])
    assert coords.shape == (2, 42, 3) and (coords >= 0).all() and (coords <= 1).all()
    loss = sum(volumetric_ce(o[:, :42], torch.rand(2, 42, 3)) for o in outs)
    loss.backward()
    assert x.grad is not None and torch.isfinite(x.grad).all()
    with pytest.raises(ValueError, match="images must be"):
        net(torch.rand(2, 3, 64, 32))


def test_crop_dataset_targets_and_a_resumable_training_run(tmp_path, body, mocap):
    root = generate(tmp_path / "s", "test", 3, 4, shard_size=4, workers=1, progress=False)
    ds = crops.CropDataset([root], 64, jitter=False)
    img, grid, crop_vec, k, pts = ds[0]
    assert img.shape == (3, 64, 64) and grid.shape == (42, 3)
    np.testing.assert_allclose(grid_to_camera(grid.double()[None], crop_vec[None], k[None])[0].numpy(), pts.numpy(),
                               atol=1e-4)
    jittered = crops.CropDataset([root], 64, jitter=True)
    assert jittered[1][0].shape == (3, 64, 64)
    cfg = T.BackboneTrainConfig(batch=2, steps=2, eval_every=2, val_images=2, workers=0,
                                model={"stacks": 1, "width": 16, "depth_bins": 4, "levels": 2, "input_size": 64})
    log = T.train([root], root, tmp_path / "run", cfg, progress=False)
    assert log["steps"] == 2 and np.isfinite(log["best_val_mpjpe_mm"])
    assert (tmp_path / "run" / "best.pt").exists() and (tmp_path / "run" / "curve.json").exists()
    cfg.steps = 3
    assert T.train([root], root, tmp_path / "run", cfg, progress=False)["steps"] == 3  # resumed from step 2
    cfg.lr = 0.1  # not a resumable change: refused, nothing overwritten
    with pytest.raises(ReconError, match="other settings"):
        T.train([root], root, tmp_path / "run", cfg, progress=False)
    # end-to-end fine-tuning (thesis 2.4.5) starts from those weights, logs the chain's error
    ft = T.BackboneTrainConfig(batch=2, steps=1, eval_every=1, val_images=2, workers=0, lr=1e-4,
                               init=str(tmp_path / "run" / "best.pt"), smplr_weight=1.0)
    log = T.train([root], root, tmp_path / "e2e", ft, progress=False)
    first, last = log["history"][0], log["history"][-1]
    assert first["tag"] == "init" and first["step"] == 0 and last["step"] == 1
    assert np.isfinite(last["val_chain_mpjpe_mm"]) and np.isfinite(last["loss"])


def test_end_to_end_chain_decodes_like_the_crop_and_passes_gradients(tmp_path, body, mocap):
    sampler = SceneSampler(body, "val", 1001, pool=64)
    rng = np.random.default_rng(0)
    img, grid, crop_vec, k, pts = (torch.stack(x) for x in zip(*[crops.make_crop(sampler.sample(i), 64, False, rng)
                                                                  for i in range(3)]))
    torch.testing.assert_close(grid_to_camera(grid.double(), crop_vec, k), pts, atol=1e-5, rtol=0)
    e2e = T.EndToEnd()
    assert not any(p.requires_grad for p in e2e.parameters())  # DAE + SMPLR stay frozen
    noisy = (grid + 0.02 * torch.randn(grid.shape, generator=torch.Generator().manual_seed(0))).requires_grad_(True)
    loss = e2e(noisy, grid, crop_vec, k)
    loss.backward()
    assert torch.isfinite(noisy.grad).all() and noisy.grad.abs().sum() > 0
    # SMPLR reproduces ground-truth J+ to ~1 cm; 5 cm of noise on the input costs clearly more
    assert e2e(grid, grid, crop_vec, k) < 0.03 < loss


def test_augmentation_moves_the_targets_with_the_image():
    """Paint each sample's head target as a dot in a blank crop; after the batch augmentation
    (kornia flip + rotation) the dot must sit at the augmented head target."""
    torch.manual_seed(0)
    size, b, head = 64, 12, skeleton.POINT_NAMES.index("head")
    grid = 0.3 + 0.4 * torch.rand(b, 42, 3)
    img = torch.zeros(b, 3, size, size)
    for i in range(b):
        x, y = (grid[i, head, :2] * size - 0.5).round().long().tolist()
        img[i, :, y - 1:y + 2, x - 1:x + 2] = 1.0
    out, g = T.CropAugmentation(gain=(1.0, 1.0), offset=0.0)(img, grid)
    assert out.shape == img.shape and g.shape == grid.shape
    moved = 0
    for i in range(b):
        y, x = np.unravel_index(out[i].mean(0).argmax().item(), (size, size))
        assert abs((x + 0.5) / size - g[i, head, 0]) < 2.5 / size and abs((y + 0.5) / size - g[i, head, 1]) < 2.5 / size
        moved += not torch.allclose(g[i, head], grid[i, head])
    assert moved > b // 2
    # depth is not an image axis: the same values (left and right swapped when flipped)
    assert torch.equal(g[..., 2].sort(-1).values, grid[..., 2].sort(-1).values)


def test_flip_mirrors_x_and_swaps_left_and_right_points():
    torch.manual_seed(3)
    grid = torch.rand(16, 42, 3)
    _, g = T.CropAugmentation(rotation_deg=0.0, gain=(1.0, 1.0), offset=0.0)(torch.rand(16, 3, 8, 8), grid)
    mirrored = grid[:, list(skeleton.POINT_MIRROR)] * torch.tensor([-1.0, 1.0, 1.0]) + torch.tensor([1.0, 0.0, 0.0])
    kept = [torch.allclose(g[i], grid[i], atol=1e-5) for i in range(16)]
    flipped = [torch.allclose(g[i], mirrored[i], atol=1e-5) for i in range(16)]
    assert all(a != b for a, b in zip(kept, flipped, strict=True))  # each sample is one or the other
    assert 2 <= sum(flipped) <= 14


def test_colour_augmentation_stays_in_range():
    torch.manual_seed(1)
    img = torch.rand(4, 3, 16, 16)
    out, _ = T.CropAugmentation(rotation_deg=0.0)(img, torch.full((4, 42, 3), 0.5))
    assert out.min() >= 0 and out.max() <= 1 and not torch.allclose(out, img)


@pytest.mark.slow
def test_gpu_recipe_resumes_then_ships_only_better_weights(tmp_path, monkeypatch, body, mocap):
    """`recon backbone recipe` on the CPU with a tiny network: the first call stops at its
    per-command limit (checkpointed), the second resumes, finishes the budget, exports, scores
    the candidate against the weights in place and ships it only if it is better."""
    from recon.backbone import recipe as R

    monkeypatch.setenv("RECON_CACHE_DIR", str(tmp_path / "cache"))
    tiny = {"stacks": 1, "width": 16, "depth_bins": 4, "levels": 2, "input_size": 64}
    cfg = R.RecipeConfig(minutes=0.5, run_minutes=0.1, init="", lr=1e-3, batch=2, repeats=1, workers=1,
                         eval_every=2, val_images=2, calibrate_on=2, score_images=2, model=tiny)
    card = tmp_path / "CARD.md"
    card.write_text("# card\n\ntext\n")
    target = tmp_path / "weights.pt"
    first = R.run_recipe(tmp_path / "run", cfg, device="cpu", weights=target, card=card, results=tmp_path,
                         progress=False)
    assert first["phase"] == "training" and first["minutes_left"] > 0 and not target.exists()
    calls = [first]
    while calls[-1]["phase"] == "training" and len(calls) < 6:  # re-run the same command until it finishes
        calls.append(R.run_recipe(tmp_path / "run", cfg, device="cpu", weights=target, card=card, results=tmp_path,
                                  progress=False))
    second = calls[-1]
    assert second["phase"] == "shipped" and second["steps"] > first["steps"]  # nothing to beat: shipped
    assert target.exists() and "Latest GPU recipe run" in card.read_text() and card.read_text().startswith("# card")
    assert (tmp_path / "backbone-gpu-recipe.json").exists()
    # the same finished run against the real shipped weights: a tiny network must not replace them
    third = R.run_recipe(tmp_path / "run", cfg, device="cpu", weights=T.WEIGHTS, card=None, results=None,
                         progress=False)
    assert third["phase"] == "kept"
    assert third["scores"]["shipped"]["crop_search_mpjpe_mm"] < third["scores"]["candidate"]["crop_search_mpjpe_mm"]
