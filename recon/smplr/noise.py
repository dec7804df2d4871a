"""Noise models for training and testing the DAE (thesis 2.3.3 / 2.4.4), on J+ in metres.

* gaussian: isotropic per-point noise, per-sample sigma;
* uniform: per-point box noise with per-point bounds (wider at the extremities);
* structured: left/right limb swaps, depth flips of a limb about its root, and occluded
  points drifting far from their place.
``mixed`` draws one of these per sample, as used for training.
"""
from __future__ import annotations

import torch

from recon.body import skeleton

P = {n: i for i, n in enumerate(skeleton.POINT_NAMES)}
EXTREMITY = torch.tensor([1.5 if any(k in n for k in ("wrist", "hand", "ankle", "foot", "toe", "elbow", "knee"))
                          else 1.0 for n in skeleton.POINT_NAMES])
LIMBS = {
    "left_arm": ["left_elbow", "left_wrist", "left_hand", "left_elbow_back", "left_hand_outer"],
    "right_arm": ["right_elbow", "right_wrist", "right_hand", "right_elbow_back", "right_hand_outer"],
    "left_leg": ["left_knee", "left_ankle", "left_foot", "left_knee_front", "left_toe_tip"],
    "right_leg": ["right_knee", "right_ankle", "right_foot", "right_knee_front", "right_toe_tip"],
}
LIMB_ROOT = {"left_arm": "left_shoulder", "right_arm": "right_shoulder", "left_leg": "left_hip",
             "right_leg": "right_hip"}


def gaussian(points, sigma_max: float = 0.06, gen: torch.Generator | None = None, sigma: float | None = None):
    b = points.shape[0]
    s = torch.full((b, 1, 1), sigma) if sigma is not None else torch.rand(b, 1, 1, generator=gen) * sigma_max
    return points + s * torch.randn(points.shape, generator=gen)


def uniform(points, bound_max: float = 0.06, gen: torch.Generator | None = None):
    b = points.shape[0]
    bound = torch.rand(b, 1, 1, generator=gen) * bound_max * EXTREMITY.view(1, -1, 1)
    return points + bound * (2 * torch.rand(points.shape, generator=gen) - 1)


def structured(points, gen: torch.Generator | None = None, p_swap: float = 0.3, p_flip: float = 0.3,
               p_drift: float = 0.5):
    out = points.clone()
    b = points.shape[0]
    for pair in (("left_arm", "right_arm"), ("left_leg", "right_leg")):
        swap = torch.rand(b, generator=gen) < p_swap / 2
        ia, ib = [P[n] for n in LIMBS[pair[0]]], [P[n] for n in LIMBS[pair[1]]]
        out[swap.nonzero().squeeze(1)[:, None], torch.tensor(ia)] = points[swap][:, ib]
        out[swap.nonzero().squeeze(1)[:, None], torch.tensor(ib)] = points[swap][:, ia]
    for limb, names in LIMBS.items():
        flip = (torch.rand(b, generator=gen) < p_flip / 4).nonzero().squeeze(1)
        idx = torch.tensor([P[n] for n in names])
        root_z = out[flip, P[LIMB_ROOT[limb]], 2][:, None]
        out[flip[:, None], idx, 2] = 2 * root_z - out[flip[:, None], idx, 2]
    drift = torch.rand(b, generator=gen) < p_drift
    k = torch.rand(b, skeleton.NUM_POINTS, generator=gen) < 0.08
    k &= drift[:, None]
    d = torch.randn(b, skeleton.NUM_POINTS, 3, generator=gen)
    d = d / d.norm(dim=-1, keepdim=True) * (0.05 + 0.15 * torch.rand(b, skeleton.NUM_POINTS, 1, generator=gen))
    out = out + d * k[..., None]
    return gaussian(out, 0.02, gen)


def mixed(points, gen: torch.Generator | None = None):
    """Per sample: 40% gaussian, 30% uniform, 30% structured (plus light gaussian)."""
    choice = torch.rand(points.shape[0], generator=gen)
    out = gaussian(points, gen=gen)
    u, s = uniform(points, gen=gen), structured(points, gen=gen)
    out = torch.where((choice >= 0.4)[:, None, None], u, out)
    out = torch.where((choice >= 0.7)[:, None, None], s, out)
    return out


def fixed_gaussian(points, mean_error: float, gen: torch.Generator | None = None):
    """Isotropic noise whose mean per-point displacement is ``mean_error`` (metres)."""
    sigma = mean_error / (8.0 / torch.pi) ** 0.5  # E|N(0, s^2 I3)| = s sqrt(8/pi)
    return points + sigma * torch.randn(points.shape, generator=gen)
