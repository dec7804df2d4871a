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


def first_stack(net: StackedHourglass) -> StackedHourglass:
    """Copy that stops after the first hourglass (whose heads are supervised like the last's):
    half the cost, for the whole-image pass that only locates the person. On synth-val images
    300-799 the three-pass MPJPE is 135.1 mm with it, 134.7 without (crop factors recalibrated;
    eval/results/backbone-crop-search.md)."""
    net = copy.deepcopy(net)
    net.hgs = nn.ModuleList(net.hgs[:1])
    return net


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

    def __init__(self, net: StackedHourglass, device: str = "cpu", depth_scale=(1.0, 1.0), jit: bool = True,
                 depth_method: str = "bones"):
        self.depth_scale = tuple(depth_scale)  # per crop pass, see calibrate_depth_scale
        self.depth_method = depth_method  # the crop-depth estimate the factors were calibrated for
        self.net = net.to(device).eval()  # as trained; ``fast`` is what runs
        self.device = torch.device(device)
        self.size = net.cfg.input_size
        self.fast = inference_copy(self.net)
        self.locator = first_stack(self.fast)  # the whole-image pass of BackboneSource
        if jit and self.device.type == "cpu":
            self.fast, self.locator = traced(self.fast, self.size), traced(self.locator, self.size)

    @classmethod
    def load(cls, path: str | Path | None = None, device: str = "cpu", jit: bool = True) -> "Backbone":
        ck = paths.load_checkpoint(path or WEIGHTS, "recon backbone train")
        net = StackedHourglass(HourglassConfig(**ck["config"]))
        net.load_state_dict(ck["net"])
        # files calibrated before the foreshortened estimate keep the plain bone-length one
        return cls(net, device, ck.get("crop_depth_scale", (1.0, 1.0)), jit, ck.get("crop_depth_method", "bones"))

    def grids(self, crops_rgb: np.ndarray, locate: bool = False, flip: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
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
        pts = np.stack([c.from_grid(gi.double().numpy()) for c, gi in zip(crops, g)])
        uv = np.stack([np.stack([c.u0 + gi[:, 0].double().numpy() * c.side, c.v0 + gi[:, 1].double().numpy() * c.side], 1)
                       for c, gi in zip(crops, g)])
        return pts, uv, conf.numpy()


def depth_from_bones(uv: np.ndarray, k: np.ndarray, template: np.ndarray, points: np.ndarray | None = None,
                     foreshortening: float = 0.85) -> float:
    """Camera distance at which the template's J+ bone lengths match the 2D bones (median over
    the 41 links). Each bone's foreshortening (its image-plane share of its 3D length) comes from
    the predicted J+ ``points`` (camera frame) when given, else is the typical 0.85 (as in the
    SMPLR 2D oracle). Per bone it cuts the median depth error after three passes from 7.8 to
    6.5 % on synth-val (eval/results/backbone-crop-search.md; most of the rest is body size)."""
    xy = (uv - k[:2, 2]) / k[[0, 1], [0, 1]]
    parents = list(skeleton.KINTREE_PLUS[1:])
    d2 = np.linalg.norm(xy[1:] - xy[parents], axis=1)
    if points is not None:
        d3 = points[1:] - points[parents]
        foreshortening = np.linalg.norm(d3[:, :2], axis=1) / np.maximum(np.linalg.norm(d3, axis=1), 1e-6)
    return float(np.median(foreshortening * template / np.maximum(d2, 1e-6)))


def crop_from_keypoints(uv: np.ndarray, k: np.ndarray, template: np.ndarray, depth_scale: float = 1.0,
                        points: np.ndarray | None = None) -> Crop:
    """Metric crop around 2D joints: centre = mean of the 24 joints back-projected at the
    bone-length depth (foreshortened by ``points``, see depth_from_bones) times ``depth_scale``."""
    z = depth_from_bones(uv, k, template, points) * depth_scale
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
    of ``source`` (a BackboneSource) over ``samples`` (dicts with rgb, K, points3d), for the
    estimate ``source.net.depth_method`` names. Run on synth-val; the factors absorb the
    template's size against the sampled bodies and the network's pull towards the crop centre
    (which shrinks 2D bones when the person is small in the first pass)."""
    scale: list[float] = []
    for p in range(passes):
        ratios = []
        for s in samples:
            k = s["K"].astype(np.float64)
            # the crop of pass p + 2 is the raw estimate after pass p + 1 (each pass as at run time)
            _, _, _, crop = source.locate(s["rgb"], k, depth_scale=scale + [1.0], passes=p + 2)
            ratios.append(float(s["points3d"][:24].astype(np.float64).mean(0)[2]) / crop.zc)
        scale.append(float(np.median(ratios)))
    return tuple(scale)


DEPTH_METHOD = "foreshortened"  # what export and calibrate write


def _calibrated(ck: dict, tmp: Path, calibrate_on: int) -> dict:
    """``ck`` with crop-depth factors for ``DEPTH_METHOD`` calibrated on the first
    ``calibrate_on`` synth-val images (``tmp``: where the network is written for BackboneSource)."""
    from recon.body import default_body
    from recon.pipeline import BackboneSource
    from recon.synth.dataset import SynthDataset, bench_dir

    ck = ck | {"crop_depth_method": DEPTH_METHOD, "crop_depth_scale": (1.0, 1.0)}
    torch.save(ck, tmp)
    try:
        ds = SynthDataset(bench_dir("synth-val"))
        scale = calibrate_depth_scale(BackboneSource(default_body(), weights=tmp), [ds[i] for i in range(calibrate_on)])
    finally:
        tmp.unlink()
    return ck | {"crop_depth_scale": scale}


def calibrate(weights: Path, out: Path | None = None, calibrate_on: int = 300) -> Path:
    """(Re)calibrate the crop-depth factors of a weights file for the current estimate
    (``DEPTH_METHOD``) on the first ``calibrate_on`` synth-val images; writes ``out`` (default:
    in place, atomically)."""
    weights = Path(weights)
    ck = _calibrated(paths.load_checkpoint(weights, "recon backbone train + export"),
                     weights.with_suffix(".uncalibrated.pt"), calibrate_on)
    out = Path(out or weights)
    paths.atomic_write(out, lambda t: torch.save(ck, t))
    return out


def export(run_dir: Path, out: Path = WEIGHTS, calibrate_on: int = 300) -> Path:
    """Shipped weights from a training run: its best checkpoint, the training config, and the
    crop-depth factors calibrated on the first ``calibrate_on`` synth-val images."""
    import json

    run_dir = Path(run_dir)
    ck = torch.load(run_dir / "best.pt", map_location="cpu", weights_only=True)
    curve = json.loads((run_dir / "curve.json").read_text())
    ck = {"net": ck["net"], "config": ck["config"], "step": ck["step"], "val_mpjpe_mm": ck["val_mpjpe_mm"],
          "train_config": curve["config"]}
    if curve["config"].get("init"):  # fine-tuned: keep the starting weights' provenance
        start = torch.load(curve["config"]["init"], map_location="cpu", weights_only=True)
        ck["fine_tuned_from"] = {k: start[k] for k in ("train_config", "step", "val_mpjpe_mm", "fine_tuned_from")
                                 if k in start}
    ck = _calibrated(ck, Path(out).with_suffix(".uncalibrated.pt"), calibrate_on)  # out replaced only when done
    paths.atomic_write(out, lambda t: torch.save(ck, t))
    return out
