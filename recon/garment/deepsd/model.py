"""DeePSD (thesis ch. 4): one network maps an outfit template mesh of any topology, vertex order
and number of layers to its animation model, blend weights W and pose-space blend shapes D
(eq. 4.2, M: {T, F} -> {W, D_PSD}); the outfit is then animated by eq. 4.1,

    V_theta = W(T + sum_p Theta(theta)_p D_p, J, theta, W),

which is exactly PBNS's form (``recon.garment.pbns.model``): a converted outfit is a ``PBNS`` and goes
wherever PBNS goes (resizing, collisions, motions, morph targets in the .glb).

Architecture (fig. 4.2): Phi, 4 graph convolutions over the template's edges (a vertex and the
mean of its neighbours, each through its own linear map) give local descriptors; one fully
connected layer and a max-pool over the outfit give a global descriptor (PointNet) concatenated to
every vertex's. Omega (blend weights), Psi (D_data, supervised) and chi (D_phys, physics only) are
4-layer MLPs applied to each vertex independently; Theta, the pose embedding, a 4-layer MLP of the
pose (PBNS's). D_PSD = D_data + D_phys.

Deviations, for a small dataset on the mean body: the vertex input is the rest position, its
normal, its distance in front of the nearest body vertex and that vertex's (diffused) blend
weights, and Omega predicts a correction to the log of those weights (a mesh with no learnt
correction is skinned as the LBS baseline).
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn

from recon import paths
from recon.body.base import BodyModel
from recon.garment import mesh, store
from recon.garment.pbns.model import (
    PBNS,
    BlendShapeGarment,
    PBNSConfig,
    blend_transforms,
    initial_weights,
    pose_features,
    pose_mlp,
)
from recon.garment.templates import Outfit, RestBody, hangs_free, make_outfit

N_JOINTS = 24
IN_FEATURES = 3 + 3 + 1 + N_JOINTS
SMOOTH = 5  # Laplacian steps over the template applied to the exported W and D


@dataclass
class DeePSDConfig:
    local: int = 128  # graph-convolution channels
    global_: int = 256  # global descriptor (0: none, the "baseline" ablation)
    hidden: int = 256  # the per-vertex MLPs' width
    keys: int = 64  # P, pose keys = blend shapes per vertex
    pose_hidden: int = 128
    blend_shapes: bool = True  # False: Psi predicts deformations from [descriptor, Theta] (ablation)

    @property
    def descriptor(self) -> int:
        return self.local + self.global_


def mlp(dims: list[int]) -> nn.Sequential:
    mods: list[nn.Module] = []
    for a, b in zip(dims[:-1], dims[1:]):
        mods += [nn.Linear(a, b), nn.ReLU()]
    return nn.Sequential(*mods[:-1])


def mean_adjacency(faces: np.ndarray, n: int) -> torch.Tensor:
    """(n, n) sparse mean over each vertex's edge neighbours (a graph convolution's aggregation)."""
    return sparse_tensor(mesh.neighbour_mean(faces, n))


def sparse_tensor(a) -> torch.Tensor:
    """A scipy sparse matrix as a coalesced float32 torch sparse COO tensor."""
    a = a.tocoo()
    idx = torch.from_numpy(np.stack([a.row, a.col]).astype(np.int64))
    return torch.sparse_coo_tensor(idx, torch.from_numpy(a.data).float(), a.shape, check_invariants=False).coalesce()


class GraphConv(nn.Module):
    """x_i' = A x_i + B mean_{j ~ i} x_j: equivariant to vertex order, any connectivity."""

    def __init__(self, a: int, b: int):
        super().__init__()
        self.own, self.nb = nn.Linear(a, b), nn.Linear(a, b, bias=False)

    def forward(self, x: torch.Tensor, adj: torch.Tensor) -> torch.Tensor:
        return self.own(x) + self.nb(torch.sparse.mm(adj.to(x.dtype), x))


def lbs_weights(rb: RestBody, outfit: Outfit) -> np.ndarray:
    """Nearest-body-vertex blend weights diffused over the outfit (PBNS's start: 20 steps with a
    skirt-like garment, else 10): the skinning the drapes start from and DeePSD's baseline."""
    skirted = any(hangs_free(rb, g) for g in outfit.garments)
    return initial_weights(rb, outfit, 20 if skirted else 10)


