"""Garments out of the GCVAE's latent space (thesis 3.4): drawn per type, decoded, interpolated
(``recon garment sample`` is recon.garment.gcvae.command)."""
from __future__ import annotations

import numpy as np
import torch

from recon.errors import MissingFile, ReconError
from recon.garment import mesh, store
from recon.garment.gcvae.model import GCVAE, TYPES, garment_mesh, one_hot
from recon.garment.templates import RestBody


def load_model(rb: RestBody) -> GCVAE:
    path = store.gcvae_path()
    if not path.exists():
        raise MissingFile(f"no GCVAE {path}: run `recon garment train --model gcvae` (its time: "
                          "recon/garment/weights/MODEL_CARD.md)")
    return GCVAE.load(path, rb)[0]


@torch.no_grad()
def sample(model: GCVAE, kind: str, n: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` garments of type ``kind`` from p(z | kind): (vertices, faces) each, the largest piece."""
    if kind not in TYPES:
        raise ReconError(f"unknown garment type {kind!r}: {', '.join(TYPES)}")
    return decode(model, model.sample_codes(kind, n, torch.Generator().manual_seed(seed)), kind)


@torch.no_grad()
def decode(model: GCVAE, z: torch.Tensor, kind: str | torch.Tensor) -> list[tuple[np.ndarray, np.ndarray]]:
    """Garment meshes of latent codes (B, Z) under a type (a name, or (B, T) weights between types)."""
    cond = one_hot([kind] * len(z)) if isinstance(kind, str) else kind
    o, m = model.decode(z, cond)
    out = []
    for i in range(len(z)):
        v, f = garment_mesh(model.graph, o[i].numpy(), torch.sigmoid(m[i]).numpy())
        out.append(mesh.largest_component(v, f) if len(f) else (v, f))
    return out


@torch.no_grad()
def interpolate(model: GCVAE, a: tuple, b: tuple, steps: int = 5) -> list[tuple[np.ndarray, np.ndarray]]:
    """Garments between two registered ones, ``(offsets (N, 3), mask (N,), type)`` each: their
    latent means and type conditions blended linearly."""
    codes, conds = [], []
    for o, m, kind in (a, b):
        c = one_hot([kind])
        codes.append(model.encode(torch.as_tensor(o)[None], torch.as_tensor(m)[None], c)[0])
        conds.append(c)
    t = torch.linspace(0, 1, steps)[:, None]
    return decode(model, (1 - t) * codes[0] + t * codes[1], (1 - t) * conds[0] + t * conds[1])
