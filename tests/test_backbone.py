"""Backbone building blocks: soft-argmax, volumetric loss, metric crop, network shapes."""
import numpy as np
import pytest
import torch

from recon.backbone.crop import Crop
from recon.backbone.hourglass import HourglassConfig, StackedHourglass
from recon.backbone.volumetric import local_mass, soft_argmax_3d, volumetric_ce, voxel_index


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
    from recon.backbone.model import first_stack, inference_copy, traced

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
    img[118:123, 126:131] = 255  # a bright dot at the principal point
    out = crop.image(img, 64)
    assert out.shape == (64, 64, 3)


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
    from recon.backbone.crop import grid_to_camera
    from recon.backbone.train import BackboneTrainConfig, CropDataset, train
    from recon.synth.dataset import generate

    root = generate(tmp_path / "s", "test", 3, 4, shard_size=4, workers=1, progress=False)
    ds = CropDataset([root], 64, augment=False)
    img, grid, crop_vec, k, pts = ds[0]
    assert img.shape == (3, 64, 64) and grid.shape == (42, 3)
    np.testing.assert_allclose(grid_to_camera(grid.double()[None], crop_vec[None], k[None])[0].numpy(), pts.numpy(),
                               atol=1e-4)
    aug = CropDataset([root], 64, augment=True)
    assert aug[1][0].shape == (3, 64, 64)
    cfg = BackboneTrainConfig(batch=2, steps=2, eval_every=2, val_images=2, workers=0,
                              model={"stacks": 1, "width": 16, "depth_bins": 4, "levels": 2, "input_size": 64})
    log = train([root], root, tmp_path / "run", cfg)
    assert log["steps"] == 2 and np.isfinite(log["best_val_mpjpe_mm"])
    assert (tmp_path / "run" / "best.pt").exists() and (tmp_path / "run" / "curve.json").exists()
    cfg.steps = 3
    assert train([root], root, tmp_path / "run", cfg)["steps"] == 3  # resumed from step 2
    # end-to-end fine-tuning (thesis 2.4.5) starts from those weights, logs the chain's error
    ft = BackboneTrainConfig(batch=2, steps=1, eval_every=1, val_images=2, workers=0, lr=1e-4,
                             init=str(tmp_path / "run" / "best.pt"), smplr_weight=1.0)
    log = train([root], root, tmp_path / "e2e", ft)
    first, last = log["history"][0], log["history"][-1]
    assert first["tag"] == "init" and first["step"] == 0 and last["step"] == 1
    assert np.isfinite(last["val_chain_mpjpe_mm"]) and np.isfinite(last["loss"])


def test_end_to_end_chain_decodes_like_the_crop_and_passes_gradients(tmp_path, body, mocap):
    from recon.backbone.crop import grid_to_camera
    from recon.backbone.train import EndToEnd, make_crop
    from recon.synth.scene import SceneSampler

    sampler = SceneSampler(body, "val", 1001, pool=64)
    rng = np.random.default_rng(0)
    img, grid, crop_vec, k, pts = (torch.stack(x) for x in zip(*[make_crop(sampler.sample(i), 64, False, rng)
                                                                  for i in range(3)]))
    torch.testing.assert_close(grid_to_camera(grid.double(), crop_vec, k), pts, atol=1e-5, rtol=0)
    e2e = EndToEnd()
    assert not any(p.requires_grad for p in e2e.parameters())  # DAE + SMPLR stay frozen
    noisy = (grid + 0.02 * torch.randn(grid.shape, generator=torch.Generator().manual_seed(0))).requires_grad_(True)
    loss = e2e(noisy, grid, crop_vec, k)
    loss.backward()
    assert torch.isfinite(noisy.grad).all() and noisy.grad.abs().sum() > 0
    # SMPLR reproduces ground-truth J+ to ~1 cm; 5 cm of noise on the input costs clearly more
    assert e2e(grid, grid, crop_vec, k) < 0.03 < loss


def test_rotation_augmentation_moves_targets_with_the_image(tmp_path, body, mocap, monkeypatch):
    """Paint the target pixel of the head in a blank image; after augmentation the brightest
    pixel must sit at the augmented head target."""
    from recon.backbone import train as T
    from recon.synth.dataset import generate

    root = generate(tmp_path / "s", "test", 3, 1, shard_size=1, workers=1, progress=False)
    ds = T.CropDataset([root], 64, augment=True, seed=1)
    plain = T.CropDataset([root], 64, augment=False)
    g0 = plain[0][1].numpy()
    head = 15
    real = T.SynthDataset.__getitem__

    def marked(self, i):
        s = real(self, i)
        crop = T.Crop.around(s["points3d"][:24].astype(np.float64).mean(0), s["K"].astype(np.float64))
        u, v = crop.u0 + g0[head, 0] * crop.side, crop.v0 + g0[head, 1] * crop.side
        s["rgb"] = np.zeros_like(s["rgb"])
        s["rgb"][int(v) - 3:int(v) + 4, int(u) - 3:int(u) + 4] = 255
        return s

    monkeypatch.setattr(T.SynthDataset, "__getitem__", marked)
    for _ in range(5):
        img, grid, *_ = ds[0]
        bright = img.mean(0).numpy()
        y, x = np.unravel_index(bright.argmax(), bright.shape)
        g = grid.numpy()
        flipped = g[head, 0]
        assert abs((x + 0.5) / 64 - flipped) < 0.1 and abs((y + 0.5) / 64 - g[head, 1]) < 0.1
