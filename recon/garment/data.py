"""What every garment family trains and evaluates on: balanced mocap pose sets and the posed
bodies (the template a trained PBNS file was made for: ``recon.garment.pbns.model.trained_outfit``)."""
from __future__ import annotations

import numpy as np
import roma
import torch

from recon.body.base import BodyModel
from recon.garment.mesh import vertex_normals
from recon.poses.mocap import MocapPoses

MIN_POSE_DISTANCE = 0.5  # radians: every pair of a pose set differs this much in some joint (thesis 5.4.3)


def balanced_poses(rotvec: np.ndarray, n: int, min_distance: float, seed: int) -> np.ndarray:
    """Greedy subset in random order: keep a pose if it differs from every kept one by at least
    ``min_distance`` rad in some non-root parameter (thesis 5.4.3)."""
    rng = np.random.default_rng(seed)
    flat = rotvec[:, 1:].reshape(len(rotvec), -1)
    kept: list[int] = []
    buf = np.empty((n, flat.shape[1]), flat.dtype)
    for i in rng.permutation(len(flat)):
        if kept and np.abs(buf[:len(kept)] - flat[i]).max(1).min() < min_distance:
            continue
        buf[len(kept)] = flat[i]
        kept.append(i)
        if len(kept) == n:
            break
    return np.array(kept)


def pose_set(split: str, n: int, min_distance: float, seed: int) -> torch.Tensor:
    """(n, 24, 3, 3) balanced mocap poses of a split, root translation dropped."""
    m = MocapPoses.load(split)
    idx = balanced_poses(m.rotvec, n, min_distance, seed)
    return roma.rotvec_to_rotmat(torch.from_numpy(m.rotvec[idx]).float())


def posed_bodies(body: BodyModel, rotmats: torch.Tensor, shape: torch.Tensor, chunk: int = 64,
                 transl: torch.Tensor | None = None):
    """Body vertices, vertex normals and joint transforms for all poses (no gradient)."""
    vs, ns, ts = [], [], []
    with torch.no_grad():
        for i in range(0, len(rotmats), chunk):
            r = rotmats[i:i + chunk]
            o = body(r, shape.expand(len(r), -1), transl=None if transl is None else transl[i:i + chunk])
            vs.append(o.vertices)
            ns.append(vertex_normals(o.vertices, body.faces))
            ts.append(o.transforms)
    return torch.cat(vs), torch.cat(ns), torch.cat(ts)
