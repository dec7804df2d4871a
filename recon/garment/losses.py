"""PBNS potential energies (thesis 5.3.4). Each term is a module with its own config; the
training loss is their plain sum. All take the posed outfit (B, N, 3) in metres, body frame
(+Y up: gravity acts along -Y)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from recon.garment import mesh as gm


def nearest(points: torch.Tensor, query: torch.Tensor, k: int = 1) -> torch.Tensor:
    """Indices of the k nearest of ``points`` (B, P, 3) for every ``query`` (B, Q, 3): (B, Q) for
    k = 1, else (B, Q, k). Exact (KD-tree), no gradient."""
    from scipy.spatial import cKDTree

    p, q = points.detach().cpu().numpy(), query.detach().cpu().numpy()
    idx = np.stack([cKDTree(p[b]).query(q[b], k=k, workers=-1)[1] for b in range(len(p))])
    return torch.from_numpy(idx).to(query.device)


def nearest_among(points: torch.Tensor, query: torch.Tensor, candidates: torch.Tensor) -> torch.Tensor:
    """Nearest of ``points`` among per-query candidate indices (B, Q, K) -> (B, Q); no gradient.
    Training precomputes candidates once per pose (a KD-tree per step would dominate the cost)."""
    with torch.no_grad():
        b, q, k = candidates.shape
        c = candidates.long().reshape(b, q * k)
        pc = torch.gather(points, 1, c[..., None].expand(-1, -1, 3)).view(b, q, k, 3)
        best = (pc - query[:, :, None]).norm(dim=-1).argmin(-1)
        return torch.gather(candidates.long(), 2, best[..., None])[..., 0]


@dataclass
class EdgeConfig:
    weight: float = 1.0e4  # lambda_e, per squared metre of mean edge-length error (mass-spring)


class EdgeLoss(nn.Module):
    """lambda_e * mean_e (|e| - |e_T|)^2, optionally weighted per edge (fabric)."""

    def __init__(self, rest: torch.Tensor, faces: np.ndarray, cfg: EdgeConfig = EdgeConfig(),
                 fabric: torch.Tensor | None = None):
        super().__init__()
        self.cfg = cfg
        e = torch.from_numpy(gm.unique_edges(faces))
        self.register_buffer("edges", e)
        self.register_buffer("rest_len", (rest[e[:, 0]] - rest[e[:, 1]]).norm(dim=-1))
        w = torch.ones(len(e)) if fabric is None else 0.5 * (fabric[e[:, 0]] + fabric[e[:, 1]])
        self.register_buffer("w", w)
        self.scale = 1.0  # set by a training schedule (stiffness continuation)

    def strain(self, v: torch.Tensor, rest_len: torch.Tensor | None = None) -> torch.Tensor:
        """Signed edge-length error (B, E), metres; ``rest_len`` (B, E) overrides the template's
        lengths per sample (resizing: each body size has its own rest garment)."""
        l0 = self.rest_len if rest_len is None else rest_len
        return (v[:, self.edges[:, 0]] - v[:, self.edges[:, 1]]).norm(dim=-1) - l0

    def forward(self, v, rest_len: torch.Tensor | None = None):
        return self.scale * self.cfg.weight * (self.w * self.strain(v, rest_len) ** 2).mean(1)


@dataclass
class BendConfig:
    weight: float = 0.02  # lambda_b, on mean squared normal difference of adjacent faces


class BendLoss(nn.Module):
    """lambda_b * mean over adjacent faces ||n_i - n_j||^2 (Laplacian of face normals, hinge-like)."""

    def __init__(self, faces: np.ndarray, cfg: BendConfig = BendConfig(), fabric: torch.Tensor | None = None):
        super().__init__()
        self.cfg = cfg
        self.register_buffer("faces", torch.from_numpy(np.ascontiguousarray(faces)).long())
        self.register_buffer("adj", torch.from_numpy(np.array(gm.face_adjacency(faces))).long())
        if fabric is None:
            w = torch.ones(len(self.adj))
        else:
            fw = fabric[self.faces].mean(1)
            w = 0.5 * (fw[self.adj[:, 0]] + fw[self.adj[:, 1]])
        self.register_buffer("w", w)

    def energy(self, v):
        n = gm.face_normals(v, self.faces)
        return (self.w * ((n[:, self.adj[:, 0]] - n[:, self.adj[:, 1]]) ** 2).sum(-1)).mean(1)

    def forward(self, v):
        return self.cfg.weight * self.energy(v)


@dataclass
class CollisionConfig:
    weight: float = 25.0e3  # lambda_c (thesis: 25 on summed squared metres; here on the mean x 1e3)
    eps: float = 0.004  # metres
    cloth_reach: float = 0.02  # cloth-to-cloth pairs farther apart than this are not in contact
    # no body force where the nearest body vertex lies inside the body (the posed body passes
    # through itself there: no side is "outside"; recon.garment.self_intersection)
    skip_self_intersection: bool = False


class CollisionLoss(nn.Module):
    """Eq. 5.5 with nearest-neighbour correspondences: body for every vertex, then (cloth-to-cloth)
    the previous layers for outer-layer vertices; both vertices of a cloth pair get the force."""

    def __init__(self, layer: np.ndarray, cfg: CollisionConfig = CollisionConfig()):
        super().__init__()
        self.cfg = cfg
        self.register_buffer("layer", torch.from_numpy(np.asarray(layer)).long())

    @staticmethod
    def penetration(v, surf, surf_normals, idx, eps):
        d = ((v - torch.gather(surf, 1, idx[..., None].expand(-1, -1, 3)))
             * torch.gather(surf_normals, 1, idx[..., None].expand(-1, -1, 3))).sum(-1)
        return torch.clamp(d - eps, max=0.0)

    def pairs(self):
        """(inner vertex ids, outer vertex ids) for each outer layer."""
        layers = sorted(set(self.layer.tolist()))
        return [(torch.nonzero(self.layer < lay)[:, 0], torch.nonzero(self.layer == lay)[:, 0]) for lay in layers[1:]]

    def forward(self, v, body_v, body_n, faces: torch.Tensor, body_cand=None, cloth_cand=None, body_inside=None):
        """body_cand (B, N, K) / cloth_cand [(B, N_outer, K) per outer layer]: candidate indices
        for the nearest-neighbour search; exact KD-tree search when None. body_inside (B, V) bool:
        body vertices inside the body, whose neighbourhood exerts no force (skip_self_intersection)."""
        idx = nearest(body_v, v) if body_cand is None else nearest_among(body_v, v, body_cand)
        pen = self.penetration(v, body_v, body_n.detach(), idx, self.cfg.eps)
        if body_inside is not None and self.cfg.skip_self_intersection:
            pen = torch.where(torch.gather(body_inside, 1, idx), torch.zeros_like(pen), pen)
        total = (pen ** 2).mean(1)
        pairs = self.pairs()
        if pairs:
            n = gm.vertex_normals(v, faces).detach()
            for k, (inner, outer) in enumerate(pairs):
                vi, vo = v[:, inner], v[:, outer]
                idx = nearest(vi, vo) if cloth_cand is None else nearest_among(vi, vo, cloth_cand[k])
                p = self.penetration(vo, vi, n[:, inner], idx, self.cfg.eps)
                # layers overlap only in part (a top over the trousers' waist): far pairs are not contacts
                gap = (vo - torch.gather(vi, 1, idx[..., None].expand(-1, -1, 3))).norm(dim=-1).detach()
                p = torch.where(gap < self.cfg.cloth_reach, p, torch.zeros_like(p))
                total = total + (p ** 2).sum(1) / v.shape[1]
        return self.cfg.weight * total


@dataclass
class GravityConfig:
    weight: float = 0.15  # mass x g per unit height (mean over vertices)


class GravityLoss(nn.Module):
    def __init__(self, cfg: GravityConfig = GravityConfig(), fabric_mass: torch.Tensor | None = None):
        super().__init__()
        self.cfg = cfg
        self.register_buffer("m", torch.ones(1) if fabric_mass is None else fabric_mass)

    def forward(self, v):
        return self.cfg.weight * (self.m * v[..., 1]).mean(1)


@dataclass
class PinConfig:
    weight: float = 10.0  # lambda_pin (thesis: 10)


class PinLoss(nn.Module):
    def __init__(self, pinned: np.ndarray, cfg: PinConfig = PinConfig()):
        super().__init__()
        self.cfg = cfg
        self.register_buffer("pinned", torch.from_numpy(np.asarray(pinned)).bool())

    def forward(self, dt):
        if not self.pinned.any():
            return dt.new_zeros(dt.shape[0])
        return self.cfg.weight * (dt[:, self.pinned] ** 2).sum(-1).mean(1)