class OutfitGraph:
    """What DeePSD reads of a template: per-vertex input features (N, IN_FEATURES), the mean
    adjacency, the nearest-body blend weights (N, 24) and faces."""

    def __init__(self, rest: np.ndarray, faces: np.ndarray, lbs_weights: np.ndarray, body_v: np.ndarray,
                 body_n: np.ndarray):
        rest = np.asarray(rest, np.float32)
        self.rest = torch.from_numpy(rest)
        self.faces = np.ascontiguousarray(faces)
        self.lbs_weights = torch.as_tensor(lbs_weights, dtype=torch.float32)
        normals = mesh.vertex_normals(self.rest[None], torch.from_numpy(self.faces).long())[0]
        _, idx = cKDTree(body_v).query(rest)
        dist = np.einsum("ij,ij->i", rest - body_v[idx], body_n[idx]).astype(np.float32)
        self.features = torch.cat([self.rest, normals, torch.from_numpy(dist)[:, None],
                                   self.lbs_weights], 1)
        self.adj = mean_adjacency(self.faces, len(rest))

    @classmethod
    def of(cls, rb: RestBody, outfit: Outfit) -> OutfitGraph:
        return cls(outfit.vertices, outfit.faces, lbs_weights(rb, outfit), rb.v, rb.n)


