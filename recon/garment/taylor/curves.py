"""Curves and checks of the Taylor model beside its table (``taylor.eval``): the model with fewer
anchors or pose examples (subsets of its database, no rebuild), and the paper's separability
check (section 4.2).
"""
from __future__ import annotations

import numpy as np
import roma
import torch

from recon.garment.data import posed_bodies
from recon.garment.taylor.model import TaylorGarment
from recon.garment.taylor.train import TaylorBuildConfig, cluster_anchors, drape_poses


def subset(model: TaylorGarment, joint_weights: torch.Tensor, n: int) -> TaylorGarment:
    """The model with ``n`` of its anchors (clustered like the database's, the member nearest each
    centre; its pose examples kept): the error-against-anchors curve without a database per count."""
    idx = torch.from_numpy(cluster_anchors(model.anchors, joint_weights, n))
    res = model.pose_residual
    if res is not None and not model.separate_examples:
        res = res[idx]
    return TaylorGarment(model.pbns, model.anchors[idx], model.q, model.basis[idx], model.maps[idx], model.shape0,
                         model.cfg, res, pose_examples=model.pose_examples)


def example_subset(model: TaylorGarment, joint_weights: torch.Tensor, n: int) -> TaylorGarment:
    """The model with ``n`` of its pose examples: its anchors alone when ``n`` is their number (the
    database without examples of its own), else ``n`` clustered among all of them."""
    a = len(model.anchors)
    if n == a:
        res, examples = model.pose_residual[:a], None
    else:
        idx = torch.from_numpy(cluster_anchors(model.pose_examples, joint_weights, n))
        res, examples = model.pose_residual[idx], model.pose_examples[idx]
    return TaylorGarment(model.pbns, model.anchors, model.q, model.basis, model.maps, model.shape0, model.cfg, res,
                         pose_examples=examples)


def separability(cfg: TaylorBuildConfig, taylor: TaylorGarment, body, anchors: list[int], radii: tuple[float, ...],
                 samples: int, seed: int = 0) -> list[dict]:
    """The paper's 4.2: bodies and poses at distance r from an anchor (a random direction over the
    72 joint-rotation components, rad, and the 6 phenotypes); error of eq. 3 to the drape there,
    practical (the model's pose model with its example corrections and the anchor's shape model)
    and theoretical (each term the drape itself)."""
    rng = np.random.default_rng(seed)
    tasks = []
    for a in anchors:
        for r in radii:
            for _ in range(samples):
                u = rng.standard_normal(78)
                u *= r / np.linalg.norm(u)
                rot = taylor.anchors[a] @ roma.rotvec_to_rotmat(torch.from_numpy(u[:72]).float().view(24, 3))
                shape = (taylor.shape0 + torch.from_numpy(u[72:]).float()).clamp(0.0, 1.0)
                tasks.append((a, r, rot, shape))
    poses = torch.stack([t[2] for t in tasks] + [taylor.anchors[t[0]] for t in tasks])
    bodies = [t[3][None] for t in tasks] * 2
    drapes = drape_poses(cfg, poses, bodies, desc="separability")
    rows = []
    n = len(tasks)
    for i, (a, r, rot, shape) in enumerate(tasks):
        at, anchor = drapes[i], drapes[n + i]
        gt = torch.from_numpy(at["posed"][1])
        bv, _, bt = posed_bodies(body, rot[None], shape[None])
        du = torch.from_numpy(anchor["unposed"][1] - anchor["unposed"][0])
        theory = taylor.pbns.skin(torch.from_numpy(at["unposed"][0]) + du, bt)[0]
        taylor.set_shape(body, shape)
        w = torch.zeros(1, taylor.q.shape[0], len(taylor.anchors))
        w[..., a] = 1.0
        practical = taylor.pose(rot[None], bt, weights=w)[0]
        rows.append({"anchor": a, "r": r, "practical_mm": float((practical - gt).norm(dim=-1).mean()) * 1000,
                     "theoretical_mm": float((theory - gt).norm(dim=-1).mean()) * 1000})
    return rows
