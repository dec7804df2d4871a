"""The trained backbone: soft targets, shipped weights on rendered val images, self-found crops,
online training data."""
import json

import cv2
import numpy as np
import pytest
import roma
import torch

from recon import camera
from recon.backbone.crop import Crop
from recon.backbone.crops import OnlineCrops
from recon.backbone.hourglass import StackedHourglass
from recon.backbone.model import Backbone
from recon.backbone.search import crop_from_keypoints
from recon.backbone.volumetric import soft_argmax_3d, trilinear_target, volumetric_ce
from recon.body import skeleton
from recon.fit import FitConfig
from recon.keypoints import BackboneSource
from recon.pipeline import Reconstructor
from recon.run import RunOptions, run
from recon.smplr.features import template_distances
from recon.synth.dataset import BENCHMARKS
from recon.synth.scene import SceneSampler


def test_trilinear_target_has_the_point_as_its_expectation():
    torch.manual_seed(0)
    shape = (8, 16, 16)
    coords = 0.1 + 0.8 * torch.rand(2, 5, 3, dtype=torch.float64)  # inside the voxel-centre hull
    idx, w, valid = trilinear_target(coords, shape)
    assert valid.all() and torch.allclose(w.sum(-1), torch.ones(2, 5, dtype=torch.float64))
    target = torch.zeros(2, 5, 8 * 16 * 16, dtype=torch.float64).scatter_add_(-1, idx, w)
    logits = torch.log(target.clamp_min(1e-300)).view(2, 5, *shape)
    torch.testing.assert_close(soft_argmax_3d(logits), coords, atol=1e-9, rtol=0)
    # the loss is lowest at the target distribution itself
    assert volumetric_ce(logits, coords) < volumetric_ce(logits + 0.5 * torch.randn_like(logits), coords)


def test_bone_depth_uses_the_predicted_foreshortening(body):
    """A template body turned away from the camera at 6 m: its 2D bones are foreshortened, so the
    fixed-0.85 estimate misses the depth; with the 3D points' own foreshortening it is exact up
    to perspective."""
    template = template_distances(body).cpu().numpy().astype(np.float64)
    with torch.no_grad():
        pts = body(points_only=True).points[0].double()
    pts = pts - pts[:24].mean(0)
    pts = (pts @ roma.rotvec_to_rotmat(torch.tensor([0.0, 1.2, 0.0], dtype=torch.float64)).T).numpy()
    pts[:, 2] += 6.0
    k = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
    uv = pts @ k.T
    uv = uv[:, :2] / uv[:, 2:]
    assert camera.depth_from_bones(uv, k, template, pts) == pytest.approx(6.0, rel=0.02)
    assert abs(camera.depth_from_bones(uv, k, template) / 6.0 - 1) > 0.05
    # the crop is centred on the joints' mean at that depth
    c = crop_from_keypoints(uv, k, template, points=pts)
    assert c.zc == pytest.approx(6.0, rel=0.02)


@pytest.fixture(scope="module")
def val_samples(body, mocap):
    b = BENCHMARKS["synth-val"]
    sampler = SceneSampler(body, b["split"], b["seed"], pool=256)
    return [sampler.sample(i) for i in range(6)]


def _mpjpe(p, gt):
    return float(np.linalg.norm((p[:24] - p[:1]) - (gt[:24] - gt[:1]), axis=1).mean() * 1000)


def test_shipped_weights_beat_an_untrained_network_on_rendered_images(val_samples):
    torch.set_num_threads(1)
    net = Backbone.load()
    untrained = Backbone(StackedHourglass(net.net.cfg))
    eager_net = Backbone.load(jit=False)
    errs = {"trained": [], "untrained": []}
    for s in val_samples:
        crop = Crop.around(s["points3d"][:24].astype(np.float64).mean(0), s["K"].astype(np.float64))
        for name, m in (("trained", net), ("untrained", untrained)):
            pts, uv, conf = m.predict([s["rgb"]], [crop])
            assert pts.shape == (1, 42, 3) and uv.shape == (1, 42, 2) and conf.shape == (1, 42)
            errs[name].append(_mpjpe(pts[0], s["points3d"].astype(np.float64)))
        # the TorchScript trace gives the eager (BN-folded, channels-last) answer
        eager = eager_net.predict([s["rgb"]], [crop])
        for a, e in zip(net.predict([s["rgb"]], [crop]), eager):
            np.testing.assert_allclose(a, e, atol=1e-4)
    # the model card reports ~114 mm on synth-val; an untrained network is > 300 mm
    assert np.mean(errs["trained"]) < 200 < np.mean(errs["untrained"])


