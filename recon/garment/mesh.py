"""Small triangle-mesh helpers the garment code needs and trimesh does not give directly:
level-set cuts, ordered boundary loops, unique edges and face adjacency, normals as tensors, and
nearest-neighbour correspondences (scipy KD-trees)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import torch
import trimesh
from scipy.spatial import cKDTree


def cut(vertices: np.ndarray, faces: np.ndarray, field: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keep the part of a mesh where a per-vertex scalar ``field`` > 0, cutting triangles along
    its zero level (linear interpolation on edges; cut vertices are shared by the faces on both
    sides of an edge, so the result stays connected and manifold). Returns (vertices, faces)
    with unused vertices removed."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    s = np.asarray(field, np.float64)
    s = np.where(np.abs(s) < 1e-9, -1e-9, s)  # no vertex exactly on the level: no degenerate faces
    inside = s > 0
    new_v, edge_vertex = [v], {}

    def on_edge(a: int, b: int) -> int:
        key = (min(a, b), max(a, b))
        if key not in edge_vertex:
            t = s[a] / (s[a] - s[b])
            edge_vertex[key] = len(v) + len(edge_vertex)
            new_v.append((v[a] + t * (v[b] - v[a]))[None])
        return edge_vertex[key]

    out = [f[inside[f].all(1)]]
    for tri in f[inside[f].any(1) & ~inside[f].all(1)]:
        poly = []  # Sutherland-Hodgman clip of one triangle against s > 0
        for i in range(3):
            a, b = tri[i], tri[(i + 1) % 3]
            if inside[a]:
                poly.append(a)
            if inside[a] != inside[b]:
                poly.append(on_edge(a, b))
        out.append(np.array([[poly[0], poly[k], poly[k + 1]] for k in range(1, len(poly) - 1)], np.int64))
    v2 = np.concatenate(new_v)
    f2 = np.concatenate([o.reshape(-1, 3) for o in out])
    return compact(v2, f2)


def compact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    used = np.unique(faces)
    remap = np.full(len(vertices), -1, np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[faces]


def faces_within(faces: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """The faces with all three corners among the vertices ``keep`` (N,) bool, renumbered to those
    vertices in order (isolated ones kept, unlike ``compact``)."""
    return (np.cumsum(keep) - 1)[faces[keep[faces].all(1)]]


def largest_component_faces(faces: np.ndarray) -> np.ndarray:
    """The faces of the largest edge-connected component, vertex ids unchanged."""
    adjacency = trimesh.Trimesh(faces=faces, process=False).face_adjacency
    labels = trimesh.graph.connected_component_labels(adjacency, node_count=len(faces))
    return faces[labels == np.bincount(labels).argmax()]


def largest_component(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return compact(vertices, largest_component_faces(faces))


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Ordered vertex loops of the open boundary (edges used by one face), oriented as the faces.
    A vertex where two boundary loops touch (a bowtie, e.g. in a decoded or hand-made mesh) is
    passed through once per loop; a walk that finds no way on ends its loop there."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(e, 1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    nxt: dict[int, list[int]] = {}
    for a, b in e[cnt[inv.ravel()] == 1]:
        nxt.setdefault(int(a), []).append(int(b))
    loops = []
    while nxt:
        start = cur = next(iter(nxt))
        loop = [start]
        while cur in nxt:
            outs = nxt[cur]
            n = outs.pop()
            if not outs:
                del nxt[cur]
            if n == start:
                break
            loop.append(n)
            cur = n
        loops.append(np.array(loop))
    return loops


def unique_edges(faces: np.ndarray) -> np.ndarray:
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(e, 1), axis=0)


def neighbour_mean(faces: np.ndarray, n: int):
    """(n, n) sparse matrix taking per-vertex values to the mean over each vertex's edge neighbours
    (zero for a vertex on no edge)."""
    return edge_mean(unique_edges(faces), n)


def edge_mean(edges: np.ndarray, n: int):
    """``neighbour_mean`` of a graph given by its unique edges (E, 2), i < j: no self-loops."""
    e = edges
    a = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
    deg = np.maximum(np.asarray(a.sum(1)).ravel(), 1)
    return (sp.diags(1.0 / deg) @ a).tocsr()


def smooth_vertex_values(x: np.ndarray, faces: np.ndarray, iterations: int, avg=None) -> np.ndarray:
    """Laplacian smoothing of per-vertex values (N, C): x <- (x + mean of the neighbours) / 2.
    ``avg``: ``neighbour_mean(faces, N)`` when the caller keeps it (building it costs more)."""
    avg = neighbour_mean(faces, len(x)) if avg is None else avg
    for _ in range(iterations):
        x = 0.5 * x + 0.5 * (avg @ x)
    return x


def face_adjacency(faces: np.ndarray) -> np.ndarray:
    """(A, 2) pairs of faces sharing an edge."""
    return trimesh.Trimesh(np.zeros((int(faces.max()) + 1, 3)), faces, process=False).face_adjacency


def take(v: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``v[:, idx]`` for (B, V, C) and an index array of any shape: (B, *idx.shape, C), by
    ``index_select``, whose forward and backward are faster on the CPU than advanced indexing's
    (a single sample gathers from its 2-D view, whose backward is faster still)."""
    flat = idx.reshape(-1)
    out = v[0].index_select(0, flat) if len(v) == 1 else v.index_select(1, flat)
    return out.view(len(v), *idx.shape, v.shape[-1])


def face_normals(v: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """(B, V, 3), (F, 3) -> unit face normals (B, F, 3)."""
    t = take(v, faces)
    n = torch.cross(t[:, :, 1] - t[:, :, 0], t[:, :, 2] - t[:, :, 0], dim=-1)
    return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def vertex_normals(v: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Area-weighted unit vertex normals (B, V, 3)."""
    t = take(v, faces)
    n = torch.cross(t[:, :, 1] - t[:, :, 0], t[:, :, 2] - t[:, :, 0], dim=-1)
    out = torch.zeros_like(v)
    for k in range(3):
        out.index_add_(1, faces[:, k], n)
    return out / out.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def nearest(points: torch.Tensor, query: torch.Tensor, k: int = 1) -> torch.Tensor:
    """Indices of the k nearest of ``points`` (B, P, 3) for every ``query`` (B, Q, 3): (B, Q) for
    k = 1, else (B, Q, k). Exact (KD-tree), no gradient."""
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
