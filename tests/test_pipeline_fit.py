"""The fit after SMPLR (recon.fit): the body-model shortcuts it relies on, the silhouette term's
geometry, and a fit that must recover a body's width from its mask."""
import cv2
import numpy as np
import pytest
import torch

from recon import camera
from recon.errors import ReconError
from recon.fit import FitConfig, SilhouetteTarget, fit_body, linear_rest_geometry, mask_weight
from recon.keypoints import Keypoints
from recon.pipeline import Reconstructor
from recon.shape import FROM_MASK, PHENOTYPES
from recon.shape import WEIGHTS as SHAPE_WEIGHTS
from recon.smplr.data import generate
from recon.smplr.lifter import WEIGHTS as LIFTER_WEIGHTS


def test_vertex_subset_and_precomputed_rest_match_full_forward(body):
    torch.manual_seed(0)
    pose, shape = 0.3 * torch.randn(2, 24, 3), torch.rand(2, 6)
    full = body(pose, shape)
    ids = torch.tensor([5, 700, 13000, 42])
    sub = body(pose, shape, vertex_ids=ids)
    assert sub.vertices.shape == (2, 4, 3)
    assert torch.allclose(sub.vertices, full.vertices[:, ids], atol=1e-5)
    assert torch.allclose(sub.landmarks, full.landmarks, atol=1e-5)
    rest = body.rest_geometry(shape, torch.cat([body.landmark_indices, ids]))
    pre = body(pose, None, vertex_ids=ids, rest=rest)
    assert torch.allclose(pre.vertices, sub.vertices) and torch.allclose(pre.joints, full.joints, atol=1e-5)


def test_linearised_rest_geometry_predicts_a_shape_change(body):
    shape = torch.tensor([[0.5, 0.6, 0.4, 0.5, 0.5, 0.5]])
    ids = torch.arange(0, body.num_vertices, 50)
    (v0, j0), (jv, jj) = linear_rest_geometry(body, shape, ids, with_jacobian=True)
    d = torch.tensor([[0.0, 0.0, 0.05, -0.04, 0.03, 0.0]])
    v1, j1 = body.rest_geometry(shape + d, torch.cat([body.landmark_indices, ids]))
    pred_v = v0 + torch.einsum("bnks,bs->bnk", jv, d)
    moved = (v1 - v0).abs().max()
    assert moved > 5e-3  # the change is not negligible ...
    assert (pred_v - v1).abs().max() < 0.05 * moved  # ... and the linear model predicts it
    assert (j0 + torch.einsum("bnks,bs->bnk", jj, d) - j1).abs().max() < 0.05 * moved


def test_silhouette_term_pulls_points_into_the_mask():
    mask = np.zeros((100, 120), bool)
    mask[20:80, 30:70] = True
    target = SilhouetteTarget(mask, (30, 20, 70, 80))
    ys, xs = np.mgrid[20:80, 30:70]
    inside = torch.tensor(np.stack([xs.ravel(), ys.ravel()], 1), dtype=torch.float32)
    shifted = (inside + torch.tensor([5.0, 0.0])).requires_grad_(True)  # ~ the kernel scale (0.05 x 60 px)
    assert target(inside) < 0.1 * target(shifted).detach()
    target(shifted).backward()
    assert shifted.grad[:, 0].sum() > 0 and shifted.grad[:, 0].sum() > 3 * shifted.grad[:, 1].abs().sum()
    # points beyond the image border cost nothing (the body continues outside)
    assert target.outside(torch.tensor([[-50.0, 50.0], [500.0, 10.0]])).abs().max() == 0.0
    assert target.outside(torch.tensor([[50.0, 50.0]])) == 0.0 and target.outside(torch.tensor([[90.0, 50.0]])) > 0.5


def _mask(vertices, faces, k, hw):
    uv = vertices @ k.T
    uv = (uv[:, :2] / uv[:, 2:]).round().astype(np.int32)
    m = np.zeros(hw, np.uint8)
    cv2.fillPoly(m, list(uv[faces]), 1)
    return m.astype(bool)


def _iou(a, b):
    return (a & b).sum() / (a | b).sum()


