"""The learned motion prior of ``recon video``: its features' conventions, the training noise it
is made with, and the shipped weights on held-out mocap (the val split's performers)."""
import json

import numpy as np
import pytest
import torch

from recon.video import prior as motion_prior
from recon.video import prior_train

torch.set_num_threads(1)


def _points(t=20, seed=0):
    g = torch.Generator().manual_seed(seed)
    p = torch.randn(t, motion_prior.POINTS, 3, generator=g) * 0.3
    p[..., 2] += 4.0
    return p


def test_features_go_back_to_the_same_points():
    p = _points()
    x, mean = motion_prior.features(p, torch.ones(len(p)))
    assert x.shape == (len(p), motion_prior.IN) and mean.shape == (1, 3)
    assert torch.allclose(motion_prior.from_features(x[..., :-1], mean), p, atol=1e-5)


def test_features_do_not_see_how_far_along_its_line_of_sight_the_person_is():
    """The root twice as far along its line of sight changes only the root's mean."""
    p = _points()
    x, mean = motion_prior.features(p, torch.ones(len(p)))
    root = p[:, :1]
    far, far_mean = motion_prior.features((p - root) + 2.0 * root, torch.ones(len(p)))
    assert torch.allclose(far, x, atol=1e-5)
    assert float(far_mean[0, 2] - mean[0, 2]) == pytest.approx(np.log(2.0), abs=1e-5)


def test_an_untrained_prior_returns_its_input_and_is_shaped_per_frame():
    prior = motion_prior.MotionPrior().eval()
    p = _points(t=33)
    out, planted = motion_prior.apply(prior, p, torch.ones(33))
    assert out.shape == p.shape and planted.shape == (33, 2)
    assert torch.allclose(out, p, atol=1e-5)  # the output layer starts at zero
    batch, _ = motion_prior.apply(prior, torch.stack([p, p]), torch.ones(2, 33))
    assert batch.shape == (2, 33, motion_prior.POINTS, 3)


def test_the_prior_reads_time_both_ways_within_its_reach():
    """A point moved at one frame (the root left alone) moves the output only within the
    convolutions' reach, before and after that frame."""
    torch.manual_seed(0)
    prior = motion_prior.MotionPrior().eval()
    torch.nn.init.normal_(prior.out.weight, std=0.1)
    p = _points(t=200)
    q = p.clone()
    q[100, 5] += 0.5
    a, _ = motion_prior.apply(prior, p, torch.ones(200))
    b, _ = motion_prior.apply(prior, q, torch.ones(200))
    moved = ((a - b).abs().amax((1, 2)) > 1e-6).nonzero().flatten()
    reach = (prior.cfg.kernel // 2) * sum(prior.cfg.dilations)
    assert moved.min() < 100 < moved.max()
    assert moved.min() >= 100 - reach and moved.max() <= 100 + reach


def test_ar_noise_has_the_asked_deviation_and_correlation():
    g = torch.Generator().manual_seed(1)
    sigma, rho = torch.tensor([0.02, 0.05]), torch.tensor([0.0, 0.9])
    x = prior_train.ar_noise(sigma, rho, 400, 200, g)
    assert x.std((0, 1)) == pytest.approx(sigma, rel=0.05)
    lag1 = (x[:, 1:] * x[:, :-1]).mean((0, 1)) / x.pow(2).mean((0, 1))
    assert lag1 == pytest.approx(rho, abs=0.03)


def test_the_training_cameras_look_at_the_person_with_y_down():
    g = torch.Generator().manual_seed(2)
    world = torch.zeros(64, 5, motion_prior.POINTS, 3)
    world[..., 1] = torch.linspace(0, 1.7, motion_prior.POINTS)  # a column standing up (+Y up)
    (cam,) = prior_train.cameras(world, prior_train.PriorTrainConfig(), g)
    cfg = prior_train.PriorTrainConfig()
    z = cam[:, 0, 0, 2]
    assert ((z > cfg.distance[0] - 1e-4) & (z < cfg.distance[1] + 1e-4)).all()
    assert (cam[:, 0, -1, 1] < cam[:, 0, 0, 1]).all()  # the top is higher in the image: smaller y
    assert cam[:, 0, 0, :2].abs().max() < 1e-4  # the root is on the optical axis


def test_bridge_fills_unseen_frames_linearly():
    x = torch.arange(6, dtype=torch.float32)[:, None] ** 2
    seen = torch.tensor([True, True, False, False, True, False])
    out = prior_train.bridge(x, seen)
    assert out[:, 0].tolist() == pytest.approx([0, 1, 1 + 15 / 3, 1 + 30 / 3, 16, 16])


def test_the_training_noise_has_the_measured_spread():
    """At scale 1 without calibration, each joint's rotation error has the measured bias and
    wobble (slow and fast parts adding up to the measured deviation), the shape its spread."""
    measured = json.loads(prior_train.NOISE.read_text())
    noise = prior_train.Noise(measured)
    sigma = torch.tensor(measured["turn_sigma"])
    assert torch.allclose(noise.turn_slow ** 2 + noise.turn_fast ** 2, sigma ** 2, atol=1e-8)
    g = torch.Generator().manual_seed(3)
    turn, shape = noise.pose(2000, 8, torch.ones(2000), g)
    expected = (torch.tensor(measured["turn_bias_sigma"]) ** 2 + sigma ** 2).sqrt()
    assert turn.std((0, 1)) == pytest.approx(expected, rel=0.1, abs=1e-3)
    assert shape.std(0) == pytest.approx(torch.tensor(measured["shape_sigma"]), rel=0.1, abs=1e-3)
    half = prior_train.Noise(measured, calibration=(0.5, 1.0))
    assert torch.allclose(half.turn_fast, noise.turn_fast * 0.5)


@pytest.fixture(scope="module")
def held_out():
    """Windows of the val split's mocap with the measured noise (fixed seed)."""
    from recon.body import default_body
    cfg = prior_train.PriorTrainConfig()
    noise = prior_train.Noise(json.loads(prior_train.NOISE.read_text()), cfg.calibration)
    gen = torch.Generator().manual_seed(7)
    bank = prior_train.Motions(default_body(), "val", cfg.frames, seed=5).bank(48, noise, cfg, gen)
    return prior_train.batch(bank, noise, cfg, gen, 48)


def test_the_shipped_prior_cleans_held_out_motion(held_out):
    prior = motion_prior.load()
    m = prior_train.evaluate(prior, held_out)
    # the per-frame noise's acceleration mostly removed, the pose no worse (mocap val performers)
    assert m["accel_out"] < 0.4 * m["accel_in"], m
    assert m["mpjpe_out"] < m["mpjpe_in"], m
    assert m["planted_accuracy"] > 0.8, m


def test_the_shipped_prior_loads_as_float16_weights_only():
    blob = torch.load(motion_prior.WEIGHTS, map_location="cpu", weights_only=True)
    assert all(v.dtype == torch.float16 for v in blob["state"].values())
    assert motion_prior.WEIGHTS.stat().st_size < 2_000_000
