"""SMPLR features, networks, noise models, training smoke test and the shipped weights."""
import json

import numpy as np
import pytest
import roma
import torch

import recon
from recon import camera
from recon.body import skeleton
from recon.smplr import features, noise
from recon.smplr import train as T
from recon.smplr.data import generate
from recon.smplr.evaluate import evaluate_and_report
from recon.smplr.model import SMPLR, WEIGHTS
from recon.smplr.networks import DAEConfig, DenoisingAutoencoder, PoseNet, ShapeNet, local_to_global


@pytest.fixture(scope="module")
def test_batch(body, mocap):
    return generate(body, "test", 64, seed=4242, noise_deg=0.0)


def test_features_invariances(body, test_batch):
    p = test_batch["points"]
    n = features.normalized_relative(p)
    assert n.shape == (64, 3 * 41)
    assert torch.allclose(n.view(64, 41, 3).norm(dim=-1), torch.ones(64, 41), atol=1e-5)
    assert torch.allclose(features.normalized_relative(2.0 * p), n, atol=1e-5)  # scale-free
    t = features.template_distances(body)
    r = roma.rotvec_to_rotmat(torch.tensor([0.3, -1.0, 0.2]))
    assert torch.allclose(features.relative_distances(p @ r.T, t), features.relative_distances(p, t), atol=1e-5)
    rest = body(points_only=True).points
    assert features.relative_distances(rest, t).abs().max() < 1e-6
    with pytest.raises(ValueError, match="J\\+ must have shape"):
        features.normalized_relative(torch.zeros(2, 24, 3))


def test_network_outputs_and_gradients():
    omega, psi, dae = PoseNet(64, 1, global_rot=True), ShapeNet(6, width=32), DenoisingAutoencoder(DAEConfig((64, 32)))
    p = torch.randn(5, 42, 3, requires_grad=True)
    r = omega(features.normalized_relative(p))
    assert torch.allclose(local_to_global(r), omega.raw(features.normalized_relative(p)), atol=1e-5)
    assert r.shape == (5, 24, 3, 3)
    assert torch.allclose(r @ r.transpose(-1, -2), torch.eye(3).expand(5, 24, 3, 3), atol=1e-5)
    assert torch.allclose(torch.det(r), torch.ones(5, 24), atol=1e-5)
    s = psi(torch.randn(5, 41))
    assert s.shape == (5, 6) and (s >= 0).all() and (s <= 1).all()
    y = dae(p)
    assert y.shape == (5, 42, 3)
    (r.sum() + y.sum()).backward()
    assert p.grad is not None and p.grad.abs().sum() > 0
    lift = DenoisingAutoencoder(DAEConfig((64, 32), lifting=True)).eval()
    q = p.detach().clone()
    q2 = q.clone()
    q2[..., 2] += 1.0  # depth is ignored when lifting
    assert torch.allclose(lift(q) - q * torch.tensor([1.0, 1.0, 0.0]), lift(q2) - q2 * torch.tensor([1.0, 1.0, 0.0]))


def test_noise_models(test_batch):
    p = test_batch["points"]
    g = torch.Generator().manual_seed(0)
    for mm in (10.0, 40.0):
        e = (noise.fixed_gaussian(p, mm / 1000, g) - p).norm(dim=-1).mean()
        assert abs(float(e) * 1000 - mm) < 0.05 * mm
    s = noise.structured(p, g, p_swap=2.0, p_flip=0.0, p_drift=0.0)  # always swap both limb pairs
    li, ri = skeleton.POINT_NAMES.index("left_wrist"), skeleton.POINT_NAMES.index("right_wrist")
    assert (s[:, li] - p[:, ri]).norm(dim=-1).max() < 0.12  # swapped (+ light gaussian)
    for f in (noise.gaussian, noise.uniform, noise.mixed):
        out = f(p, gen=g)
        assert out.shape == p.shape and torch.isfinite(out).all() and not torch.equal(out, p)