class DeePSD(nn.Module):
    def __init__(self, cfg: DeePSDConfig | None = None):
        super().__init__()
        self.cfg = cfg = cfg or DeePSDConfig()
        dims = [IN_FEATURES, 64, cfg.local, cfg.local, cfg.local]
        self.phi = nn.ModuleList(GraphConv(a, b) for a, b in zip(dims[:-1], dims[1:]))
        self.global_fc = nn.Linear(cfg.local, cfg.global_) if cfg.global_ else None
        f, h, p = cfg.descriptor, cfg.hidden, cfg.keys
        self.omega = mlp([f, h, h, h, N_JOINTS])
        self.psi = mlp([f, h, h, h, 3 * p] if cfg.blend_shapes else [f + p, h, h, h, 3])
        self.chi = mlp([f, h, h, h, 3 * p])
        self.theta = pose_mlp(cfg.pose_hidden, 4, p)
        for head in (self.omega, self.chi):  # start as the LBS baseline and no physics correction
            nn.init.zeros_(head[-1].weight)
            nn.init.zeros_(head[-1].bias)

    def descriptors(self, g: OutfitGraph) -> torch.Tensor:
        """Phi: (N, F) local descriptors with the outfit's global one appended."""
        x = g.features
        for i, conv in enumerate(self.phi):
            x = conv(x, g.adj)
            x = torch.relu(x) if i < len(self.phi) - 1 else x
        if self.global_fc is None:
            return x
        glob = self.global_fc(torch.relu(x)).max(0).values
        return torch.cat([x, glob.expand(len(x), -1)], 1)

    def weights(self, lbs_weights: torch.Tensor, desc: torch.Tensor) -> torch.Tensor:
        """Omega: blend weights (n, 24), a correction of the nearest-body ones (n, 24)."""
        return torch.softmax(torch.log(lbs_weights.clamp_min(1e-6)) + self.omega(desc), -1)

    def blend_shapes(self, desc: torch.Tensor, physics: bool = True) -> torch.Tensor:
        """D (n, P, 3): Psi's, plus chi's with ``physics``."""
        n = len(desc)
        d = self.psi(desc).view(n, -1, 3)
        return d + self.chi(desc).view(n, -1, 3) if physics else d

    def keys(self, rotmats: torch.Tensor) -> torch.Tensor:
        """Theta: pose keys (B, P) of (B, 24, 3, 3) local rotations."""
        return self.theta(pose_features(rotmats))

    def displacements(self, desc: torch.Tensor, rotmats: torch.Tensor, physics: bool = True) -> torch.Tensor:
        """Rest-pose displacements (B, n, 3) of the vertices described by ``desc`` (n, F)."""
        k = self.keys(rotmats)
        if self.cfg.blend_shapes:
            return torch.einsum("bp,npk->bnk", k, self.blend_shapes(desc, physics))
        n, b = len(desc), len(k)
        x = torch.cat([desc[None].expand(b, -1, -1), k[:, None].expand(-1, n, -1)], -1)
        return self.psi(x)

    def forward(self, g: OutfitGraph, rotmats: torch.Tensor, transforms: torch.Tensor, physics: bool = True,
                subset: torch.Tensor | None = None) -> torch.Tensor:
        """Posed outfit (B, n, 3) at poses (B, 24, 3, 3) with the body's joint transforms
        (B, 24, 3, 4); only the vertices ``subset`` (the per-vertex heads are independent:
        training evaluates a sample of them)."""
        desc, rest, lbs = self.descriptors(g), g.rest, g.lbs_weights
        if subset is not None:
            desc, rest, lbs = desc[subset], rest[subset], lbs[subset]
        x = rest + self.displacements(desc, rotmats, physics)
        return BlendShapeGarment.apply_blend(x, blend_transforms(self.weights(lbs, desc), transforms))

    @torch.no_grad()
    def outfit(self, g: OutfitGraph, physics: bool = True, smooth: int = SMOOTH) -> PBNS:
        """The animation model of an outfit, no training: W and D in a PBNS (eq. 4.1), both
        Laplacian-smoothed over the template ``smooth`` steps (the per-vertex heads' noise on an
        irregular triangulation would crease the cloth)."""
        if not self.cfg.blend_shapes:
            raise ValueError("the deformation ablation has no blend shapes to export")
        desc = self.descriptors(g)
        w = self.weights(g.lbs_weights, desc)
        d = self.blend_shapes(desc, physics).reshape(len(desc), -1)
        if smooth:
            avg = mesh.neighbour_mean(g.faces, len(desc))
            w = torch.from_numpy(mesh.smooth_vertex_values(w.double().numpy(), g.faces, smooth, avg)).float()
            d = torch.from_numpy(mesh.smooth_vertex_values(d.double().numpy(), g.faces, smooth, avg)).float()
        cfg = PBNSConfig(hidden=self.cfg.pose_hidden, layers=4, embedding=self.cfg.keys, optimise_weights=False)
        model = PBNS(g.rest, torch.from_numpy(g.faces), w, cfg)
        model.D.copy_(d.view(len(desc), self.cfg.keys, 3).permute(1, 0, 2).reshape(self.cfg.keys, -1))
        model.mlp.load_state_dict(self.theta.state_dict())
        return model.eval()

    # --- persistence ----------------------------------------------------------------------------
    def save(self, path: Path, extra: dict) -> None:
        sd = {k: v.half() for k, v in self.state_dict().items()}  # float16: half the file
        paths.atomic_write(Path(path), lambda t: torch.save({"cfg": asdict(self.cfg), "state": sd} | extra, t))

    @classmethod
    def load(cls, path: Path) -> tuple[DeePSD, dict]:
        ck = paths.load_checkpoint(path, "recon garment train --model deepsd")
        m = cls(DeePSDConfig(**ck["cfg"]))
        m.load_state_dict({k: v.float() for k, v in ck["state"].items()})
        return m.eval(), ck


def animation_model(body: BodyModel, outfit: str | Outfit, path: Path | None = None) -> tuple[PBNS, dict]:
    """An outfit (a preset, a garment mesh's path or an ``Outfit``) made ready to animate by DeePSD,
    no training: (PBNS with its W and D, the checkpoint fields ``Dresser`` reads)."""
    model, _ = DeePSD.load(path or store.deepsd_path())
    rb = RestBody(body)
    o = outfit if isinstance(outfit, Outfit) else make_outfit(body, outfit)
    pbns = model.outfit(OutfitGraph.of(rb, o))
    name = None if isinstance(outfit, Outfit) else str(outfit)
    ck = {"shape": body.mean_shape.detach().clone(), "garment_id": torch.from_numpy(o.garment_id),
          "layer": torch.from_numpy(o.layer), "meta_json": json.dumps({"garments": [g.name for g in o.garments],
                                                                       "source": name, "model": "deepsd"})}
    return pbns, ck
