"""Backbone building blocks: soft-argmax, volumetric loss, metric crop, network shapes."""
import numpy as np
import pytest
import torch

from recon.backbone.crop import Crop
from recon.backbone.hourglass import HourglassConfig, StackedHourglass
from recon.backbone.volumetric import soft_argmax_3d, volumetric_ce, voxel_index


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