def test_flip_averaging_is_mirror_equivariant_and_helps(val_samples):
    """avg(f(x), M f(Mx)) is exactly mirror-equivariant: the mirrored crop gives the mirrored
    answer (left/right points swapped, x -> 1 - x). And on rendered images it is no worse
    than the single pass (synth-val: ~3 mm better, eval/results/synth-test.md)."""
    torch.set_num_threads(1)
    net = Backbone.load()
    crops = []
    for s in val_samples:
        crop = Crop.around(s["points3d"][:24].astype(np.float64).mean(0), s["K"].astype(np.float64))
        crops.append(crop.image(s["rgb"], net.size))
    x = np.stack(crops)
    g, conf = net.grids(x, flip=True)
    gm, confm = net.grids(np.ascontiguousarray(x[:, :, ::-1]), flip=True)
    mirror = list(skeleton.POINT_MIRROR)
    back = gm[:, mirror].clone()
    back[..., 0] = 1 - back[..., 0]
    torch.testing.assert_close(back, g, atol=2e-4, rtol=0)
    torch.testing.assert_close(confm[:, mirror], conf, atol=2e-4, rtol=0)
    errs = {}
    for flip in (False, True):
        errs[flip] = []
        for s in val_samples:
            crop = Crop.around(s["points3d"][:24].astype(np.float64).mean(0), s["K"].astype(np.float64))
            pts, _, _ = net.predict([s["rgb"]], [crop], flip=flip)
            errs[flip].append(_mpjpe(pts[0], s["points3d"].astype(np.float64)))
    assert np.mean(errs[True]) < np.mean(errs[False]) + 2.0


def test_backbone_source_finds_the_person_without_ground_truth(body, val_samples):
    torch.set_num_threads(1)
    src = BackboneSource(body)
    d2, depth = [], []
    for s in val_samples:
        k = s["K"].astype(np.float64)
        kp = src(s["rgb"], k)
        assert kp is not None and kp.points3d.shape == (42, 3) and np.allclose(kp.points3d[0], 0)
        d2.append(np.linalg.norm(kp.points2d[:24] - s["points2d"][:24], axis=1).mean())
        _, _, _, crop = src.search.locate(s["rgb"], k)
        depth.append(crop.zc / s["points3d"][:24, 2].mean())
    assert np.median(d2) < 15  # pixels, 256 x 256 images
    assert 0.7 < np.median(depth) < 1.3


def test_online_crops_are_valid_training_samples(body, mocap):
    it = iter(OnlineCrops(64, seed=3, repeats=2, buffer=4))
    for _ in range(6):
        img, grid, *_ = next(it)
        assert img.shape == (3, 64, 64) and 0 <= img.min() and img.max() <= 1
        assert grid.shape == (42, 3) and ((grid > -0.2) & (grid < 1.2)).all()


def test_recon_run_with_the_backbone_source(tmp_path, val_samples):
    torch.set_num_threads(1)
    cv2.imwrite(str(tmp_path / "synthetic.png"), val_samples[0]["rgb"][..., ::-1])
    rec = Reconstructor(source="backbone", fit=FitConfig(steps=0))
    s = run([tmp_path / "synthetic.png"], tmp_path / "out", RunOptions(overlay=False), reconstructor=rec,
            progress=False, log=lambda *_: None)
    assert s.done == ["synthetic"]
    js = json.loads((tmp_path / "out" / "synthetic" / "result.json").read_text())
    assert js["keypoint_source"] == "backbone" and len(js["joints3d"]) == 24
    assert js["fit"] == {"steps": 0, "silhouette": 0.0}


def test_the_flip_reaches_the_backbone_source():
    assert Reconstructor(source="backbone", flip=True).source.flip
    assert not Reconstructor(source="backbone").source.flip
