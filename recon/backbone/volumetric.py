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


def trilinear_target(coords: torch.Tensor, shape: tuple[int, int, int]
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Split each point's unit mass over its 8 surrounding voxel centres (trilinear weights).

    Unlike a one-hot voxel, the target's expectation equals the point itself, so a network
    trained with cross-entropy against it is not pulled to voxel centres (a one-hot target on
    16 depth bins of a 2.5 m volume costs ~4 cm of quantisation per axis). Returns flat indices
    (B, P, 8), weights (B, P, 8) and validity (B, P); mass falling outside the volume is clamped
    onto its border voxel."""
    d, h, w = shape
    idx, wts = [], []
    per_axis = []
    for c, n in ((coords[..., 0], w), (coords[..., 1], h), (coords[..., 2], d)):
        t = c * n - 0.5  # continuous voxel index (centres at integers)
        lo = t.floor()
        frac = t - lo
        lo = lo.long()
        per_axis.append(((lo.clamp(0, n - 1), 1 - frac), ((lo + 1).clamp(0, n - 1), frac)))
    for ix, wx in per_axis[0]:
        for iy, wy in per_axis[1]:
            for iz, wz in per_axis[2]:
                idx.append((iz * h + iy) * w + ix)
                wts.append(wx * wy * wz)
    valid = ((coords >= 0) & (coords <= 1)).all(-1)
    return torch.stack(idx, -1), torch.stack(wts, -1), valid


def volumetric_ce(logits: torch.Tensor, coords: torch.Tensor) -> torch.Tensor:
    """Softmax cross-entropy of each point's volume against its ground-truth location (thesis
    2.4.1), with the mass split trilinearly over the 8 nearest voxels (see ``trilinear_target``);
    points outside the volume are ignored."""
    b, p, d, h, w = logits.shape
    idx, wts, valid = trilinear_target(coords, (d, h, w))
    x = logits.reshape(b, p, -1)
    logp = F.log_softmax(x if x.dtype == torch.float64 else x.float(), dim=-1)  # bf16/fp16 logits: in float32
    ce = -(logp.gather(-1, idx) * wts).sum(-1)
    return (ce * valid).sum() / valid.sum().clamp(min=1)


def local_mass(logits: torch.Tensor, coords: torch.Tensor) -> torch.Tensor:
    """Probability mass of the (up to) 3x3x3 voxels around each point's voxel: a peak
    confidence in [0, 1]. (B, P, D, H, W) logits, (B, P, 3) grid coordinates -> (B, P).

    Reads 27 logits per point instead of box-filtering the whole volume (the cheaper of the two);
    voxels outside the volume count as zero mass."""
    b, p, d, h, w = logits.shape
    flat = logits.reshape(b, p, -1)
    lse = torch.logsumexp(flat, -1, keepdim=True)
    centre = torch.stack([(coords[..., 2] * d).floor(), (coords[..., 1] * h).floor(), (coords[..., 0] * w).floor()], -1)
    steps = torch.arange(-1, 2, device=logits.device)
    offsets = torch.stack(torch.meshgrid(steps, steps, steps, indexing="ij"), -1).view(27, 3)
    idx = centre.clamp(torch.zeros(3, device=logits.device), torch.tensor([d - 1, h - 1, w - 1], device=logits.device))
    idx = idx.long()[..., None, :] + offsets  # (B, P, 27, 3) as (z, y, x)
    size = torch.tensor([d, h, w], device=logits.device)
    inside = ((idx >= 0) & (idx < size)).all(-1)
    idx = torch.minimum(idx.clamp_min(0), size - 1)
    lin = (idx[..., 0] * h + idx[..., 1]) * w + idx[..., 2]
    return ((flat.gather(-1, lin) - lse).exp() * inside).sum(-1)
