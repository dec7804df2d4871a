"""Stacked hourglass (Newell et al. 2016) with volumetric heads (thesis 2.4.1).

Each stack outputs (B, P, D, H/4, W/4) logits for P = 42 points (24 joints + 18 landmarks)
plus optional limb volumes; intermediate supervision on every stack.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from recon.backbone.efficientnet import ImageNetStem
from recon.body import skeleton


@dataclass
class HourglassConfig:
    stacks: int = 2
    width: int = 128
    depth_bins: int = 16
    levels: int = 4
    points: int = skeleton.NUM_POINTS
    limbs: int = 0  # extra volumes (thesis: 4 limb heatmaps)
    input_size: int = 256
    stem: str = "hourglass"  # or "efficientnet-lite0": ImageNet-initialisable (recon.backbone.efficientnet)


STEMS = ("hourglass", "efficientnet-lite0")
SIZES = {"cpu": HourglassConfig(stacks=2, width=64, depth_bins=16, input_size=128),
         "base": HourglassConfig(stacks=2, width=128, depth_bins=16, input_size=128),
         "gpu": HourglassConfig(stacks=5, width=256, depth_bins=16, input_size=256, limbs=4)}


class Residual(nn.Module):
    def __init__(self, cin: int, cout: int):
        super().__init__()
        mid = cout // 2
        self.net = nn.Sequential(
            nn.BatchNorm2d(cin), nn.ReLU(inplace=True), nn.Conv2d(cin, mid, 1),
            nn.BatchNorm2d(mid), nn.ReLU(inplace=True), nn.Conv2d(mid, mid, 3, padding=1),
            nn.BatchNorm2d(mid), nn.ReLU(inplace=True), nn.Conv2d(mid, cout, 1))
        self.skip = nn.Identity() if cin == cout else nn.Conv2d(cin, cout, 1)

    def forward(self, x):
        return self.net(x) + self.skip(x)


class Hourglass(nn.Module):
    def __init__(self, levels: int, width: int):
        super().__init__()
        self.up = Residual(width, width)
        self.down = nn.Sequential(nn.MaxPool2d(2), Residual(width, width))
        self.inner = Hourglass(levels - 1, width) if levels > 1 else Residual(width, width)
        self.out = Residual(width, width)

    def forward(self, x):
        y = self.out(self.inner(self.down(x)))
        return self.up(x) + nn.functional.interpolate(y, scale_factor=2, mode="nearest")


class StackedHourglass(nn.Module):
    def __init__(self, cfg: HourglassConfig | None = None, imagenet: bool = False):
        """``imagenet``: start an EfficientNet stem from its ImageNet weights (training only;
        trained weights hold every parameter)."""
        super().__init__()
        cfg = cfg or HourglassConfig()
        if cfg.stem not in STEMS:
            raise ValueError(f"stem must be one of {STEMS}; got {cfg.stem!r}")
        if imagenet and cfg.stem == "hourglass":
            raise ValueError("ImageNet initialisation needs stem='efficientnet-lite0'")
        self.cfg = cfg
        w = cfg.width
        if cfg.stem == "hourglass":
            self.stem = nn.Sequential(nn.Conv2d(3, 64, 7, stride=2, padding=3), nn.BatchNorm2d(64),
                                      nn.ReLU(inplace=True), Residual(64, w // 2), nn.MaxPool2d(2),
                                      Residual(w // 2, w // 2), Residual(w // 2, w))
        else:
            self.stem = ImageNetStem(w, imagenet)
        self.volumes = cfg.points + cfg.limbs
        self.hgs = nn.ModuleList(Hourglass(cfg.levels, w) for _ in range(cfg.stacks))
        self.feats = nn.ModuleList(
            nn.Sequential(Residual(w, w), nn.Conv2d(w, w, 1), nn.BatchNorm2d(w), nn.ReLU(inplace=True))
            for _ in range(cfg.stacks))
        self.heads = nn.ModuleList(nn.Conv2d(w, self.volumes * cfg.depth_bins, 1) for _ in range(cfg.stacks))
        self.merge_f = nn.ModuleList(nn.Conv2d(w, w, 1) for _ in range(cfg.stacks - 1))
        self.merge_h = nn.ModuleList(nn.Conv2d(self.volumes * cfg.depth_bins, w, 1) for _ in range(cfg.stacks - 1))

    def forward(self, images: torch.Tensor) -> list[torch.Tensor]:
        """(B, 3, S, S) images in [0, 1] -> per stack (B, P + limbs, D, S/4, S/4) logits."""
        if images.ndim != 4 or images.shape[1] != 3 or images.shape[2] != images.shape[3]:
            raise ValueError(f"images must be (B, 3, S, S); got {tuple(images.shape)}")
        x = self.stem(images)
        outs = []
        for i, hg in enumerate(self.hgs):
            f = self.feats[i](hg(x))
            h = self.heads[i](f)
            b, _, hh, ww = h.shape
            outs.append(h.view(b, self.volumes, self.cfg.depth_bins, hh, ww))
            if i < len(self.hgs) - 1:
                x = x + self.merge_f[i](f) + self.merge_h[i](h)
        return outs
