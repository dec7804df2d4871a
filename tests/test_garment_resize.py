"""Outfit resizing (thesis 5.5.6): tightness convention, a short training run, the Dresser hook."""
import numpy as np
import torch

from recon.garment import resize, store
from recon.garment.dress import Dresser
from recon.garment.pbns.model import trained_outfit
from recon.garment.pbns.train import train_resizer
from recon.garment.templates import PRESETS
from recon.paths import load_checkpoint

PBNS_FILE = store.SHIPPED_DIR / "pbns_top-shorts.pt"


def _girth(v: np.ndarray, body_v: np.ndarray) -> float:
    """Mean horizontal distance of cloth vertices from the body's vertical axis."""
    c = body_v.mean(0)
    return float(np.linalg.norm((v - c)[:, [0, 2]], axis=1).mean())


def test_transfer_tightness_is_looser_when_positive(body):
    outfit, shape0, _ = trained_outfit(body, PBNS_FILE)
    tr = resize.Transfer(body, outfit.vertices, outfit.faces, shape0)
    s = shape0[None].float()
    same = tr(s, torch.zeros(1, 2))[0]
    np.testing.assert_allclose(same, outfit.vertices, atol=1e-6)  # own shape, no tightness: the template
    with torch.no_grad():
        bv = body.rest_geometry(s)[0][0].numpy()
    loose, tight = tr(s, torch.tensor([[0.3, 0.0]]))[0], tr(s, torch.tensor([[-0.1, 0.0]]))[0]
    assert _girth(tight, bv) < _girth(same, bv) < _girth(loose, bv)


def test_resizer_trains_and_feeds_the_dresser(body, tmp_path, monkeypatch):
    torch.set_num_threads(1)
    cfg = resize.ResizeConfig(samples=16, val_samples=4, epochs=3, batch=8)
    out = tmp_path / "resize_top-shorts.pt"
    meta = train_resizer(body, PBNS_FILE, out, cfg, log=lambda *_: None, progress=False)
    assert out.exists() and len(meta["curve"]) == 3 and not list(tmp_path.glob(".*.run"))
    assert np.isfinite(meta["curve"][-1]["val_collision_pct"])
    outfit, _, _ = trained_outfit(body, PBNS_FILE)
    rz = resize.OutfitResizer(body, out, outfit.vertices, outfit.faces)
    shape = body.mean_shape.clone()
    v = rz.rest(shape, torch.tensor([0.1, 0.0]))
    base = rz.rest(shape, torch.tensor([0.1, 0.0]), corrected=False)
    assert v.shape == (1, len(outfit.vertices), 3) and not torch.equal(v, base)
    # the Dresser picks up a resizer file named after the outfit and accepts a tightness
    monkeypatch.setattr(store, "resizer_path", lambda outfit, pbns=None: tmp_path / f"resize_{outfit}.pt")
    d = Dresser("top-shorts")
    rot = torch.eye(3).expand(1, 24, 3, 3).clone()
    dressed = d(body, rot, shape[None], tightness=(0.1, 0.0))
    assert dressed.vertices.shape == (1, len(outfit.vertices), 3) and np.isfinite(dressed.vertices).all()


def test_every_shipped_outfit_has_a_resizer_for_its_template():
    for name in PRESETS:
        rest = load_checkpoint(store.pbns_path(name), "recon garment train")["state"]["rest"]
        ck = load_checkpoint(store.resizer_path(name), "recon garment resize")
        assert ck["num_vertices"] == len(rest) and ck["state"]["D"].shape[1] == len(rest), name
