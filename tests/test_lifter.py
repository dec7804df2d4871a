"""The camera-aware lifter: ray conventions, the perspective-crop invariance, training data, the
shipped weights."""
import json

import numpy as np
import pytest
import roma
import torch

from recon import camera
from recon.body import skeleton
from recon.smplr import lifter_train as LT
from recon.smplr.data import generate
from recon.smplr.lifter import IN_DIM, WEIGHTS, Lifter, LifterConfig, prepare, rays, to_axis


@pytest.fixture(scope="module")
def views(body, mocap):
    return generate(body, "test", 32, seed=99, noise_deg=0.0)["points"]


def test_rays_follow_the_opencv_convention():
    k = torch.tensor([[[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]])
    uv = torch.tensor([[[320.0, 240.0], [820.0, 240.0], [320.0, 740.0]]])
    r = rays(uv, k)[0]
    assert torch.allclose(r[0], torch.tensor([0.0, 0.0, 1.0]), atol=1e-6)  # principal point: the optical axis
    s = 2 ** -0.5
    assert torch.allclose(r[1], torch.tensor([s, 0.0, s]), atol=1e-6)  # right of centre: +x
    assert torch.allclose(r[2], torch.tensor([0.0, s, s]), atol=1e-6)  # below centre: +y (down)


def test_to_axis_is_the_smallest_rotation_onto_the_optical_axis():
    ray = torch.nn.functional.normalize(torch.tensor([[0.3, -0.2, 1.0], [0.0, 0.0, 1.0], [-0.5, 0.4, 0.6]]), dim=-1)
    r = to_axis(ray)
    assert torch.allclose((r @ ray[..., None])[..., 0], torch.tensor([0.0, 0.0, 1.0]).expand(3, 3), atol=1e-6)
    assert torch.allclose(r[1], torch.eye(3))
    angle = roma.rotmat_to_rotvec(r).norm(dim=-1)
    assert torch.allclose(angle, torch.acos(ray[:, 2]), atol=1e-5)  # no extra twist about the ray


def test_features_do_not_depend_on_where_the_person_is_seen(views):
    """Rotating the camera about its centre moves the person across the image; the network's
    input stays the same up to a roll about the pelvis ray, which the camera's up direction (the
    last three features) carries."""
    p = camera.to_opencv(views[:4] - views[:4, :1]) + torch.tensor([0.0, 0.0, 4.0])
    k = torch.tensor([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]]).expand(4, 3, 3)
    turn = roma.rotvec_to_rotmat(torch.tensor([0.1, -0.25, 0.05]))
    a = prepare(camera.project(p, k), k)
    b = prepare(camera.project(p @ turn.T, k), k)
    assert a.features.shape == (4, IN_DIM)
    n = skeleton.NUM_POINTS
    xa, xb = a.features[:, :2 * n].view(4, n, 2), b.features[:, :2 * n].view(4, n, 2)
    u, _, vt = torch.linalg.svd(xb.transpose(1, 2) @ xa)
    roll = u @ vt  # the best 2D rotation taking a's points onto b's
    assert torch.allclose(xa @ roll.transpose(1, 2), xb, atol=2e-4)
    assert torch.allclose(a.features[:, 2 * n:-3], b.features[:, 2 * n:-3], atol=1e-4)  # visibility, size
    assert torch.allclose(torch.linalg.det(roll), torch.ones(4), atol=1e-4)
    assert not torch.allclose(a.features[:, -3:], b.features[:, -3:], atol=1e-2)


def test_lifted_points_return_to_the_real_camera(views):
    """The targets the lifter learns, mapped back by the same path as its predictions, are the
    camera-frame J+ and pelvis exactly."""
    gen = torch.Generator().manual_seed(0)
    batch = LT.place_in_cameras(views, LT.CameraConfig(), gen)
    inp = prepare(batch["uv_clean"], batch["K"])
    rel, log_zs = LT.targets(inp, batch["points"])
    assert torch.allclose(rel @ inp.rotation, batch["points"] - batch["points"][:, :1], atol=1e-5)
    root = inp.root_ray * (log_zs.exp() / inp.size)[:, None]
    assert torch.allclose(root, batch["points"][:, 0], atol=1e-4)


