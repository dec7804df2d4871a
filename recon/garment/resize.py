"""Outfit resizing with PBNS (thesis 5.5.6): body shape + tightness -> rest-pose outfit.
Trained by ``recon garment resize`` (recon.garment.pbns.train), evaluated by recon.garment.pbns.eval.

The pose input of PBNS is replaced by the body shape beta concatenated with the outfit
tightness gamma (R^2) and skinning is removed:

    V(beta, gamma) = E_T(beta, gamma) + f_X([beta, gamma]) . D        (rest pose)

E_T is the CLOTH3D resizing of the template (3.3.2): the rest-body displacement from the
template's shape to the *target* shape beta + gamma (gamma offsets anny's "weight" and
"height" phenotypes, CLOTH3D's fatness and size) moved to every cloth vertex from its nearest
body vertex and Laplacian-smoothed. Its edge lengths are the rest lengths of the edge energy.
Training is unsupervised with the PBNS energies on the rest body of shape beta (edge vs E_T,
bending, collision, cloth-to-cloth by layer, gravity, waist pins at E_T): the network fixes
what the displacement transfer gets wrong (cloth inside a fuller body, loose cloth that
should hang). gamma > 0 is looser.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn

from recon import paths
from recon.body.base import BodyModel
from recon.errors import ReconError
from recon.garment import losses
from recon.garment.mesh import neighbour_mean, smooth_vertex_values

TIGHTNESS_PHENOTYPES = ("weight", "height")  # what gamma offsets (anny), like CLOTH3D's beta_0, beta_1
TIGHTNESS_RANGE = ((-0.1, 0.3), (-0.05, 0.1))  # sampling range per component, biased to loose (CLOTH3D)


@dataclass
class ResizeConfig:
    samples: int = 600  # (shape, tightness) training samples
    val_samples: int = 100
    epochs: int = 2  # more epochs trade edge error for the body margin (the garment model card)
    batch: int = 16
    lr: float = 1e-3
    lr_psd: float = 3e-4
    hidden: int = 32
    layers: int = 4
    embedding: int = 32
    smooth: int = 10  # Laplacian iterations on the transferred displacement
    candidates: int = 8
    seed: int = 0
    edge: losses.EdgeConfig = field(default_factory=losses.EdgeConfig)
    bend: losses.BendConfig = field(default_factory=losses.BendConfig)
    collision: losses.CollisionConfig = field(default_factory=lambda: losses.CollisionConfig(weight=1e5))
    gravity: losses.GravityConfig = field(default_factory=losses.GravityConfig)
    pin: losses.PinConfig = field(default_factory=losses.PinConfig)


class Resizer(nn.Module):
    """[beta, gamma] -> 4 x 32 MLP -> X -> X . D: rest-pose correction of E_T (no skinning)."""

    def __init__(self, num_vertices: int, num_inputs: int, cfg: ResizeConfig | None = None):
        super().__init__()
        cfg = cfg or ResizeConfig()
        dims = [num_inputs] + [cfg.hidden] * cfg.layers
        mlp: list[nn.Module] = []
        for a, b in zip(dims[:-1], dims[1:]):
            mlp += [nn.Linear(a, b), nn.ReLU()]
        self.mlp = nn.Sequential(*mlp, nn.Linear(cfg.hidden, cfg.embedding))
        self.D = nn.Parameter(torch.zeros(cfg.embedding, num_vertices, 3))

    def forward(self, shape: torch.Tensor, tightness: torch.Tensor) -> torch.Tensor:
        x = self.mlp(torch.cat([shape, tightness], -1))
        return torch.einsum("bk,knc->bnc", x, self.D)


class Transfer:
    """E_T: CLOTH3D displacement transfer (3.3.2) of an outfit's rest vertices, modelled on the
    body of shape ``shape0``, to other shapes: the rest-body displacement of each cloth vertex's
    nearest body vertex, Laplacian-smoothed so body detail does not print through."""

    def __init__(self, body: BodyModel, rest: np.ndarray, faces: np.ndarray, shape0: torch.Tensor, smooth: int = 10):
        self.body, self.rest, self.faces, self.smooth = body, rest, faces, smooth
        with torch.no_grad():
            self.v0 = body.rest_geometry(shape0.reshape(1, -1).to(body.mean_shape))[0][0].numpy()
        self.idx = cKDTree(self.v0).query(rest)[1]
        self.avg = neighbour_mean(faces, len(rest))

    def target(self, shape: torch.Tensor, tightness: torch.Tensor) -> torch.Tensor:
        """Shape the garment is sized for: ``shape`` with gamma added to TIGHTNESS_PHENOTYPES."""
        cols = [list(self.body.shape_names).index(n) for n in TIGHTNESS_PHENOTYPES]
        t = shape.clone()
        t[..., cols] = (t[..., cols] + tightness).clamp(0, 1)
        return t

    def resize(self, shape: torch.Tensor, body_rest: np.ndarray | None = None) -> np.ndarray:
        """(B, S) target shapes -> (B, N, 3) resized rest vertices. ``body_rest`` (B, V, 3): the
        bodies' rest vertices when the caller has them already."""
        if body_rest is None:
            with torch.no_grad():
                body_rest = self.body.rest_geometry(shape.to(self.body.mean_shape))[0].numpy()
        v1 = body_rest
        d = [v[self.idx] - self.v0[self.idx] for v in v1]
        smooth = [smooth_vertex_values(x, self.faces, self.smooth, self.avg) for x in d]
        return np.stack([self.rest + x for x in smooth]).astype(np.float32)

    def __call__(self, shape: torch.Tensor, tightness: torch.Tensor) -> np.ndarray:
        """(B, S), (B, 2) -> (B, N, 3) rest vertices sized for shape + tightness."""
        return self.resize(self.target(shape, tightness))