def test_fit_to_a_mask_corrects_biased_keypoints(body):
    """A person seen by the camera whose detected 2D keypoints are all 8 px to the right (a
    detector bias; the mask is right). Fitting the keypoints alone keeps the body where they
    are; with the mask term the body moves onto the person."""
    hw, k = (256, 256), np.array([[300.0, 0, 128], [0, 300.0, 128], [0, 0, 1]])
    rot = body.identity_pose(1)
    rot[0, 0] = torch.tensor(camera.HALF_TURN_X, dtype=torch.float32)
    shape = torch.tensor([0.5, 0.5, 0.5, 0.9, 0.5, 0.5])
    with torch.no_grad():
        gt = body(rot, shape[None], transl=torch.tensor([[0.0, 0.1, 2.6]]))
    faces = body.faces.numpy()
    gt_mask = _mask(gt.vertices[0].numpy(), faces, k, hw)
    pts = gt.points[0].numpy().astype(np.float64)
    uv = pts @ k.T
    uv = uv[:, :2] / uv[:, 2:] + np.array([8.0, 0.0])
    ys, xs = np.nonzero(gt_mask)
    kp = Keypoints(pts - pts[:1], uv, 1.0, (xs.min(), ys.min(), xs.max(), ys.max()), gt_mask)
    t0 = camera.place(pts - pts[:1], uv, k)
    start_iou = _iou(_mask(gt.vertices[0].numpy() - pts[:1] + t0, faces, k, hw), gt_mask)
    fits = {}
    for silhouette in (0.0, 10.0):
        f = fit_body(body, FitConfig(silhouette=silhouette), rot[0], shape, t0, kp, k, hw)
        fits[silhouette] = _iou(_mask(f.vertices, faces, k, hw), gt_mask), f.shape
        with torch.no_grad():  # the returned mesh is the body at the returned parameters
            again = body(f.rotmats[None], f.shape[None], transl=torch.tensor(f.translation[None], dtype=torch.float32))
        assert np.abs(again.vertices[0].numpy() - f.vertices).max() < 1e-5
    assert torch.equal(fits[0.0][1], shape)  # keypoints alone do not touch the shape
    assert abs(fits[0.0][0] - start_iou) < 0.05
    assert fits[10.0][0] > start_iou + 0.2 and fits[10.0][0] > fits[0.0][0] + 0.2


def test_mask_weight_skips_missing_or_failed_masks():
    cfg = FitConfig(silhouette=10.0)
    pts, uv = np.zeros((42, 3)), np.zeros((42, 2))
    mask = np.zeros((100, 100), bool)
    box = (20.0, 10.0, 60.0, 90.0)
    assert mask_weight(cfg, Keypoints(pts, uv, 1.0, box, None)) == 0.0
    assert mask_weight(cfg, Keypoints(pts, uv, 1.0, box, mask)) == 0.0  # empty: segmentation failed
    mask[10:90, 30:50] = True  # a person-like strip: half of the box
    assert mask_weight(cfg, Keypoints(pts, uv, 1.0, box, mask)) == 10.0
    assert mask_weight(FitConfig(silhouette=0.0), Keypoints(pts, uv, 1.0, box, mask)) == 0.0


@pytest.mark.skipif(not LIFTER_WEIGHTS.exists(), reason="no shipped lifter weights")
def test_reconstructor_lifts_a_sources_2d_in_each_lift_mode(body, mocap):
    """A keypoint source that reports the exact 2D J+ of a held-out body in a camera, and a 3D guess
    that is the true J+ plus a bias: "source" inherits the bias, "camera" (the lifter on the 2D) does
    not, "blend" sits between them, and all three place the body at the right depth."""
    view = generate(body, "test", 1, seed=5, noise_deg=0.0)["points"][0].double().numpy()
    cam = camera.to_opencv(view - view[:1]) + np.array([0.1, 0.2, 3.5])
    k = camera.default_intrinsics(480, 640)
    uv = camera.project(cam, k)
    bias = np.zeros_like(cam)
    bias[:, 2] = np.linspace(-0.25, 0.25, len(cam))  # a depth tilt the 2D cannot show

    def source(rgb, kk):
        return Keypoints(cam - cam[:1] + bias, uv, 1.0, (0.0, 0.0, 640.0, 480.0))
    source.name = "fake"

    img = np.zeros((480, 640, 3), np.uint8)
    err = {}
    for lift in ("source", "camera", "blend"):
        rec = Reconstructor(body=body, source=source, fit=FitConfig(steps=0), lift=lift)
        r = rec(img, k)
        err[lift] = np.linalg.norm((r.joints - r.joints[:1]) - (cam[:24] - cam[:1]), axis=1).mean()
        assert abs(r.translation[2] - 3.5) < 0.5, (lift, r.translation)
    assert err["camera"] < err["source"] and err["camera"] <= err["blend"] <= err["source"] + 1e-3, err


