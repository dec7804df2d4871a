"""Dress a posed body with a trained PBNS outfit.

The outfit was simulated on one body shape. For another shape its rest pose is resized the
CLOTH3D way (thesis 3.3.2): the rest-body displacement between the two shapes is transferred
to every cloth vertex from its nearest body vertex and Laplacian-smoothed, so body detail does
not print through. Pose-space deformations (PBNS) and skinning then follow the new body.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from recon.garment.mesh import smooth_vertex_values
from recon.garment.pbns import PBNS
from recon.garment.train import WEIGHTS_DIR


@dataclass
class DressedOutfit:
    vertices: np.ndarray  # (B, N, 3) posed cloth, same frame as the body output
    faces: np.ndarray  # (F, 3)
    garment_id: np.ndarray  # (N,)
    names: list[str]


class Dresser:
    """``Dresser("tshirt-trousers")(body, rotmats, shape, transl) -> DressedOutfit``."""

    def __init__(self, outfit: str = "tshirt-trousers", path: str | Path | None = None):
        import json

        if path is None and outfit.endswith(".pt"):  # a weights file instead of a preset name
            path = outfit
        path = Path(path or WEIGHTS_DIR / f"pbns_{outfit}.pt")
        if not path.exists():
            raise FileNotFoundError(f"no trained outfit {path}: run `recon garment train --outfit {outfit}`")
        self.model, ck = PBNS.load(path)
        self.shape = ck["shape"]
        self.garment_id = ck["garment_id"].numpy()
        self.names = json.loads(ck["meta_json"])["garments"]
        self._resized: dict[bytes, torch.Tensor] = {}

    def rest_for(self, body, shape: torch.Tensor, smooth: int = 10) -> torch.Tensor:
        """Outfit rest vertices resized to ``shape`` (1-D tensor)."""
        key = shape.detach().cpu().numpy().tobytes()
        if key not in self._resized:
            from scipy.spatial import cKDTree

            with torch.no_grad():
                v0, _ = body.rest_geometry(self.shape[None].to(body.mean_shape))
                v1, _ = body.rest_geometry(shape.reshape(1, -1).to(body.mean_shape))
            rest = self.model.rest.numpy()
            _, idx = cKDTree(v0[0].numpy()).query(rest)
            d = (v1[0] - v0[0]).numpy()[idx]
            d = smooth_vertex_values(d, self.model.faces.numpy(), smooth)
            self._resized[key] = torch.from_numpy(rest + d).float()
        return self._resized[key]

    @torch.no_grad()
    def __call__(self, body, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None = None,
                 up: torch.Tensor | None = None) -> DressedOutfit:
        """``up``: (3, 3) rotation from the frame of ``rotmats``' root to the gravity-aligned body
        frame (+Y up); e.g. diag(1, -1, -1) for poses in an upright OpenCV camera frame. The
        network sees the gravity-aligned pose; the cloth is posed in the input frame."""
        b = rotmats.shape[0]
        shape = shape.reshape(b, -1)
        out = body(rotmats, shape, transl=transl, points_only=True)
        r = rotmats.clone()
        if up is not None:
            r[:, 0] = up.to(r) @ r[:, 0]
        dt = self.model.deformation(r)
        rest = torch.stack([self.rest_for(body, s) for s in shape])
        verts = self.model.skin(rest + dt, out.transforms)
        return DressedOutfit(verts.numpy(), self.model.faces.numpy(), self.garment_id, self.names)

