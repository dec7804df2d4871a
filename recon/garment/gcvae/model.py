"""The GCVAE garment space (thesis 3.4, CLOTH3D's baseline): a garment on the rest body is encoded
as per-body-vertex offsets and a mask (which body vertices it covers), and a graph-convolutional
conditional VAE learns a latent space of them: encode, decode, sample, interpolate.

- Registration (3.4.1): the body without head, hands and feet (where garments never are); a body
  vertex is covered where a garment vertex has it as nearest body vertex (then closed over the
  mesh: no pinholes), its offset the vector to the nearest point of the garment surface. Skirts do
  not follow the body's topology between the legs (the thesis' SMPL-skirt topology answers that;
  here the legs stay apart, and the skirt rows of the results show what it costs).
- Pooling (3.4.3): a hierarchy of vertex clusters that never crosses a body segment (the thesis'
  rule for its mesh simplification), 4 levels, max-pooling down and copying up.
- Conditioning: the garment type (one-hot) instead of body shape and tightness (the body here is
  the mean one); as in the thesis the type is also regressed from the encoder's first fully
  connected layer (L_cvar). The KL is to N(0, I); p(z | type), which sampling draws from, is a
  Gaussian per type fitted to the training garments' codes after training (the decoder alone
  would let z carry the type).
- Loss (eq. 3.2-3.4): L1 on offsets, L1 on face normals, mask (binary cross-entropy), collision
  max(0, -o . n), KL.

A decoded garment is the body plus offsets on the faces whose three vertices are covered.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import trimesh
from scipy.cluster.vq import kmeans2
from scipy.spatial import cKDTree
from torch import nn

from recon import paths
from recon.garment import mesh
from recon.garment.deepsd.model import GraphConv, mean_adjacency, sparse_tensor
from recon.garment.templates import J, RestBody

TYPES = ("top", "trousers", "skirt", "dress", "jumpsuit")
LEFT_OUT = ("head", "left_hand", "right_hand", "left_foot", "right_foot")  # never under a garment


@dataclass
class GCVAEConfig:
    channels: tuple = (32, 64, 64, 128)  # graph convolutions per level (encoder; decoder mirrored)
    latent: int = 64
    fc: int = 256
    pool: int = 4  # vertices per cluster, level to level
    seed: int = 0


class BodyGraph:
    """The body surface the garments are encoded on: kept vertices (rest pose), normals, faces, and
    the pooling hierarchy (cluster of every vertex per level, mean adjacency per level)."""

    def __init__(self, rb: RestBody, cfg: GCVAEConfig):
        keep = ~np.isin(rb.owner, [J[n] for n in LEFT_OUT])
        self.index = np.flatnonzero(keep)  # into the full body
        remap = np.full(len(rb.v), -1)
        remap[self.index] = np.arange(len(self.index))
        f = remap[rb.f]
        self.faces = f[(f >= 0).all(1)]
        self.v = torch.from_numpy(rb.v[self.index]).float()
        self.n = torch.from_numpy(rb.n[self.index]).float()
        segment = rb.owner[self.index]
        self.adj = [mean_adjacency(self.faces, len(self.index))]
        self.assign: list[torch.Tensor] = []  # level l vertex -> level l+1 cluster
        pos, edges = rb.v[self.index], mesh.unique_edges(self.faces)
        for _ in range(len(cfg.channels) - 1):
            labels = np.empty(len(pos), np.int64)
            start, centres, seg_next = 0, [], []
            for s in np.unique(segment):
                sel = np.flatnonzero(segment == s)
                k = max(1, int(round(len(sel) / cfg.pool)))
                c, lab = kmeans2(pos[sel], k, seed=cfg.seed, minit="++") if k > 1 else (pos[sel].mean(0, keepdims=True),
                                                                                          np.zeros(len(sel), int))
                used, lab = np.unique(lab, return_inverse=True)  # empty clusters dropped
                labels[sel] = start + lab
                centres.append(c[used])
                seg_next += [s] * len(used)
                start += len(used)
            self.assign.append(torch.from_numpy(labels))
            e = labels[edges]
            e = np.unique(np.sort(e[e[:, 0] != e[:, 1]], 1), axis=0)
            pos, segment = np.concatenate(centres), np.array(seg_next)
            self.adj.append(edge_adjacency(e, len(pos)))
            edges = e
        self.sizes = [len(self.index)] + [int(a.max()) + 1 for a in self.assign]


def edge_adjacency(edges: np.ndarray, n: int) -> torch.Tensor:
    """Mean adjacency of a graph given by its edges (the coarse levels have no faces), without
    self-loops: a vertex's own feature enters through ``GraphConv.own`` only."""
    return sparse_tensor(mesh.edge_mean(edges, n))


