"""Generated 3D training data for SMPLR: (J+, rotations, shape) triplets, no images.

Poses come from recon.poses.PoseSampler (mocap split + joint noise + mirror), shapes from
ShapeSampler; a random camera view rotates the root (yaw uniform, pitch ~ N(0, 15 deg),
roll ~ N(0, 5 deg)), so J+ is expressed as a camera would see it, pelvis at the origin.
Sets are cached in the recon cache by (split, size, seed).
"""
from __future__ import annotations

import logging

import numpy as np
import torch
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from recon import paths
from recon.body import lbs
from recon.body.base import BodyModel
from recon.poses.sampler import PoseSampler, ShapeSampler

log = logging.getLogger(__name__)


def view_rotations(n: int, rng: np.random.Generator) -> np.ndarray:
    yaw = rng.uniform(-180, 180, n)
    pitch = np.clip(rng.normal(0, 15, n), -45, 45)
    roll = np.clip(rng.normal(0, 5, n), -20, 20)
    return Rotation.from_euler("YXZ", np.stack([yaw, pitch, roll], 1), degrees=True).as_matrix()


def generate(body: BodyModel, split: str, n: int, seed: int, noise_deg: float, chunk: int = 2048) -> dict[str,
             torch.Tensor]:
    ps = PoseSampler(body, split=split, noise_deg=noise_deg, seed=seed)
    ss = ShapeSampler(body, seed=seed + 1)
    rng = np.random.default_rng(seed + 2)
    pts, rots, shapes = [], [], []
    for start in tqdm(range(0, n, chunk), desc=f"SMPLR data {split}", unit="chunk"):
        m = min(chunk, n - start)
        rot = lbs.as_rotmats(ps.sample(m), 24)
        view = torch.tensor(view_rotations(m, rng), dtype=torch.float32)
        rot[:, 0] = view @ rot[:, 0]
        shape = ss.sample(m)
        with torch.no_grad():
            pts.append(body(rot, shape, points_only=True).points)
        rots.append(rot)
        shapes.append(shape)
    return {"points": torch.cat(pts), "rotmats": torch.cat(rots), "shape": torch.cat(shapes)}


def load_or_generate(body: BodyModel, split: str, n: int, seed: int, noise_deg: float) -> dict[str, torch.Tensor]:
    path = paths.cache_dir() / f"smplr-data-{split}-{n}-s{seed}-n{noise_deg:g}.pt"
    if path.exists():
        return torch.load(path, weights_only=True)
    data = generate(body, split, n, seed, noise_deg)
    paths.atomic_write(path, lambda tmp: torch.save(data, tmp))
    return data
