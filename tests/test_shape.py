"""The shape head: crop conventions, outputs, training smoke test, the shipped weights, and
SMPLR taking a known shape."""
import numpy as np
import pytest
import torch

from recon import camera
from recon.shape import PHENOTYPES, WEIGHTS, ShapeHead, ShapeHeadConfig, crop_box, crop_mask
from recon.shape import train as T
from recon.smplr.data import generate
from recon.smplr.model import SMPLR


def person_mask(h=200, w=160, box=(50, 30, 110, 190)):
    m = np.zeros((h, w), bool)
    x0, y0, x1, y1 = box
    m[y0:y1, x0:x1] = True
    return m


def test_crop_box_is_a_square_around_the_points_with_the_margin():
    pts = np.array([[10.0, 20.0], [30.0, 100.0], [20.0, 60.0]])
    cx, cy, side = crop_box(pts, 1.25)
    assert (cx, cy) == (20.0, 60.0) and side == pytest.approx(100.0)


def test_crop_mask_centres_the_box_and_leaves_outside_the_image_empty():
    m = person_mask()
    pts = np.array([[50.0, 30.0], [110.0, 190.0]])
    c = crop_mask(m, crop_box(pts, 1.25), 112)
    assert c.shape == (112, 112) and c.dtype == np.uint8
    rows, cols = np.nonzero(c > 127)
    assert abs(rows.mean() - 55.5) < 1.5 and abs(cols.mean() - 55.5) < 1.5  # the person in the middle
    assert (rows.max() - rows.min() + 1) == pytest.approx(112 / 1.25, abs=2)  # its height fills 1/1.25
    far = crop_mask(m, np.array([-500.0, -500.0, 100.0]), 32)  # a box off the image: background only
    assert far.max() == 0


def test_head_outputs_and_phenotype_range():
    torch.manual_seed(0)
    head = ShapeHead(ShapeHeadConfig(size=64, width=8)).eval()
    raw = head(torch.rand(3, 1, 64, 64))
    assert raw.shape == (3, len(PHENOTYPES))
    p = ShapeHead.phenotypes(raw * 10)
    assert ((p >= 0) & (p <= 1)).all()
    pred = head.predict([person_mask(), person_mask()], [np.array([[50.0, 30.0], [110.0, 190.0]])] * 2)
    assert pred.shape == (2, 6) and np.allclose(pred[0], pred[1])
    assert head.predict([], []).shape == (0, 6)


def test_predict_is_mirror_symmetric():
    """predict averages the crop with its mirror image: a mirrored person gives the same phenotypes."""
    torch.manual_seed(1)
    head = ShapeHead(ShapeHeadConfig(size=64, width=8)).eval()
    m = person_mask()
    m[40:80, 110:140] = True  # an arm on one side
    pts = np.array([[50.0, 30.0], [140.0, 190.0]])
    mirrored_pts = np.array([[160 - 140.0, 30.0], [160 - 50.0, 190.0]])
    a = head.predict([m], [pts])
    b = head.predict([m[:, ::-1].copy()], [mirrored_pts])
    np.testing.assert_allclose(a, b, atol=1e-5)


def test_save_load_round_trip(tmp_path):
    head = ShapeHead(ShapeHeadConfig(size=64, width=8))
    head.save(tmp_path / "h.pt", {"note": "test"}, torch.float16)
    again = ShapeHead.load(tmp_path / "h.pt")
    assert again.cfg == head.cfg and again.meta == {"note": "test"}
    for k, v in head.state_dict().items():
        torch.testing.assert_close(again.state_dict()[k], v.half().float() if v.is_floating_point() else v)


def test_augment_keeps_the_person_and_changes_the_outline():
    rng = np.random.default_rng(0)
    masks = np.stack([crop_mask(person_mask(), np.array([80.0, 110.0, 200.0]), 64)] * 16)
    out = T.augment(masks, rng)
    assert out.shape == masks.shape and out.dtype == np.uint8
    iou = ((out > 127) & (masks > 127)).sum((1, 2)) / ((out > 127) | (masks > 127)).sum((1, 2))
    assert (iou > 0.5).all() and (iou < 1).any()


def test_training_learns_a_separable_gender(tmp_path):
    """Wide bodies female, narrow male: a few hundred steps separate them on held-out crops."""
    rng = np.random.default_rng(0)

    def crops(n):
        g = rng.integers(0, 2, n)
        masks = []
        for gi in g:
            half = (28 if gi else 12) + rng.integers(-3, 4)
            m = np.zeros((64, 64), np.uint8)
            m[8:56, 32 - half // 2:32 + half // 2] = 255
            masks.append(m)
        shape = np.tile(np.array([0, 0.5, 0.5, 0.5, 0.5, 0.5], np.float32), (n, 1))
        shape[:, 0] = g
        return np.stack(masks), shape

    for name, n in (("render", 256), ("val", 64)):
        m, s = crops(n)
        np.savez(tmp_path / f"{name}.npz", masks=m, shape=s)
    cfg = T.ShapeTrainConfig(minutes=0, steps=60, batch=16, eval_every=30, mediapipe_share=0.0)
    meta = T.train([tmp_path / "render.npz"], [], tmp_path / "val.npz", out=tmp_path / "w.pt", cfg=cfg,
                   model_cfg=ShapeHeadConfig(size=64, width=8), run_dir=tmp_path / "run", progress=False)
    assert meta["val_metrics"]["gender_acc"] > 0.9
    assert ShapeHead.load(tmp_path / "w.pt").cfg.size == 64 and not (tmp_path / "run").exists()


def test_smplr_takes_a_known_shape_where_given(body, mocap):
    model = SMPLR.load(body)
    batch = generate(body, "test", 2, seed=7, noise_deg=0.0)
    with torch.no_grad():
        gt = body(batch["rotmats"], batch["shape"])
    k = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
    pts = camera.to_opencv(gt.points.double().numpy()) + [0.0, 0.0, 4.0]
    uv = camera.project(pts, k)
    free = model.lift_and_place(pts, uv, k, denoise=False)
    known = np.full((2, 6), np.nan)
    known[0, 0], known[1, 3] = 1.0 - float(free.shape[0, 0] > 0.5), 0.9
    b = model.lift_and_place(pts, uv, k, denoise=False, shape=known)
    expect = free.shape.clone()
    expect[0, 0], expect[1, 3] = known[0, 0], 0.9
    torch.testing.assert_close(b.shape, expect)
    assert not np.allclose(b.vertices[0], free.vertices[0])  # the other gender is another body


@pytest.mark.skipif(not WEIGHTS.exists(), reason="shape head weights not trained")
def test_shipped_weights_load_and_record_their_validation():
    head = ShapeHead.load()
    assert head.meta["val_metrics"]["gender_acc"] > 0.6