def test_generated_cameras_frame_the_person(views):
    gen = torch.Generator().manual_seed(1)
    cfg = LT.CameraConfig(bench_share=1.0, noise_scale=(0.0, 0.0))
    b = LT.place_in_cameras(views, cfg, gen)
    h = 2 * b["K"][:, 1, 2]
    span = b["uv"][..., 1].amax(1) - b["uv"][..., 1].amin(1)
    assert ((span / h > 0.4) & (span / h < 0.95)).all()  # the benchmark's framing: 55-90 % of the height
    assert b["visible"][:, 0].all()
    assert torch.equal(b["uv"], b["uv_clean"])  # no noise asked for
    wide = LT.place_in_cameras(views.repeat(8, 1, 1), LT.CameraConfig(bench_share=0.0), gen)
    assert (~wide["visible"]).any()  # some people cut by the frame


def test_residual_bank_is_relative_and_mirrored(tmp_path):
    gt = np.zeros((3, 42, 2))
    gt[..., 1] = np.linspace(0, 200, 42)  # box height 200 px
    pred = gt + np.array([10.0, 0.0])
    path = tmp_path / "r.npz"
    np.savez(path, found=np.array([True, True, False]), points2d=pred, gt_points2d=gt)
    bank = LT.residual_bank(path)
    assert bank.shape == (4, 42, 2)
    assert torch.allclose(bank[:2, :, 0], torch.full((2, 42), 0.05))
    assert torch.allclose(bank[2:, :, 0], torch.full((2, 42), -0.05))  # the mirror image
    assert LT.residual_bank(None) is None


def test_lifter_gradcheck_float64():
    torch.manual_seed(0)
    m = Lifter(LifterConfig(width=16, blocks=1, dropout=0.0)).double().eval()
    k = torch.tensor([[[500.0, 0, 100], [0, 500.0, 100], [0, 0, 1]]], dtype=torch.float64)
    uv = (100 + 40 * torch.randn(1, skeleton.NUM_POINTS, 2, dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(lambda x: m(x, k).points, (uv,), eps=1e-6, atol=1e-5)


def test_training_steps_reduce_the_loss(tmp_path, body, mocap, monkeypatch):
    """A few steps on generated data, saved and loaded back (the command's path, minus size)."""
    small = generate(body, "train", 512, seed=1, noise_deg=0.0)
    monkeypatch.setattr(LT, "load_or_generate", lambda *a, **k: small)
    cfg = LT.LifterTrainConfig(steps=300, batch=64, eval_every=50, val_size=128)
    out = tmp_path / "lifter.pt"
    meta = LT.train(out, cfg, LifterConfig(width=64, blocks=1), run_dir=tmp_path / "run", progress=False)
    curve = [r["val_mpjpe_mm"] for r in meta["curve"]]
    assert min(curve[-2:]) < 0.8 * curve[0], curve
    m = Lifter.load(out)
    pts, root = m.lift(np.full((2, 42, 2), 128.0) + np.random.default_rng(0).normal(0, 30, (2, 42, 2)),
                       np.array([[500.0, 0, 128], [0, 500, 128], [0, 0, 1]]))
    assert pts.shape == (2, 42, 3) and root.shape == (2, 3) and (root[:, 2] > 0).all()
    assert json.loads(torch.load(out, weights_only=True)["meta_json"])["model"]["width"] == 64


@pytest.mark.skipif(not WEIGHTS.exists(), reason="no shipped lifter weights")
def test_shipped_lifter_lifts_clean_2d(views):
    """The shipped lifter on clean 2D of held-out poses in benchmark-like cameras."""
    gen = torch.Generator().manual_seed(5)
    b = LT.place_in_cameras(views, LT.CameraConfig(bench_share=1.0, noise_scale=(0.0, 0.0)), gen)
    m = Lifter.load()
    with torch.no_grad():
        out = m(b["uv"], b["K"], b["visible"])
    rel = b["points"] - b["points"][:, :1]
    err = (out.points - rel)[:, :24].norm(dim=-1).mean() * 1000
    assert err < 80, err
    depth = (out.root[:, 2] / b["points"][:, 0, 2]).log().abs().median()
    assert depth < 0.1
