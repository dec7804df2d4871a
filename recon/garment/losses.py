"""PBNS potential energies (thesis 5.3.4) and NCS's inertia term (6.3.4, eq. 6.9). Each term is a
module with its own config; the training loss (``Criterion``) is their plain sum and keeps each
term for logging. All take the
posed outfit (B, N, 3) in metres, body frame (+Y up: gravity acts along -Y). The geometric
quantities (strain, bending, penetration) are recon.garment.metrics', shared with the
evaluation."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn

from recon.garment import mesh
from recon.garment.mesh import nearest, nearest_among
from recon.garment.metrics import bending, penetration, strain
from recon.poses.mocap import FPS


@dataclass
class EdgeConfig:
    weight: float = 1.0e4  # lambda_e, per squared metre of mean edge-length error (mass-spring)


class EdgeLoss(nn.Module):
    """lambda_e * mean_e (|e| - |e_T|)^2, optionally weighted per edge (fabric)."""

    def __init__(self, rest: torch.Tensor, faces: np.ndarray, cfg: EdgeConfig | None = None,
                 fabric: torch.Tensor | None = None):
        super().__init__()
        self.cfg = cfg or EdgeConfig()
        e = torch.from_numpy(mesh.unique_edges(faces))
        self.register_buffer("edges", e)
        self.register_buffer("rest_len", (rest[e[:, 0]] - rest[e[:, 1]]).norm(dim=-1))
        w = torch.ones(len(e)) if fabric is None else 0.5 * (fabric[e[:, 0]] + fabric[e[:, 1]])
        self.register_buffer("w", w)
        self.scale = 1.0  # set by a training schedule (stiffness continuation)

    def strain(self, v: torch.Tensor, rest_len: torch.Tensor | None = None) -> torch.Tensor:
        """Signed edge-length error (B, E), metres; ``rest_len`` (B, E) overrides the template's
        lengths per sample (resizing: each body size has its own rest garment)."""
        return strain(v, self.edges, self.rest_len if rest_len is None else rest_len)

    def forward(self, v, rest_len: torch.Tensor | None = None):
        return self.scale * self.cfg.weight * (self.w * self.strain(v, rest_len) ** 2).mean(1)


@dataclass
class BendConfig:
    weight: float = 0.02  # lambda_b, on mean squared normal difference of adjacent faces


class BendLoss(nn.Module):
    """lambda_b * mean over adjacent faces ||n_i - n_j||^2 (Laplacian of face normals, hinge-like)."""

    def __init__(self, faces: np.ndarray, cfg: BendConfig | None = None, fabric: torch.Tensor | None = None):
        super().__init__()
        self.cfg = cfg or BendConfig()
        self.register_buffer("faces", torch.from_numpy(np.ascontiguousarray(faces)).long())
        self.register_buffer("adj", torch.from_numpy(np.array(mesh.face_adjacency(faces))).long())
        if fabric is None:
            w = torch.ones(len(self.adj))
        else:
            fw = fabric[self.faces].mean(1)
            w = 0.5 * (fw[self.adj[:, 0]] + fw[self.adj[:, 1]])
        self.register_buffer("w", w)

    def energy(self, v):
        return bending(v, self.faces, self.adj, self.w)

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

    def __init__(self, layer: np.ndarray, cfg: CollisionConfig | None = None):
        super().__init__()
        self.cfg = cfg or CollisionConfig()
        self.register_buffer("layer", torch.from_numpy(np.asarray(layer)).long())

    def pairs(self):
        """(inner vertex ids, outer vertex ids) for each outer layer."""
        layers = sorted(set(self.layer.tolist()))
        return [(torch.nonzero(self.layer < lay)[:, 0], torch.nonzero(self.layer == lay)[:, 0]) for lay in layers[1:]]

    def forward(self, v, body_v, body_n, faces: torch.Tensor, body_cand=None, cloth_cand=None, body_inside=None):
        """body_cand (B, N, K) / cloth_cand [(B, N_outer, K) per outer layer]: candidate indices
        for the nearest-neighbour search; exact KD-tree search when None. body_inside (B, V) bool:
        body vertices inside the body, whose neighbourhood exerts no force (skip_self_intersection)."""
        idx = nearest(body_v, v) if body_cand is None else nearest_among(body_v, v, body_cand)
        pen = penetration(v, body_v, body_n.detach(), idx, self.cfg.eps)
        if body_inside is not None and self.cfg.skip_self_intersection:
            pen = torch.where(torch.gather(body_inside, 1, idx), torch.zeros_like(pen), pen)
        total = (pen ** 2).mean(1)
        pairs = self.pairs()
        if pairs:
            n = mesh.vertex_normals(v, faces).detach()
            for k, (inner, outer) in enumerate(pairs):
                vi, vo = v[:, inner], v[:, outer]
                idx = nearest(vi, vo) if cloth_cand is None else nearest_among(vi, vo, cloth_cand[k])
                p = penetration(vo, vi, n[:, inner], idx, self.cfg.eps)
                # layers overlap only in part (a top over the trousers' waist): far pairs are not contacts
                gap = (vo - torch.gather(vi, 1, idx[..., None].expand(-1, -1, 3))).norm(dim=-1).detach()
                p = torch.where(gap < self.cfg.cloth_reach, p, torch.zeros_like(p))
                total = total + (p ** 2).sum(1) / v.shape[1]
        return self.cfg.weight * total


@dataclass
class GravityConfig:
    weight: float = 0.15  # mass x g per unit height (mean over vertices)


class GravityLoss(nn.Module):
    def __init__(self, cfg: GravityConfig | None = None, fabric_mass: torch.Tensor | None = None):
        super().__init__()
        self.cfg = cfg or GravityConfig()
        self.register_buffer("m", torch.ones(1) if fabric_mass is None else fabric_mass)

    def forward(self, v):
        return self.cfg.weight * (self.m * v[..., 1]).mean(1)


@dataclass
class PinConfig:
    weight: float = 10.0  # lambda_pin (thesis: 10)


class PinLoss(nn.Module):
    def __init__(self, pinned: np.ndarray, cfg: PinConfig | None = None):
        super().__init__()
        self.cfg = cfg or PinConfig()
        self.register_buffer("pinned", torch.from_numpy(np.asarray(pinned)).bool())

    def forward(self, dt):
        if not self.pinned.any():
            return dt.new_zeros(dt.shape[0])
        return self.cfg.weight * (dt[:, self.pinned] ** 2).sum(-1).mean(1)


class Criterion(nn.Module):
    """The PBNS loss: the sum of the energies (Eq. 5.3); ``terms`` keeps each one for logging.
    ``cfg`` carries one config per term (``edge``, ``bend``, ``collision``, ``gravity``, ``pin``:
    GarmentTrainConfig, ResizeConfig)."""

    def __init__(self, outfit, rest: torch.Tensor, cfg):
        super().__init__()
        self.edge = EdgeLoss(rest, outfit.faces, cfg.edge)
        self.bend = BendLoss(outfit.faces, cfg.bend)
        self.collision = CollisionLoss(outfit.layer, cfg.collision)
        self.gravity = GravityLoss(cfg.gravity)
        self.pin = PinLoss(outfit.pinned, cfg.pin)
        self.register_buffer("faces", torch.from_numpy(np.ascontiguousarray(outfit.faces)).long())

    def forward(self, v, dt, body_v, body_n, body_cand=None, cloth_cand=None, rest_len=None, body_inside=None):
        self.terms = {"edge": self.edge(v, rest_len), "bend": self.bend(v),
                      "collision": self.collision(v, body_v, body_n, self.faces, body_cand, cloth_cand, body_inside),
                      "gravity": self.gravity(v), "pin": self.pin(dt)}
        return sum(self.terms.values())


@dataclass
class Fabric:
    """The cloth's energies as PBNS trains them: NCS, its teacher and the quasi-static drape
    minimise the same ones."""
    # stiff edges meet the strain target; gravity and bending raised with them keep the sag and the
    # smoothness they would lose (the garment model card's ablation, fifth round)
    edge: EdgeConfig = field(default_factory=lambda: EdgeConfig(weight=3e5))
    bend: BendConfig = field(default_factory=lambda: BendConfig(weight=1.0))
    collision: CollisionConfig = field(default_factory=lambda: CollisionConfig(weight=1e5))
    gravity: GravityConfig = field(default_factory=lambda: GravityConfig(weight=5.0))
    pin: PinConfig = field(default_factory=PinConfig)


FABRIC = Fabric()


@torch.no_grad()
def candidates(model, crit: Criterion, rot, bt, bv, k: int, chunk: int = 64, codes=None):
    """Per pose, the k nearest body vertices (and inner-layer vertices) of every vertex of the
    skinned template (dT = 0), or of the model's drape at ``codes`` (P, E) where given: the
    prediction moves a few cm at most, so its nearest neighbour is almost always among them.
    int16/int32 to keep 3,000 poses in memory."""
    body_c, cloth_c = [], [[] for _ in crit.collision.pairs()]
    for i in range(0, len(rot), chunk):
        rest = model.rest if codes is None else model.rest + model.decode(codes[i:i + chunk])
        v = model.skin(rest, bt[i:i + chunk])
        body_c.append(nearest(bv[i:i + chunk], v, k).to(torch.int16 if bv.shape[1] < 32767 else torch.int32))
        for j, (inner, outer) in enumerate(crit.collision.pairs()):
            cloth_c[j].append(nearest(v[:, inner], v[:, outer], k).to(torch.int32))
    return torch.cat(body_c), [torch.cat(c) for c in cloth_c]


@dataclass
class InertiaConfig:
    # in the units of the PBNS energies, whose gravity term is GravityConfig.weight x mean height:
    # gravity weight / g (5 / 9.81) puts inertia and gravity in their physical ratio
    weight: float = 5.0 / 9.81
    # share of the cloth's velocity relative to where the body carries it (the skinned outfit) that
    # it keeps from one frame to the next: the fabric's and the air's damping, the air moving with
    # the body. 0.95 is the reference simulation's (reference.DynamicConfig); 1 is the thesis' eq.
    # 6.8, whose only damping is the implicit step's
    keep_velocity: float = 0.95


class InertiaLoss(nn.Module):
    """Eq. 6.9 as a mean over particles: weight x m / (2 dt^2) |x_t - x_proj|^2 with the projection
    x_proj = x_{t-1} + v, v = c + keep (x_{t-1} - x_{t-2} - c): the previous velocity, its part
    relative to the body's carrying motion c damped (``InertiaConfig.keep_velocity``); c = 0 when
    not given (the world frame). The masses are scaled to a mean of 1 (the PBNS energies are per
    mean vertex). The previous states are constants: gradients must not travel back in time (the
    thesis' point against SNUG), so they are detached here whatever the caller passes."""

    def __init__(self, masses: torch.Tensor, fps: float = FPS, cfg: InertiaConfig | None = None):
        super().__init__()
        self.cfg = cfg or InertiaConfig()
        self.fps = fps
        m = torch.as_tensor(masses, dtype=torch.float32 if not torch.is_tensor(masses) else masses.dtype)
        self.register_buffer("m", m / m.mean())

    def projection(self, x_prev: torch.Tensor, x_prev2: torch.Tensor,
                   carry: torch.Tensor | None = None) -> torch.Tensor:
        """x_proj from the two previous states and the carrying motion over this frame (detached)."""
        x_prev, v = x_prev.detach(), (x_prev - x_prev2).detach()
        c = torch.zeros_like(v) if carry is None else carry.detach()
        return x_prev + c + self.cfg.keep_velocity * (v - c)

    def to_projection(self, x: torch.Tensor, proj: torch.Tensor) -> torch.Tensor:
        d2 = ((x - proj.detach()) ** 2).sum(-1)
        return self.cfg.weight * 0.5 * self.fps ** 2 * (self.m.to(x) * d2).mean(-1)

    def forward(self, x: torch.Tensor, x_prev: torch.Tensor, x_prev2: torch.Tensor,
                carry: torch.Tensor | None = None) -> torch.Tensor:
        return self.to_projection(x, self.projection(x_prev, x_prev2, carry))
