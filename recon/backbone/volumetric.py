"""Volumetric heatmaps: soft-argmax to coordinates and the softmax cross-entropy loss.

Heatmap logits have shape (B, P, D, H, W) (depth bins, rows, columns); coordinates are grid
coordinates in [0, 1]^3 ordered (x, y, z) = (column, row, depth), voxel centres at (i + 0.5) / n.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F


def _centres(n: int, like: torch.Tensor) -> torch.Tensor:
    return (torch.arange(n, dtype=like.dtype, device=like.device) + 0.5) / n


def soft_argmax_3d(logits: torch.Tensor) -> torch.Tensor:
    """(B, P, D, H, W) logits -> (B, P, 3) expected grid coordinates (differentiable)."""
    b, p, d, h, w = logits.shape
    prob = F.softmax(logits.reshape(b, p, -1), dim=-1).view(b, p, d, h, w)
    x = (prob.sum(dim=(2, 3)) * _centres(w, logits)).sum(-1)
    y = (prob.sum(dim=(2, 4)) * _centres(h, logits)).sum(-1)
    z = (prob.sum(dim=(3, 4)) * _centres(d, logits)).sum(-1)
    return torch.stack([x, y, z], dim=-1)


def voxel_index(coords: torch.Tensor, shape: tuple[int, int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Grid coordinates (B, P, 3) -> flat voxel index (B, P) and a validity mask (inside the volume)."""
    d, h, w = shape
    ix = (coords[..., 0] * w).floor().long()
    iy = (coords[..., 1] * h).floor().long()
    iz = (coords[..., 2] * d).floor().long()
    valid = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h) & (iz >= 0) & (iz < d)
    flat = (iz.clamp(0, d - 1) * h + iy.clamp(0, h - 1)) * w + ix.clamp(0, w - 1)
    return flat, valid


def volumetric_ce(logits: torch.Tensor, coords: torch.Tensor) -> torch.Tensor:
    """Softmax cross-entropy of each point's volume against its ground-truth voxel (thesis
    2.4.1); points outside the volume are ignored."""
    b, p, d, h, w = logits.shape
    flat, valid = voxel_index(coords, (d, h, w))
    ce = F.cross_entropy(logits.reshape(b * p, -1), flat.reshape(-1), reduction="none").view(b, p)
    return (ce * valid).sum() / valid.sum().clamp(min=1)