def pool(x: torch.Tensor, assign: torch.Tensor, n: int) -> torch.Tensor:
    """Max over each cluster: (B, N, C) -> (B, n, C)."""
    out = torch.full((x.shape[0], n, x.shape[2]), -torch.inf, dtype=x.dtype)
    return out.scatter_reduce(1, assign[None, :, None].expand_as(x), x, "amax")


def graph_conv(conv: GraphConv, x: torch.Tensor, adj: torch.Tensor) -> torch.Tensor:
    """A GraphConv over a batch (B, N, C)."""
    b, n, c = x.shape
    agg = torch.sparse.mm(adj.to(x.dtype), x.permute(1, 0, 2).reshape(n, b * c)).view(n, b, c).permute(1, 0, 2)
    return conv.own(x) + conv.nb(agg)


class GCVAE(nn.Module):
    def __init__(self, graph: BodyGraph, cfg: GCVAEConfig | None = None):
        super().__init__()
        self.cfg = cfg = cfg or GCVAEConfig()
        self.graph = graph
        ch = list(cfg.channels)
        self.enc = nn.ModuleList(GraphConv(a, b) for a, b in zip([7] + ch[:-1], ch))
        flat = graph.sizes[-1] * ch[-1]
        self.enc_fc = nn.Linear(flat, cfg.fc)
        self.type_head = nn.Linear(cfg.fc, len(TYPES))  # L_cvar: the condition regressed from the encoder
        self.mu = nn.Linear(cfg.fc + len(TYPES), cfg.latent)
        self.logvar = nn.Linear(cfg.fc + len(TYPES), cfg.latent)
        self.dec_fc = nn.Sequential(nn.Linear(cfg.latent + len(TYPES), cfg.fc), nn.ReLU(), nn.Linear(cfg.fc, flat))
        rev = ch[::-1]
        self.dec = nn.ModuleList(GraphConv(a, b) for a, b in zip(rev, rev[1:] + [rev[-1]]))
        self.out = nn.Linear(rev[-1], 4)  # offset (3), mask logit
        # p(z | type): a Gaussian per type fitted to the training garments' codes (fit_type_prior)
        self.register_buffer("prior_mean", torch.zeros(len(TYPES), cfg.latent))
        self.register_buffer("prior_tril", torch.eye(cfg.latent).expand(len(TYPES), -1, -1).clone())

    def encode(self, offsets: torch.Tensor, mask: torch.Tensor, kind: torch.Tensor):
        """(B, N, 3), (B, N), one-hot (B, T) -> mu, logvar (B, Z), type logits (B, T)."""
        g = self.graph
        x = torch.cat([g.v.expand(len(offsets), -1, -1), offsets * 10.0, mask[..., None]], -1)
        for lvl, conv in enumerate(self.enc):
            x = torch.relu(graph_conv(conv, x, g.adj[lvl]))
            if lvl < len(g.assign):
                x = pool(x, g.assign[lvl], g.sizes[lvl + 1])
        h = torch.relu(self.enc_fc(x.flatten(1)))
        hc = torch.cat([h, kind], -1)
        return self.mu(hc), self.logvar(hc), self.type_head(h)

    def decode(self, z: torch.Tensor, kind: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, Z), one-hot (B, T) -> offsets (B, N, 3), mask logits (B, N)."""
        g = self.graph
        x = self.dec_fc(torch.cat([z, kind], -1)).view(len(z), g.sizes[-1], -1)
        for i, conv in enumerate(self.dec):
            lvl = len(g.sizes) - 1 - i
            x = torch.relu(graph_conv(conv, x, g.adj[lvl]))
            if lvl > 0:
                x = x[:, g.assign[lvl - 1]]  # unpool: copy to the finer level's vertices
        y = self.out(x)
        return y[..., :3] / 10.0, y[..., 3]

    def forward(self, offsets, mask, kind):
        mu, logvar, type_logits = self.encode(offsets, mask, kind)
        z = mu + torch.randn_like(mu) * torch.exp(0.5 * logvar) if self.training else mu
        o, m = self.decode(z, kind)
        return o, m, mu, logvar, type_logits

    @torch.no_grad()
    def fit_type_prior(self, offsets: torch.Tensor, mask: torch.Tensor, kinds: list[str], chunk: int = 32) -> None:
        """p(z | type) as the Gaussian of the codes (means of q(z | x)) of each type's garments,
        its covariance shrunk towards the diagonal (a few hundred garments, 64 dimensions)."""
        cond = one_hot(kinds)
        mu = torch.cat([self.encode(offsets[i:i + chunk], mask[i:i + chunk], cond[i:i + chunk])[0]
                        for i in range(0, len(kinds), chunk)])
        for t in range(len(TYPES)):
            z = mu[cond[:, t] > 0]
            if len(z) < 2:
                continue
            cov = torch.cov(z.T)
            cov = 0.5 * cov + 0.5 * torch.diag(cov.diagonal()) + 1e-6 * torch.eye(len(cov))
            self.prior_mean[t], self.prior_tril[t] = z.mean(0), torch.linalg.cholesky(cov)

    def sample_codes(self, kind: str, n: int, generator: torch.Generator | None = None) -> torch.Tensor:
        """(n, Z) codes drawn from p(z | kind)."""
        t = TYPES.index(kind)
        eps = torch.randn(n, self.cfg.latent, generator=generator)
        return self.prior_mean[t] + eps @ self.prior_tril[t].T

    def save(self, path: Path, extra: dict) -> None:
        sd = {k: v.half() for k, v in self.state_dict().items()}
        cfg = asdict(self.cfg) | {"channels": list(self.cfg.channels)}
        paths.atomic_write(Path(path), lambda t: torch.save({"cfg": cfg, "state": sd} | extra, t))

    @classmethod
    def load(cls, path: Path, rb: RestBody) -> tuple[GCVAE, dict]:
        ck = paths.load_checkpoint(path, "recon garment train --model gcvae")
        cfg = GCVAEConfig(**(ck["cfg"] | {"channels": tuple(ck["cfg"]["channels"])}))
        m = cls(BodyGraph(rb, cfg), cfg)
        m.load_state_dict({k: v.float() for k, v in ck["state"].items()})
        return m.eval(), ck


def one_hot(kinds: list[str]) -> torch.Tensor:
    return torch.nn.functional.one_hot(torch.tensor([TYPES.index(k) for k in kinds]), len(TYPES)).float()


def register(graph: BodyGraph, vertices: np.ndarray, faces: np.ndarray, close: int = 2,
             samples: int = 40000) -> tuple[np.ndarray, np.ndarray]:
    """A garment on the rest body as (offsets (N, 3), mask (N,)) on ``graph``'s vertices."""
    bv = graph.v.numpy()
    hit = np.zeros(len(bv))
    _, near = cKDTree(bv).query(vertices)
    hit[near] = 1.0
    avg = mesh.neighbour_mean(graph.faces, len(bv))
    m = hit
    for _ in range(close):  # closing: dilate then erode, pinholes between hit vertices filled
        m = np.maximum(m, (avg @ m > 0.0).astype(float))
    for _ in range(close):
        m = np.minimum(m, (avg @ m >= 0.999).astype(float))
    mask = np.maximum(m, hit)
    pts, _ = trimesh.sample.sample_surface_even(trimesh.Trimesh(vertices, faces, process=False), samples, seed=0)
    pts = np.concatenate([pts, vertices])
    _, idx = cKDTree(pts).query(bv)
    offsets = (pts[idx] - bv) * mask[:, None]
    return offsets.astype(np.float32), mask.astype(np.float32)


def garment_mesh(graph: BodyGraph, offsets: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Decoded garment: body + offsets, the faces whose three vertices are covered, compacted."""
    on = mask > 0.5
    f = graph.faces[on[graph.faces].all(1)]
    v = graph.v.numpy() + offsets
    if len(f) == 0:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int64)
    return mesh.compact(v, f)