def test_training_reduces_validation_loss(body, test_batch, tmp_path, monkeypatch):
    monkeypatch.setattr(T, "work_dir", lambda: tmp_path)
    cfg = T.TrainConfig(batch=32, lr=3e-3, steps={"psi": 400}, eval_every=200, psi_width=32)
    data = {k: v[:48] for k, v in test_batch.items()}
    val = {k: v[48:] for k, v in test_batch.items()}
    torch.manual_seed(cfg.seed)
    fresh = T.Stage("psi", cfg, body, features.template_distances(body))
    with torch.no_grad():
        init = float(fresh.loss(val, torch.Generator().manual_seed(0), False))
    log = T.train_stage("psi", cfg, body, data, val, progress=False)
    hist = log["history"]
    assert len(hist) == 2 and hist[-1]["val_loss"] < 0.9 * init
    assert (tmp_path / "psi" / "best.pt").exists()
    # resuming a finished stage does no more steps
    assert T.train_stage("psi", cfg, body, data, val, progress=False)["history"] == hist


@pytest.mark.skipif(not WEIGHTS.exists(), reason="shipped SMPLR weights not present")
def test_shipped_weights_reconstruct_held_out_bodies(body, test_batch):
    model = SMPLR.load(body)
    with torch.no_grad():
        out = model(test_batch["points"], denoise=False)
        gt = body(test_batch["rotmats"], test_batch["shape"])
    pve = ((out.body.vertices - out.body.joints[:, :1]) - (gt.vertices - gt.joints[:, :1])).norm(dim=-1).mean()
    assert pve < 0.025, f"clean-input PVE {1000 * pve:.1f} mm"
    gender_ok = ((out.shape[:, 0] > 0.5) == (test_batch["shape"][:, 0] > 0.5)).float().mean()
    assert gender_ok > 0.9
    with torch.no_grad():
        lifted = model(test_batch["points"], mode="2d")
    assert lifted.body.vertices.shape == out.body.vertices.shape
    with pytest.raises(ValueError, match="mode"):
        model(test_batch["points"], mode="4d")
    bad = test_batch["points"].clone()
    bad[0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        model(bad)


@pytest.mark.skipif(not WEIGHTS.exists(), reason="shipped SMPLR weights not present")
def test_eval_table_runs_and_clean_beats_noisy(tmp_path):
    assert recon.SMPLR is SMPLR
    md = evaluate_and_report(n=16, out_dir=tmp_path)
    rows = json.loads(md.with_suffix(".json").read_text())["rows"]
    assert len(rows) == 12 and md.read_text().count("\n|") >= 13
    assert rows["Omega+Psi"]["PVE"] < rows["Gaussian 40 mm, DAE"]["PVE"] < rows["Gaussian 40 mm, no DAE"]["PVE"]
    assert rows["Psi (true pose)"]["PVE"] < rows["Omega+Psi"]["PVE"]


def test_lift_and_place_puts_a_known_body_back_where_it_was(body, test_batch):
    """Camera-frame J+ of bodies 4 m in front of a camera, and their projections: SMPLR's bodies
    come back in the camera frame, at the right place, with their roots rotated into it."""
    model = SMPLR.load(body)
    k = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
    with torch.no_grad():
        gt = body(test_batch["rotmats"][:4], test_batch["shape"][:4])  # view frame, pelvis at 0
    pts = camera.to_opencv(gt.points.double().numpy()) + [0.1, 0.2, 4.0]
    uv = camera.project(pts, k)
    b = model.lift_and_place(pts, uv, k, denoise=False)
    assert b.vertices.shape == (4, body.num_vertices, 3) and b.translation.shape == (4, 3)
    err = np.linalg.norm(np.concatenate([b.joints, b.landmarks], 1) - pts, axis=-1).mean()
    assert err < 0.03  # metres: SMPLR's clean-input error (~1 cm) plus placement
    np.testing.assert_allclose(b.joints[:, 0], b.translation, atol=1e-6)
    with torch.no_grad():  # the parameters re-posed in the camera frame give the returned mesh
        again = body(b.rotmats, b.shape, transl=torch.tensor(b.translation, dtype=torch.float32))
    np.testing.assert_allclose(again.vertices.numpy(), b.vertices, atol=1e-4)
