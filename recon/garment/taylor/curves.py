"""Curves and checks of the Taylor model beside its table (``taylor.eval``): the model with fewer
anchors or pose examples (subsets of its database, no rebuild), the paper's separability check
(section 4.2) and its speed.
"""
from __future__ import annotations

import copy
import time

import numpy as np
import roma
import torch

from recon.body.base import BodyModel
from recon.garment import store
from recon.garment.collide import CollisionResolver
from recon.garment.data import posed_bodies
from recon.garment.pbns.model import PBNS, widened
from recon.garment.taylor.config import TaylorBuildConfig
from recon.garment.taylor.data import drape_poses
from recon.garment.taylor.model import TaylorGarment
from recon.garment.taylor.train import cluster_anchors
from recon.timing import compare


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


def separability(cfg: TaylorBuildConfig, taylor: TaylorGarment, body: BodyModel, anchors: list[int],
                 radii: tuple[float, ...], samples: int, seed: int = 0) -> list[dict]:
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


@torch.no_grad()
def speed(body: BodyModel, outfit: str, taylor: TaylorGarment | None, poses: torch.Tensor) -> dict:
    """Frames a second at batch 1 (1 thread, given the posed body) of PBNS, of the Taylor model
    (with penetration handling) with and without its pose examples' corrections and of it as built
    with the post-step, timed in interleaved rounds (the median over rounds), and the time of a new
    body shape (ms). Without a built database
    the Taylor model is timed on one of the default size with random contents (its cost does not
    depend on the values), its pose model widened as a build's. ``poses`` (anchors + 8, 24, 3, 3):
    the first is timed, the last ``anchors`` are a random database's."""
    pbns, ck = PBNS.load(store.pbns_path(outfit))
    rot = poses[:1]
    shape = ck["shape"]
    random_db = taylor is None
    if random_db:
        cfg = TaylorBuildConfig()
        a, n, s = cfg.anchors, pbns.rest.shape[0], len(shape)
        g = torch.Generator().manual_seed(0)
        q = torch.rand(7, 72, generator=g)
        e = a + cfg.pose_examples
        anchors = poses[8:]
        examples = torch.cat([anchors, roma.rotvec_to_rotmat(0.3 * torch.randn(e - a, 24, 3, generator=g))])
        model = copy.deepcopy(pbns)
        if cfg.pose_fit.hidden:
            model.mlp = widened(model.mlp, cfg.pose_fit.hidden)
        taylor = TaylorGarment(model, anchors, q / q.sum(1, keepdim=True),
                               1e-3 * torch.randn(a, cfg.components, n, 3, generator=g),
                               torch.randn(a, cfg.components, 2 * s + 1, generator=g), shape,
                               pose_residual=1e-3 * torch.randn(e, n, 3, generator=g),
                               correct_pose=cfg.pose_fit.corrections,
                               pose_examples=examples if cfg.pose_examples else None, fitted=True)
    out = body(rot[:1], shape[None])
    t_ms = []
    for k in range(5):
        t = time.perf_counter()
        taylor.set_shape(body, shape + 0.01 * k)
        t_ms.append((time.perf_counter() - t) * 1000)
    r, tr, bv = rot[:1], out.transforms, out.vertices
    resolver = CollisionResolver(pbns.faces.numpy(), ck["layer"].numpy())

    def uncorrected():
        with taylor.corrections(False):
            return taylor.pose(r, tr, bv)

    def corrected():
        with taylor.corrections(True):
            return taylor.pose(r, tr, bv)

    ms = compare({"pbns": lambda: pbns.pose(r, tr), "taylor": corrected, "uncorrected": uncorrected,
                  "post": lambda: resolver(taylor.pose(r, tr, bv), bv, body.faces, rest=taylor.graded)}, rounds=7)
    return {"vertices": int(pbns.rest.shape[0]), "random_database": random_db, "anchors": len(taylor.anchors),
            "pose_examples": len(taylor.example_poses),
            "pbns_fps": 1000.0 / ms["pbns"], "taylor_fps": 1000.0 / ms["taylor"],
            "taylor_uncorrected_fps": 1000.0 / ms["uncorrected"], "corrections": taylor.correct_pose,
            "taylor_post_fps": 1000.0 / ms["post"],
            "new_shape_ms": float(np.median(t_ms))}
