"""Post-hoc collision resolution of a posed outfit, for rendering and export.

PBNS leaves about 1 % of the cloth vertices a few millimetres inside the body, mostly at the
hips in deep flexion (eval/results/garment-pbns.md), where skin pokes through the cloth in a
render. ``CollisionResolver`` moves every such vertex to ``eps`` outside, along the normal of its nearest
body vertex (the test of the collision metric and loss), and spreads the move over the
neighbouring cloth (a harmonic extension over ``spread`` rings) so it leaves no spikes; then outer
layers are pushed out of the inner ones by the layer order. Given the rest garment, a strain step
comes first: ``strain_iters`` iterations of projective dynamics (each edge's target is its rest
length along its current direction; a global solve with a pre-factored matrix, anchored to the
prediction by ``strain_anchor``; ``strain_smooth`` > 0 also penalises a rough move, at the cost of
a denser factor), each followed by the contact planes of the vertices near the body. Not part of
the networks: the evaluations report them with and without it, and its cost.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import torch
from scipy.sparse.linalg import splu
from scipy.spatial import cKDTree

from recon.garment import mesh


class CollisionResolver:
    """``CollisionResolver(faces, layer)(cloth, body_v, body_faces) -> cloth`` (B, N, 3), metres."""

    def __init__(self, faces: np.ndarray, layer: np.ndarray | None = None, eps: float = 0.002,
                 spread: int = 2, passes: int = 3, cloth_reach: float = 0.02, strain_iters: int = 10,
                 strain_anchor: float = 0.01, strain_smooth: float = 0.0, contact_reach: float = 0.02):
        self.faces = np.asarray(faces)
        self.n = int(self.faces.max()) + 1
        layer = np.zeros(self.n, np.int64) if layer is None else np.asarray(layer).astype(np.int64)
        # (inner, outer) vertex ids per outer layer, the order of CollisionLoss.pairs
        self.pairs = [(np.nonzero(layer < lay)[0], np.nonzero(layer == lay)[0])
                      for lay in sorted(set(layer.tolist()))[1:]]
        self.eps, self.spread, self.passes, self.cloth_reach = eps, spread, passes, cloth_reach
        self.strain_iters, self.strain_anchor, self.strain_smooth = strain_iters, strain_anchor, strain_smooth
        self.contact_reach = contact_reach
        self.edges = mesh.unique_edges(self.faces)
        self._strain = None  # (edge difference operator G, G^T, the prediction's term K, factor), made on first use
        self.avg = mesh.neighbour_mean(self.faces, self.n).astype(np.float32)
        self.cloth_inc = self.incidence(self.faces, self.n)
        self._body_faces, self._body_inc = None, None

    def _extend(self, rows: np.ndarray, push: np.ndarray, hit: np.ndarray) -> np.ndarray:
        """Displacements (N, 3) equal to ``push`` at the colliding vertices (``rows[hit]``), relaxed
        towards the neighbour mean elsewhere (``spread`` Jacobi steps): the move fades over a few
        rings."""
        fixed = rows[hit]
        d = np.zeros((self.n, 3), np.float32)
        d[fixed] = push[hit]
        target = d[fixed].copy()
        for _ in range(self.spread):
            d = self.avg @ d
            d[fixed] = target
        return d

    def _push(self, v: np.ndarray, tree, surf: np.ndarray, surf_n: np.ndarray, reach: float | None = None):
        """Moves (Q, 3) taking the vertices ``v`` that are behind ``surf`` (the normal of their
        nearest surface vertex) to eps in front of it; zero elsewhere. Returns (moves, inside)."""
        dist, idx = tree.query(v)
        depth = ((v - surf[idx]) * surf_n[idx]).sum(-1)
        inside = depth < 0
        if reach is not None:  # layers overlap only in part: far pairs are not contacts
            inside &= dist < reach
        return (self.eps - depth)[:, None] * surf_n[idx] * inside[:, None], inside

    @staticmethod
    def incidence(faces: np.ndarray, n: int):
        """(n, F) sparse vertex-face incidence: vertex normals = incidence @ face normals (an
        index_add over faces costs more on one thread: benchmarks/bench_garment.py)."""
        f = np.asarray(faces)
        rows, cols = f.ravel(), np.repeat(np.arange(len(f)), 3)
        return sp.csr_matrix((np.ones(f.size, np.float32), (rows, cols)), shape=(n, len(f)))

    @staticmethod
    def normals(v: np.ndarray, faces: np.ndarray, inc) -> np.ndarray:
        t = v[faces]
        n = inc @ np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])  # area-weighted
        return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)

    def _strain_system(self):
        """G (E, N) takes positions to edge vectors; the strain step solves
        (G^T G + K) x = G^T p + K y with K = anchor I + smooth S, S = (I - A)^T (I - A) and A the
        neighbour mean: a move that stays near the prediction y (and is smooth with ``strain_smooth``)."""
        if self._strain is None:
            e, m = self.edges, len(self.edges)
            rows, cols = np.r_[np.arange(m), np.arange(m)], np.r_[e[:, 0], e[:, 1]]
            g = sp.csr_matrix((np.r_[-np.ones(m), np.ones(m)], (rows, cols)), shape=(m, self.n))
            keep = self.strain_anchor * sp.identity(self.n, format="csr")
            if self.strain_smooth:  # a 2-ring stencil: a denser factor
                lap = sp.identity(self.n) - self.avg.astype(np.float64)
                keep = keep + self.strain_smooth * (lap.T @ lap)
            keep = keep.tocsr()
            # a symmetric ordering: less fill, faster solves than the default column ordering
            lu = splu((g.T @ g + keep).tocsc(), permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
            self._strain = (g, g.T.tocsr(), keep, lu)
        return self._strain

    def relax(self, v: np.ndarray, rest_len: np.ndarray, tree, surf: np.ndarray, surf_n: np.ndarray) -> np.ndarray:
        """The strain step on one frame ``v`` (N, 3): ``strain_iters`` projective-dynamics
        iterations towards the rest lengths (E,), each followed by the contact planes (eps in front
        of the nearest body vertex, found once) of the vertices within ``contact_reach`` of the body."""
        g, gt, keep, lu = self._strain_system()
        y = v.astype(np.float64)
        dist, idx = tree.query(v)
        near = np.nonzero(dist < self.contact_reach)[0]
        p, nrm = surf[idx[near]].astype(np.float64), surf_n[idx[near]].astype(np.float64)
        fixed = keep @ y
        x = y
        for _ in range(self.strain_iters):
            d = g @ x
            target = rest_len[:, None] * d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
            x = lu.solve(gt @ target + fixed)
            depth = ((x[near] - p) * nrm).sum(-1)
            x[near] += np.maximum(self.eps - depth, 0.0)[:, None] * nrm
        return x.astype(np.float32)

    @torch.no_grad()
    def __call__(self, cloth, body_v, body_faces, rest=None) -> torch.Tensor:
        """``rest``: the rest garment (N, 3) or one per sample (B, N, 3), whose edge lengths the
        strain step restores (no strain step without it, or with ``strain_iters`` 0)."""
        out = torch.as_tensor(cloth, dtype=torch.float32).detach().cpu().numpy().copy()
        bv = torch.as_tensor(body_v, dtype=torch.float32).detach().cpu().numpy()
        bf = np.asarray(body_faces)
        if self._body_faces is None or not np.array_equal(self._body_faces, bf):  # the body mesh rarely changes
            self._body_faces, self._body_inc = bf.copy(), self.incidence(bf, bv.shape[1])
        rest_len = None
        if rest is not None and self.strain_iters:
            r = torch.as_tensor(rest, dtype=torch.float32).detach().cpu().numpy()  # (N, 3) or (B, N, 3)
            lengths = np.linalg.norm(r[..., self.edges[:, 0], :] - r[..., self.edges[:, 1], :], axis=-1)
            rest_len = np.broadcast_to(lengths.astype(np.float64), (len(out), len(self.edges)))
        for b in range(len(out)):
            bn = self.normals(bv[b], bf, self._body_inc)
            tree = cKDTree(bv[b], balanced_tree=False, compact_nodes=False)  # builds faster, queries alike
            if rest_len is not None:
                out[b] = self.relax(out[b], rest_len[b], tree, bv[b], bn)
            # only moved vertices can change side, so later passes query those alone; a spread
            # move can push a neighbour into another body part (between the thighs)
            query = np.arange(self.n)
            for _ in range(self.passes):
                push, inside = self._push(out[b, query], tree, bv[b], bn)
                if not inside.any():
                    break
                d = self._extend(query, push, inside)
                out[b] += d
                query = np.nonzero(np.abs(d).sum(1) > 0)[0]
            for inner, outer in self.pairs:
                n = self.normals(out[b], self.faces, self.cloth_inc)[inner]
                tree = cKDTree(out[b, inner], balanced_tree=False, compact_nodes=False)
                push, hit = self._push(out[b, outer], tree, out[b, inner], n, self.cloth_reach)
                if hit.any():
                    d = self._extend(outer, push, hit)
                    d[inner] = 0.0  # inner layers stay put
                    out[b] += d
        return torch.from_numpy(out)
