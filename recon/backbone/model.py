"""Inference with the trained volumetric hourglass: image + crop -> J+ in the camera frame.

``Backbone.load()`` reads the shipped weights (``weights/hourglass_base.pt``, see its
MODEL_CARD.md). A crop is the thesis' metric crop (``recon.backbone.crop``): the network was
trained on crops 2.5 m wide centred on the mean joint, so a crop must put the person at that
scale. With ground truth (benchmark protocol) that crop is known; on a photo,
``BackboneSource`` finds it by itself: a first pass on the whole image, then crops re-centred
on the predicted joints at the depth where the template's bone lengths match the 2D bones.
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
from recon.backbone.crop import EXTENT_M, Crop
from recon.backbone.hourglass import HourglassConfig, StackedHourglass
from recon.backbone.volumetric import local_mass, soft_argmax_3d
from recon.body import skeleton

log = logging.getLogger(__name__)
WEIGHTS = Path(__file__).parent / "weights" / "hourglass_base.pt"


def inference_copy(net: StackedHourglass) -> StackedHourglass:
    """Eval-mode copy for CPU inference: every BatchNorm that follows a convolution is folded
    into it, and weights are channels-last (oneDNN's fast layout). Same outputs to float
    rounding; ~1.2x faster at batch 1 on one thread, mostly from the layout."""
    net = copy.deepcopy(net).eval()
    for seq in [m for m in net.modules() if isinstance(m, nn.Sequential)]:
        for i in range(len(seq) - 1):
            if isinstance(seq[i], nn.Conv2d) and isinstance(seq[i + 1], nn.BatchNorm2d):
                seq[i], seq[i + 1] = fuse_conv_bn_eval(seq[i], seq[i + 1]), nn.Identity()
    return net.to(memory_format=torch.channels_last)


def traced(net: nn.Module, size: int) -> nn.Module:
    """TorchScript trace + freeze of an inference copy (constant-folded weights, fused
    conv+ReLU/add): ~25% faster again than eager at batch 1 on one CPU thread, ~1 s to build.
    torch.jit is deprecated in favour of torch.compile, which takes ~35 s to compile this net on
    the 2-core CPU for the same speed, so we keep the trace while it works and fall back to eager
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

    def __init__(self, net: StackedHourglass, device: str = "cpu", depth_scale=(1.0, 1.0), jit: bool = True):
        self.depth_scale = tuple(depth_scale)  # per crop pass, see calibrate_depth_scale
        self.net = net.to(device).eval()  # as trained; ``fast`` is what runs
        self.device = torch.device(device)
        self.size = net.cfg.input_size
        self.fast = inference_copy(self.net)
        if jit and self.device.type == "cpu":
            self.fast = traced(self.fast, self.size)

    @classmethod
    def load(cls, path: str | Path | None = None, device: str = "cpu", jit: bool = True) -> "Backbone":
        ck = paths.load_checkpoint(path or WEIGHTS, "recon backbone train")
        net = StackedHourglass(HourglassConfig(**ck["config"]))
        net.load_state_dict(ck["net"])
        return cls(net, device, ck.get("crop_depth_scale", (1.0, 1.0)), jit)

    def grids(self, crops_rgb: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, S, S, 3) uint8 crops -> grid coordinates (B, 42, 3) and confidences (B, 42): the
        probability mass within one voxel of the expected position."""
        # (B, S, S, 3) uint8 is already channels-last: permuting gives the layout the fast net wants
        x = torch.from_numpy(np.ascontiguousarray(crops_rgb)).to(self.device).permute(0, 3, 1, 2).float() / 255.0
        with torch.no_grad():
            logits = self.fast(x)[-1][:, :skeleton.NUM_POINTS].float().contiguous()
            g = soft_argmax_3d(logits)
            return g.cpu(), local_mass(logits, g).cpu()

    def predict(self, images: list[np.ndarray], crops: list[Crop]):
        batch = np.stack([c.image(im, self.size) for im, c in zip(images, crops)])
        g, conf = self.grids(batch)
        pts = np.stack([c.from_grid(gi.double().numpy()) for c, gi in zip(crops, g)])
        uv = np.stack([np.stack([c.u0 + gi[:, 0].double().numpy() * c.side, c.v0 + gi[:, 1].double().numpy() * c.side], 1)
                       for c, gi in zip(crops, g)])
        return pts, uv, conf.numpy()


def depth_from_bones(uv: np.ndarray, k: np.ndarray, template: np.ndarray, foreshortening: float = 0.85) -> float:
    """Camera distance at which the template's J+ bone lengths match the 2D bones (median over
    the 41 links; 0.85 = typical foreshortening, as in the SMPLR 2D oracle)."""
    xy = (uv - k[:2, 2]) / k[[0, 1], [0, 1]]
    d2 = np.linalg.norm(xy[1:] - xy[list(skeleton.KINTREE_PLUS[1:])], axis=1)
    return float(foreshortening * np.median(template / np.maximum(d2, 1e-6)))


def crop_from_keypoints(uv: np.ndarray, k: np.ndarray, template: np.ndarray, depth_scale: float = 1.0) -> Crop:
    """Metric crop around 2D joints: centre = mean of the 24 joints back-projected at the
    bone-length depth times ``depth_scale``."""
    z = depth_from_bones(uv, k, template) * depth_scale
    c = uv[:24].mean(0)
    centre = np.array([(c[0] - k[0, 2]) * z / k[0, 0], (c[1] - k[1, 2]) * z / k[1, 1], z])
    return Crop.around(centre, k)


def whole_image_crop(shape: tuple[int, ...], k: np.ndarray) -> Crop:
    """Square crop over the whole image (first pass before the person is located)."""
    h, w = shape[:2]
    side = float(max(h, w))
    return Crop((w - side) / 2, (h - side) / 2, side, float(k[0, 0] * EXTENT_M / side), k)


def calibrate_depth_scale(source, samples, passes: int = 2) -> tuple[float, ...]:
    """Median (true crop depth / estimated crop depth) after each of the first ``passes`` passes
    of ``source`` (a BackboneSource) over ``samples`` (dicts with rgb, K, points3d). Run on
    synth-val; the factors absorb the 2D heuristic's bias and the network's pull towards the
    crop centre (which shrinks 2D bones when the person is small in the first pass)."""
    scale: list[float] = []
    for p in range(passes):
        ratios = []
        for s in samples:
            k = s["K"].astype(np.float64)
            _, uv, _, _ = source.locate(s["rgb"], k, depth_scale=scale + [1.0], passes=p + 1)
            z_true = float(s["points3d"][:24].astype(np.float64).mean(0)[2])
            ratios.append(z_true / crop_from_keypoints(uv, k, source.template).zc)
        scale.append(float(np.median(ratios)))
    return tuple(scale)


def export(run_dir: Path, out: Path = WEIGHTS, calibrate_on: int = 300) -> Path:
    """Shipped weights from a training run: its best checkpoint, the training config, and the
    crop-depth factors calibrated on the first ``calibrate_on`` synth-val images."""
    import json

    from recon.body import default_body
    from recon.pipeline import BackboneSource
    from recon.synth.dataset import SynthDataset, bench_dir

    run_dir = Path(run_dir)
    ck = torch.load(run_dir / "best.pt", map_location="cpu", weights_only=True)
    curve = json.loads((run_dir / "curve.json").read_text())
    ck = {"net": ck["net"], "config": ck["config"], "step": ck["step"], "val_mpjpe_mm": ck["val_mpjpe_mm"],
          "train_config": curve["config"]}
    if curve["config"].get("init"):  # fine-tuned: keep the starting weights' provenance
        start = torch.load(curve["config"]["init"], map_location="cpu", weights_only=True)
        ck["fine_tuned_from"] = {k: start[k] for k in ("train_config", "step", "val_mpjpe_mm", "fine_tuned_from")
                                 if k in start}
    tmp = out.with_suffix(".uncalibrated.pt")
    torch.save(ck, tmp)
    ds = SynthDataset(bench_dir("synth-val"))
    ck["crop_depth_scale"] = calibrate_depth_scale(BackboneSource(default_body(), weights=tmp),
                                                   [ds[i] for i in range(calibrate_on)])
    tmp.unlink()
    paths.atomic_write(out, lambda t: torch.save(ck, t))
    return out
