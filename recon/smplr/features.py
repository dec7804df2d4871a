"""SMPLR input features (thesis eq. 2.1-2.3) over J+ = 24 joints + 18 landmarks.

N_i = unit(J+_i - J+_kappa(i)) feeds the pose network Omega (scale-free); B_i = |J+_i -
J+_kappa(i)| - B*_i, relative to the mean body's template distances B*, feeds the shape
network Psi (rotation-free). i runs over the 41 non-root points; kappa = KINTREE_PLUS.
"""
from __future__ import annotations

import torch

from recon.body import skeleton
from recon.body.base import BodyModel

CHILDREN = torch.arange(1, skeleton.NUM_POINTS)
PARENTS = torch.tensor(skeleton.KINTREE_PLUS[1:])


def relative_vectors(points: torch.Tensor) -> torch.Tensor:
    """(B, 42, 3) -> (B, 41, 3) child minus parent along the SMPLR tree."""
    if points.ndim != 3 or points.shape[1:] != (skeleton.NUM_POINTS, 3):
        raise ValueError(f"J+ must have shape (B, {skeleton.NUM_POINTS}, 3); got {tuple(points.shape)}")
    return points[:, CHILDREN] - points[:, PARENTS]


def normalized_relative(points: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """N of eq. 2.1, flattened: (B, 123)."""
    v = relative_vectors(points)
    return (v / v.norm(dim=-1, keepdim=True).clamp(min=eps)).flatten(1)


def relative_distances(points: torch.Tensor, template: torch.Tensor) -> torch.Tensor:
    """B of eq. 2.3: (B, 41), with ``template`` = B* (41,) from the mean body in rest pose."""
    return relative_vectors(points).norm(dim=-1) - template


def template_distances(body: BodyModel) -> torch.Tensor:
    with torch.no_grad():
        return relative_vectors(body(points_only=True).points).norm(dim=-1)[0]


def centre(points: torch.Tensor, planar: bool = False) -> torch.Tensor:
    """Subtract the centroid (of x, y only when ``planar``: depth is unknown when lifting).
    The DAE works centroid-centred: it fixes the shape of J+, not where it is."""
    c = points.mean(1, keepdim=True)
    if planar:
        c = c * c.new_tensor([1.0, 1.0, 0.0])
    return points - c
