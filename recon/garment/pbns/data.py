"""What the resizer is trained and evaluated on (thesis 5.5.6): (shape, tightness) conditions
with their transferred rest outfits."""
from __future__ import annotations

import numpy as np
import torch

from recon.body.base import BodyModel
from recon.garment.mesh import nearest, vertex_normals
from recon.garment.resize import TIGHTNESS_RANGE, Transfer
from recon.poses.sampler import ShapeSampler


def sample_conditions(body: BodyModel, n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """n (shape, tightness) conditions: shapes from the body's prior, tightness uniform in
    TIGHTNESS_RANGE."""
    shape = ShapeSampler(body, seed=seed).sample(n).float()
    rng = np.random.default_rng(seed)
    tight = np.stack([rng.uniform(lo, hi, n) for lo, hi in TIGHTNESS_RANGE], 1)
    return shape, torch.from_numpy(tight).float()


class Conditions:
    """Per (shape, tightness) condition: the transferred rest outfit E_T and its edge lengths, the
    rest body of that shape with normals, and nearest-body-vertex candidates of E_T."""

    def __init__(self, body: BodyModel, transfer: Transfer, shape, tight, edges: torch.Tensor, k: int):
        with torch.no_grad():
            bv = torch.cat([body.rest_geometry(shape[i:i + 64].to(body.mean_shape))[0]
                            for i in range(0, len(shape), 64)])
        self.shape, self.tight = shape, tight
        self.base = torch.from_numpy(np.concatenate([transfer(shape[i:i + 64], tight[i:i + 64])
                                                     for i in range(0, len(shape), 64)]))
        self.rest_len = (self.base[:, edges[:, 0]] - self.base[:, edges[:, 1]]).norm(dim=-1)
        self.bv, self.bn = bv.float(), vertex_normals(bv.float(), body.faces)
        self.cand = nearest(self.bv, self.base, k).to(torch.int16 if bv.shape[1] < 32767 else torch.int32)