class OutfitResizer:
    """Trained resizer: ``rest(shape, tightness)`` -> (B, N, 3) rest outfit on that body."""

    def __init__(self, body: BodyModel, path: Path, rest: np.ndarray, faces: np.ndarray):
        ck = paths.load_checkpoint(path, "recon garment resize")
        meta = json.loads(ck["meta_json"])
        net_keys = ("hidden", "layers", "embedding", "smooth")
        cfg = ResizeConfig(**{k: v for k, v in meta["config"].items() if k in net_keys})
        self.net = Resizer(ck["num_vertices"], ck["num_inputs"], cfg).eval()
        self.net.load_state_dict(ck["state"])
        self.transfer = Transfer(body, rest, faces, ck["shape0"], cfg.smooth)

    @torch.no_grad()
    def rest(self, shape: torch.Tensor, tightness: torch.Tensor | None = None, corrected: bool = True) -> torch.Tensor:
        shape = shape.reshape(-1, shape.shape[-1]).float()
        tightness = torch.zeros(len(shape), 2) if tightness is None else tightness.reshape(-1, 2).float()
        base = torch.from_numpy(self.transfer(shape, tightness))
        return base + self.net(shape, tightness) if corrected else base


class RestResizer:
    """An outfit's rest vertices for any body shape, remembered per shape: its trained resizer
    (``OutfitResizer``, a tightness allowed) where ``resizer_path`` is given, else the transfer.
    ``rest``/``faces``: the outfit's, on the body shape ``shape`` it was made on."""

    def __init__(self, rest: torch.Tensor, faces: torch.Tensor, shape: torch.Tensor, resizer_path: Path | None):
        self.rest, self.faces, self.shape, self.path = rest, faces, shape, resizer_path
        self.resizer: OutfitResizer | None = None
        self.transfer: Transfer | None = None
        self._resized: dict[bytes, torch.Tensor] = {}

    def __call__(self, body: BodyModel, shape: torch.Tensor, smooth: int = 10, tightness=None) -> torch.Tensor:
        """(N, 3) for ``shape`` (S,); ``tightness`` (2,) needs the resizer (> 0 looser)."""
        if self.path is not None:
            if self.resizer is None:
                self.resizer = OutfitResizer(body, self.path, self.rest.numpy(), self.faces.numpy())
            t = torch.zeros(2) if tightness is None else torch.as_tensor(tightness, dtype=torch.float32)
            key = shape.detach().cpu().numpy().tobytes() + t.numpy().tobytes()
            if key not in self._resized:
                self._resized[key] = self.resizer.rest(shape.detach().cpu(), t)[0]
            return self._resized[key]
        if tightness is not None:
            raise ReconError("tightness needs a trained resizer: run `recon garment resize`")
        key = shape.detach().cpu().numpy().tobytes()
        if key not in self._resized:
            if self.transfer is None or self.transfer.smooth != smooth:
                self.transfer = Transfer(body, self.rest.numpy(), self.faces.numpy(), self.shape, smooth)
            self._resized[key] = torch.from_numpy(self.transfer.resize(shape.detach().cpu().reshape(1, -1))[0])
        return self._resized[key]
