"""How good a posed (or resized) outfit is, physically: the numbers of the training logs and of
the evaluation tables alike (thesis Tables 5.1/5.2).

``penetration`` is the one collision test: the signed distance of a cloth vertex along the
normal of its nearest body (or inner-layer) vertex. The collision energy (recon.garment.losses)
pushes on it; ``collision_pct`` counts the vertices behind the surface.
"""
from __future__ import annotations

import numpy as np
import torch

from recon.garment import mesh

# (low, high] % of the covered skin inside the body (recon.garment.self_intersection); the first bin includes 0
SELF_INTERSECTION_BINS = ((0.0, 1.0), (1.0, 3.0), (3.0, 100.0))


def penetration(v: torch.Tensor, surf: torch.Tensor, surf_normals: torch.Tensor, idx: torch.Tensor,
                eps: float = 0.0) -> torch.Tensor:
    """min(0, d - eps) per vertex (B, N), where d is the distance of ``v`` (B, N, 3) in front of
    its corresponding surface vertex ``surf[idx]`` along that vertex's normal: < 0 means the
    vertex is inside the surface (or closer than ``eps`` to it)."""
    d = ((v - torch.gather(surf, 1, idx[..., None].expand(-1, -1, 3)))
         * torch.gather(surf_normals, 1, idx[..., None].expand(-1, -1, 3))).sum(-1)
    return torch.clamp(d - eps, max=0.0)


def collision_pct(v: torch.Tensor, body_v: torch.Tensor, body_n: torch.Tensor,
                  idx: torch.Tensor | None = None) -> torch.Tensor:
    """(B,) % of cloth vertices inside the body (exact nearest body vertex; ``idx`` (B, N): those
    indices already found, e.g. the first of ``mesh.nearest``'s k, which come sorted)."""
    idx = mesh.nearest(body_v, v) if idx is None else idx
    return (penetration(v, body_v, body_n, idx) < 0).float().mean(1) * 100


def strain(v: torch.Tensor, edges: torch.Tensor, rest_len: torch.Tensor) -> torch.Tensor:
    """Signed edge-length error (B, E), metres: posed lengths of ``edges`` minus ``rest_len``
    ((E,) or one rest garment per sample (B, E))."""
    return (mesh.take(v, edges[:, 0]) - mesh.take(v, edges[:, 1])).norm(dim=-1) - rest_len


def bending(v: torch.Tensor, faces: torch.Tensor, adjacency: torch.Tensor, weights: torch.Tensor | None = None
            ) -> torch.Tensor:
    """(B,) mean over adjacent face pairs (A, 2) of ||n_i - n_j||^2 (optionally weighted): 0 for a
    flat sheet, crumpling otherwise."""
    n = mesh.face_normals(v, faces)
    d = ((mesh.take(n, adjacency[:, 0]) - mesh.take(n, adjacency[:, 1])) ** 2).sum(-1)
    return (d if weights is None else weights * d).mean(1)


@torch.no_grad()
def physical_metrics(v: torch.Tensor, faces: np.ndarray, rest: torch.Tensor, body_v, body_n,
                     body_self: torch.Tensor | None = None) -> dict:
    """Collision %, edge error (mm, and length-weighted %: slivers at cut lines would dominate a
    plain mean), bending (mean squared normal difference of adjacent faces), gravity (mean
    height above the lowest body point, m) of posed cloth ``v`` (B, N, 3).

    ``rest``: (N, 3) template, or (B, N, 3) one rest garment per sample (resizing).
    ``body_self`` (B,): the body's self-intersection % per pose; adds collision % and edge error
    per bin of SELF_INTERSECTION_BINS."""
    e = torch.from_numpy(mesh.unique_edges(faces))
    l0 = (rest[..., e[:, 0], :] - rest[..., e[:, 1], :]).norm(dim=-1)
    s = strain(v, e, l0)
    per_pose, strain_pose = collision_pct(v, body_v, body_n), s.abs().mean(-1) * 1000
    bend = bending(v, torch.from_numpy(np.ascontiguousarray(faces)).long(),
                   torch.from_numpy(np.array(mesh.face_adjacency(faces))).long())
    floor = body_v[..., 1].min(1).values[:, None]
    bins = {}
    if body_self is not None:
        for lo, hi in SELF_INTERSECTION_BINS:
            k = ((body_self > lo) | (lo == 0)) & (body_self <= hi)
            bins[f"{lo:g}-{hi:g}"] = {"poses": int(k.sum()),
                                      "collision_pct": float(per_pose[k].mean()) if k.any() else None,
                                      "edge_mm": float(strain_pose[k].mean()) if k.any() else None}
    return ({"by_body_self_intersection": bins} if bins else {}) | {
            "collision_pct": float(per_pose.mean()),
            "edge_mm": float(s.abs().mean() * 1000),
            "edge_pct": float((s.abs().sum(1) / l0.sum(-1)).mean() * 100),
            "bend": float(bend.mean()),
            "gravity_m": float((v[..., 1] - floor).mean())}


def rest_metrics(v: torch.Tensor, base: torch.Tensor, faces: np.ndarray, body_v, body_n) -> dict:
    """Resized rest outfits ``v`` (B, N, 3): vertices inside the rest body (%) and mean |edge -
    E_T edge| (mm) against the transferred outfits ``base`` (B, N, 3)."""
    m = physical_metrics(v, faces, base, body_v, body_n)
    return {k: m[k] for k in ("collision_pct", "edge_mm")}
