"""Body shape from the person's mask: ``ShapeHead``.

SMPLR reads the body shape from the J+; from detected keypoints those carry little of gender
and build (docs/pipeline.md). The person's silhouette does: a small CNN reads the mask, cropped
square around the J+ 2D (``crop_mask``), and regresses anny's six phenotypes (gender as a
logit). It sees the mask only, never the colours, so it learns body outlines rather than the
renders' textures. Trained by ``recon shape train`` (``recon.shape.train``) on our renders' masks
made to look like MediaPipe's.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import nn

from recon import paths

WEIGHTS = Path(__file__).resolve().parent / "weights" / "shape_head.pt"
PHENOTYPES = ("gender", "age", "muscle", "weight", "height", "proportions")  # anny's, in its order
# The gender logit is divided by this at inference: the head, trained on undressed renders, is
# surer than it is right on dressed people; the temperature that calibrates it was fitted on
# other-val (the model card), so that where an outline does not tell the gender stays near 0.5.
GENDER_TEMPERATURE = 3.4


@dataclass
class ShapeHeadConfig:
    size: int = 112  # crop side (pixels)
    width: int = 24  # channels of the first stage; doubled at each of the three others
    margin: float = 1.25  # crop side over the J+ 2D extent
    dropout: float = 0.2


def crop_box(points2d: np.ndarray, margin: float) -> np.ndarray:
    """The square crop around J+ 2D (P, 2): (centre x, centre y, side) in pixels."""
    lo, hi = points2d.min(0), points2d.max(0)
    return np.array([*(0.5 * (lo + hi)), max(float((hi - lo).max()) * margin, 1.0)])


def crop_mask(mask: np.ndarray, box: np.ndarray, size: int) -> np.ndarray:
    """(H, W) bool/uint8 mask -> (size, size) uint8 in {0..255} of the square ``box`` (``crop_box``);
    outside the image is background."""
    cx, cy, side = box
    a = size / side
    m = np.array([[a, 0, size / 2 - a * cx], [0, a, size / 2 - a * cy]], np.float32)
    src = mask.astype(np.uint8) * 255 if mask.dtype == bool else np.ascontiguousarray(mask, np.uint8)
    return cv2.warpAffine(src, m, (size, size), flags=cv2.INTER_AREA, borderValue=0)


def _stage(cin: int, cout: int) -> nn.Sequential:
    """A stride-2 conv then a stride-1 conv, each with batch norm and ReLU."""
    layers = []
    for a, b, s in ((cin, cout, 2), (cout, cout, 1)):
        layers += [nn.Conv2d(a, b, 3, s, 1, bias=False), nn.BatchNorm2d(b), nn.ReLU(inplace=True)]
    return nn.Sequential(*layers)


class ShapeHead(nn.Module):
    """(B, 1, size, size) masks in [0, 1] -> (B, 6) raw outputs: the gender logit, then the
    other five phenotypes (``phenotypes`` maps them into anny's [0, 1])."""

    def __init__(self, cfg: ShapeHeadConfig | None = None):
        super().__init__()
        self.cfg = cfg or ShapeHeadConfig()
        w = self.cfg.width
        self.features = nn.Sequential(_stage(1, w), _stage(w, 2 * w), _stage(2 * w, 4 * w), _stage(4 * w, 8 * w),
                                      nn.AdaptiveAvgPool2d(1), nn.Flatten())
        self.out = nn.Sequential(nn.Dropout(self.cfg.dropout), nn.Linear(8 * w, len(PHENOTYPES)))

    def forward(self, masks: torch.Tensor) -> torch.Tensor:
        return self.out(self.features(masks))

    @staticmethod
    def phenotypes(raw: torch.Tensor) -> torch.Tensor:
        """Raw outputs -> phenotypes in [0, 1] (gender: the probability of female)."""
        return torch.cat([torch.sigmoid(raw[:, :1]), raw[:, 1:].clamp(0.0, 1.0)], 1)

    @torch.no_grad()
    def read(self, crops: np.ndarray, temperature: float | None = None) -> np.ndarray:
        """(B, size, size) uint8 mask crops -> (B, 6) phenotypes (eval mode); the raw outputs are
        averaged with the mirrored crop's (gender and build do not change in a mirror), the gender
        logit divided by ``temperature`` (default ``GENDER_TEMPERATURE``)."""
        self.eval()
        x = torch.tensor(crops, dtype=torch.float32, device=next(self.parameters()).device)[:, None] / 255.0
        raw = 0.5 * (self(x) + self(x.flip(3)))
        raw[:, 0] /= GENDER_TEMPERATURE if temperature is None else temperature
        return self.phenotypes(raw).cpu().numpy().astype(np.float64)

    def predict(self, masks: list[np.ndarray], points2d: list[np.ndarray]) -> np.ndarray:
        """Full-image person masks and their J+ 2D -> (B, 6) phenotypes (``read`` of their crops)."""
        if not masks:
            return np.zeros((0, len(PHENOTYPES)))
        return self.read(np.stack([crop_mask(m, crop_box(p, self.cfg.margin), self.cfg.size)
                                   for m, p in zip(masks, points2d, strict=True)]))

    @classmethod
    def load(cls, path: str | Path | None = None) -> ShapeHead:
        ck = paths.load_checkpoint(path or WEIGHTS, "recon shape train")
        model = cls(ShapeHeadConfig(**ck["cfg"]))
        model.load_state_dict({k: v.float() for k, v in ck["state"].items()})
        model.meta = json.loads(ck.get("meta_json", "{}"))
        return model.eval()

    def save(self, path: str | Path, meta: dict, dtype: torch.dtype = torch.float32) -> None:
        state = paths.cast_floats(self.state_dict(), dtype)
        paths.atomic_write(path, lambda t: torch.save({"cfg": asdict(self.cfg), "state": state,
                                                       "meta_json": json.dumps(meta)}, t))
