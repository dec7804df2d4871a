"""Inference with the trained volumetric hourglass: image + crop -> J+ in the camera frame.

``Backbone.load()`` reads the shipped weights (``weights/hourglass_base.pt``, see its
MODEL_CARD.md). A crop is the thesis' metric crop (``recon.backbone.crop``): the network was
trained on crops 2.5 m wide centred on the mean joint, so a crop must put the person at that
scale. With ground truth (benchmark protocol) that crop is known; on a photo the crop search
(``recon.backbone.search``) finds it.
"""
from __future__ import annotations

import copy
import logging
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval

from recon import paths
from recon.backbone.crop import Crop
from recon.backbone.hourglass import HourglassConfig, StackedHourglass
from recon.backbone.volumetric import local_mass, soft_argmax_3d
from recon.body import skeleton

log = logging.getLogger(__name__)
WEIGHTS = Path(__file__).parent / "weights" / "hourglass_base.pt"


def inference_copy(net: StackedHourglass) -> StackedHourglass:
    """Eval-mode copy for CPU inference: every BatchNorm that follows a convolution is folded
    into it, and weights are channels-last (oneDNN's fast layout). Same outputs to float
    rounding; faster at batch 1 on one thread, mostly from the layout (benchmarks/bench_backbone_stem.py)."""
    net = copy.deepcopy(net).eval()
    for seq in [m for m in net.modules() if isinstance(m, nn.Sequential)]:
        for i in range(len(seq) - 1):
            if isinstance(seq[i], nn.Conv2d) and isinstance(seq[i + 1], nn.BatchNorm2d):
                seq[i], seq[i + 1] = fuse_conv_bn_eval(seq[i], seq[i + 1]), nn.Identity()
    return net.to(memory_format=torch.channels_last)


def first_stack(net: StackedHourglass) -> StackedHourglass:
    """Copy that stops after the first hourglass (whose heads are supervised like the last's):
    half the cost, for the whole-image pass that only locates the person (what it costs in
    accuracy: eval/results/backbone-crop-search.md)."""
    net = copy.deepcopy(net)
    net.hgs = nn.ModuleList(net.hgs[:1])
    return net


def traced(net: nn.Module, size: int) -> nn.Module:
    """TorchScript trace + freeze of an inference copy (constant-folded weights, fused
    conv+ReLU/add): faster again than eager at batch 1 on one CPU thread, and quick to build.
    torch.jit is deprecated in favour of torch.compile, which compiles this net far more slowly for
    the same speed (docs/backbone.md), so we keep the trace while it works and fall back to eager
    when it does not."""
    x = torch.zeros(1, size, size, 3).permute(0, 3, 1, 2)  # channels-last, like grids' input
    try:
        with torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # deprecation + tracer warnings on the shape check
            return torch.jit.freeze(torch.jit.trace(net, x, check_trace=False, strict=False))
    except Exception as e:  # noqa: BLE001 - any failure of the optional fast path
        log.warning("backbone: TorchScript trace failed (%s); running eager", e)
        return net


class Backbone:
    """Stacked hourglass + soft-argmax decoding. ``predict(images, ks, crops)`` -> (B, 42, 3)
    camera-frame J+ (OpenCV axes, metres), (B, 42, 2) pixels and (B, 42) peak confidences."""

    def __init__(self, net: StackedHourglass, device: str = "cpu", depth_scale=(1.0, 1.0), jit: bool = True,
                 depth_method: str = "bones"):
        self.depth_scale = tuple(depth_scale)  # per crop pass, see recon.backbone.search
        self.depth_method = depth_method  # the crop-depth estimate the factors were calibrated for
        self.net = net.to(device).eval()  # as trained; ``fast`` is what runs
        self.device = torch.device(device)
        self.size = net.cfg.input_size
        self.fast = inference_copy(self.net)
        self.locator = first_stack(self.fast)  # the whole-image pass of BackboneSource
        if jit and self.device.type == "cpu":
            self.fast, self.locator = traced(self.fast, self.size), traced(self.locator, self.size)

    @classmethod
    def load(cls, path: str | Path | None = None, device: str = "cpu", jit: bool = True) -> Backbone:
        """The shipped weights, an exported file or a training run's ``best.pt`` (float16 files
        are read as float32)."""
        return cls.from_checkpoint(paths.load_checkpoint(path or WEIGHTS, "recon backbone train"), device, jit)

    @classmethod
    def from_checkpoint(cls, ck: dict, device: str = "cpu", jit: bool = True) -> Backbone:
        net = StackedHourglass(HourglassConfig(**ck["config"]))
        net.load_state_dict(ck["net"])
        # files calibrated before the foreshortened estimate keep the plain bone-length one
        return cls(net, device, ck.get("crop_depth_scale", (1.0, 1.0)), jit, ck.get("crop_depth_method", "bones"))

    def grids(self, crops_rgb: np.ndarray, locate: bool = False, flip: bool = False
              ) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, S, S, 3) uint8 crops -> grid coordinates (B, 42, 3) and confidences (B, 42): the
        probability mass within one voxel of the expected position. ``locate``: first stack only.
        ``flip``: average with the prediction on the mirrored crop (mirrored back, left/right
        points swapped; the training flip undone), at twice the cost."""
        # (B, S, S, 3) uint8 is already channels-last: permuting gives the layout the fast net wants
        x = torch.from_numpy(np.ascontiguousarray(crops_rgb)).to(self.device).permute(0, 3, 1, 2).float() / 255.0
        b = len(x)
        if flip:
            x = torch.cat([x, x.flip(-1).contiguous(memory_format=torch.channels_last)])
        with torch.no_grad():
            logits = (self.locator if locate else self.fast)(x)[-1][:, :skeleton.NUM_POINTS].float().contiguous()
            g = soft_argmax_3d(logits)
            conf = local_mass(logits, g)
            if flip:
                mirror = list(skeleton.POINT_MIRROR)
                gf, cf = g[b:, mirror].clone(), conf[b:, mirror]
                gf[..., 0] = 1.0 - gf[..., 0]
                g, conf = 0.5 * (g[:b] + gf), 0.5 * (conf[:b] + cf)
            return g.cpu(), conf.cpu()

    def predict(self, images: list[np.ndarray], crops: list[Crop], locate: bool = False, flip: bool = False):
        batch = np.stack([c.image(im, self.size) for im, c in zip(images, crops)])
        g, conf = self.grids(batch, locate, flip)
        pts = np.stack([c.from_grid(gi.double().numpy()) for c, gi in zip(crops, g, strict=True)])
        uv = np.stack([c.pixels(gi.double().numpy()) for c, gi in zip(crops, g, strict=True)])
        return pts, uv, conf.numpy()