def _seen_body(body, seed: int):
    """A generated body 3 m in front of a 640 x 480 camera: its camera-frame J+, their 2D, its mask
    and the intrinsics."""
    batch = generate(body, "test", 1, seed=seed, noise_deg=0.0)
    with torch.no_grad():
        gt = body(batch["rotmats"], batch["shape"])
    root, offset = gt.points[0, :1].double().numpy(), np.array([0.0, 0.1, 3.0])
    cam = camera.to_opencv(gt.points[0].double().numpy() - root) + offset
    verts = camera.to_opencv(gt.vertices[0].double().numpy() - root) + offset
    k = camera.default_intrinsics(480, 640)
    uv = camera.project(cam, k)
    mask = _mask(verts, body.faces.numpy(), k, (480, 640))
    return cam, uv, mask, k


@pytest.mark.skipif(not SHAPE_WEIGHTS.exists(), reason="no shipped shape head weights")
def test_reconstructor_takes_gender_and_build_from_the_shape_head(body, mocap):
    """A source that reports a body's exact J+ and its mask: with the shape head the body's
    FROM_MASK phenotypes are the head's reading of that mask, the others SMPLR's; without it, all
    SMPLR's. A source without a mask leaves SMPLR's shape."""
    cam, uv, mask, k = _seen_body(body, seed=6)

    def source(rgb, kk, with_mask=True):
        return Keypoints(cam - cam[:1], uv, 1.0, (0.0, 0.0, 640.0, 480.0), mask if with_mask else None)
    source.name = "fake"

    def no_mask(rgb, kk):
        return source(rgb, kk, with_mask=False)
    no_mask.name = "fake"

    img = np.zeros((480, 640, 3), np.uint8)
    cols = [PHENOTYPES.index(p) for p in FROM_MASK]
    others = [i for i in range(len(PHENOTYPES)) if i not in cols]
    plain = Reconstructor(body=body, source=source, fit=FitConfig(steps=0), shape_head=False)(img, k)
    headed = Reconstructor(body=body, source=source, fit=FitConfig(steps=0))
    r = headed(img, k)
    expect = headed.shape_head.predict([mask], [uv])[0]
    np.testing.assert_allclose(r.shape[cols], expect[cols], atol=1e-5)
    np.testing.assert_allclose(r.shape[others], plain.shape[others], atol=1e-5)
    assert "shape" in r.timings_ms
    bare = Reconstructor(body=body, source=no_mask, fit=FitConfig(steps=0))(img, k)
    np.testing.assert_allclose(bare.shape, plain.shape, atol=1e-6)


@pytest.mark.skipif(not SHAPE_WEIGHTS.exists(), reason="no shipped shape head weights")
def test_a_gender_and_height_the_user_gives_are_kept(body):
    """``gender`` fixes anny's gender (1 female, 0 male) through SMPLR and the fit (which moves the
    shape with a mask), with confidence 1; ``height_cm`` sets the height phenotype so the body stands
    that tall; "auto" reports the shape head's confidence |2p - 1|."""
    cam, uv, mask, k = _seen_body(body, seed=7)

    def source(rgb, kk):
        return Keypoints(cam - cam[:1], uv, 1.0, (0.0, 0.0, 640.0, 480.0), mask)
    source.name = "fake"

    img = np.zeros((480, 640, 3), np.uint8)
    g = PHENOTYPES.index("gender")
    for gender, value in (("male", 0.0), ("female", 1.0), ("neutral", 0.5)):
        r = Reconstructor(body=body, source=source, fit=FitConfig(steps=10), gender=gender)(img, k)
        assert r.shape[g] == pytest.approx(value, abs=1e-6) and r.shape_confidence == 1.0
    auto = Reconstructor(body=body, source=source, fit=FitConfig(steps=0))
    r = auto(img, k)
    p = auto.shape_head.predict([mask], [uv])[0, g]
    assert r.shape_confidence == pytest.approx(abs(2 * p - 1), abs=1e-6)
    assert r.to_json()["shape_confidence"] == pytest.approx(r.shape_confidence, abs=1e-3)
    for cm in (160.0, 185.0):
        r = Reconstructor(body=body, source=source, fit=FitConfig(steps=10), height_cm=cm)(img, k)
        assert r.height_m == pytest.approx(cm / 100, abs=0.01)
    with pytest.raises(ReconError):
        Reconstructor(body=body, source=source, gender="other")
