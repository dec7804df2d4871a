"""Draped garments for the other-domain renders (``recon.synth.other``), in float64.

A wardrobe holds the five PBNS presets and CLOTH3D-style outfits of the held-out garment
distribution (``recon.garment.outfits``) made ready to animate by DeePSD, no training. An outfit
is sized to a body the CLOTH3D way (the rest-body displacement of the nearest body vertex,
smoothed; a looser fit is a heavier target body), posed by its PBNS model, and pushed out of the
body where it sinks in. Everything runs in float64 and is rounded to float32 only at the end. Not
bit-stable across CPUs: a nearest-vertex query that meets a tie (a symmetric body) can pick the
other vertex when a float64 differs in its last bit, moving a garment vertex by up to ~1 mm and a
few edge pixels of the image (``tests/test_other_domain.py`` bounds it).
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from recon.body.base import BodyModel
from recon.garment import mesh, store
from recon.garment.deepsd.model import DeePSD, OutfitGraph
from recon.garment.outfits import OutfitSampler
from recon.garment.pbns.model import PBNS, PBNSConfig
from recon.garment.templates import PRESETS, RestBody, make_outfit
from recon.render.normals import vertex_normals

PUSH_MARGIN = 0.004  # cloth kept this far (m) in front of the body surface
PUSH_REACH = 0.06  # only cloth whose nearest body vertex is this close is pushed


@dataclass
class Outfit64:
    name: str
    model: PBNS  # float64
    faces: np.ndarray  # (F, 3)
    garment_id: np.ndarray  # (N,)
    kinds: list[str]  # garment name per garment id
    shape0: torch.Tensor  # the body shape the template was made on
    idx: np.ndarray | None = None  # nearest body vertex of each rest cloth vertex (set by ``Wardrobe``)
    avg: object | None = None  # the template's neighbour-mean matrix


def _deepsd_outfit(net: DeePSD, rb: RestBody, outfit, name: str, shape0) -> Outfit64:
    """DeePSD's animation model of ``outfit`` computed in float64 (``DeePSD.outfit``'s recipe)."""
    g = OutfitGraph.of(rb, outfit)
    g.features, g.lbs_weights = g.features.double(), g.lbs_weights.double()
    g.adj = g.adj.double()
    with torch.no_grad():
        desc = net.descriptors(g)
        w = net.weights(g.lbs_weights, desc).numpy()
        d = net.blend_shapes(desc).reshape(len(desc), -1).numpy()
    avg = mesh.neighbour_mean(g.faces, len(desc))
    w = mesh.smooth_vertex_values(w, g.faces, 5, avg)
    d = mesh.smooth_vertex_values(d, g.faces, 5, avg)
    cfg = PBNSConfig(hidden=net.cfg.pose_hidden, layers=4, embedding=net.cfg.keys, optimise_weights=False)
    model = PBNS(torch.from_numpy(outfit.vertices), torch.from_numpy(g.faces), torch.ones(len(w), 24), cfg).double()
    with torch.no_grad():
        model.rest.copy_(torch.from_numpy(np.asarray(outfit.vertices, np.float64)))
        model.weight_logits.copy_(torch.log(torch.from_numpy(w).clamp_min(1e-6)))
        model.D.copy_(torch.from_numpy(d).view(len(w), net.cfg.keys, 3).permute(1, 0, 2).reshape(net.cfg.keys, -1))
        model.mlp.load_state_dict({k: v.double() for k, v in net.theta.state_dict().items()})
    return Outfit64(name, model.eval(), g.faces, outfit.garment_id, [x.name for x in outfit.garments], shape0)


class Wardrobe:
    """The presets (``presets``) and ``n_random`` CLOTH3D outfits of stream ``seed`` (made once
    each), of the held-out distribution (``held_out``: the other domain's) or the training one (the
    training generator's). ``body``: the float64 body model."""

    def __init__(self, body: BodyModel, seed: int, n_random: int = 8, presets: bool = True, held_out: bool = True):
        self.body = body
        self.outfits: list[Outfit64] = []
        for name in PRESETS if presets else ():
            model, ck = PBNS.load(store.trained_pbns(name))
            kinds = json.loads(ck["meta_json"])["garments"]
            self.outfits.append(Outfit64(name, model.double().eval(), model.faces.numpy(), ck["garment_id"].numpy(),
                                         kinds, ck["shape"].double()))
        if n_random:
            net, _ = DeePSD.load(store.deepsd_path())
            net = net.double()
            rb = RestBody(body)
            sampler, rng = OutfitSampler(held_out=held_out), np.random.default_rng([seed, 77])
            for k in range(n_random):
                family, specs = sampler(rng)
                o = make_outfit(body, specs)
                self.outfits.append(_deepsd_outfit(net, rb, o, f"{family}-{k}", body.mean_shape.double()))
        for o in self.outfits:
            with torch.no_grad():
                v0 = body.rest_geometry(o.shape0.reshape(1, -1).to(body.mean_shape))[0][0].numpy()
            o.idx = cKDTree(v0).query(o.model.rest.numpy())[1]
            o.avg = mesh.neighbour_mean(o.faces, len(o.idx))
            o.v0 = v0

    def dress(self, k: int, rotmats: torch.Tensor, shape: torch.Tensor, body_out, loose: float) -> np.ndarray:
        """Outfit ``k`` on one posed body: rotmats (1, 24, 3, 3) and shape (1, S) in float64,
        ``body_out`` its body output (transforms, vertices); ``loose`` >= 0 sizes the outfit for a
        heavier body (anny's weight + loose). (N, 3) float64 vertices in the body output's frame."""
        o = self.outfits[k]
        target = shape.clone()
        w = list(self.body.shape_names).index("weight")
        target[0, w] = (target[0, w] + loose).clamp(0.0, 1.0)
        with torch.no_grad():
            v1 = self.body.rest_geometry(target)[0][0].numpy()
        disp = mesh.smooth_vertex_values(v1[o.idx] - o.v0[o.idx], o.faces, 10, o.avg)
        rest = o.model.rest.numpy() + disp
        with torch.no_grad():
            posed = o.model.pose(rotmats, body_out.transforms, torch.from_numpy(rest))[0].numpy()
        return push_out(posed, body_out.vertices[0].numpy(), self.body.faces.numpy())


def push_out(cloth: np.ndarray, body_v: np.ndarray, body_f: np.ndarray) -> np.ndarray:
    """Cloth vertices behind the body surface (or closer than ``PUSH_MARGIN``) moved out along the
    nearest body vertex's normal."""
    n = vertex_normals(body_v, body_f)
    dist, idx = cKDTree(body_v).query(cloth)
    depth = ((cloth - body_v[idx]) * n[idx]).sum(1)
    move = (dist < PUSH_REACH) & (depth < PUSH_MARGIN)
    out = cloth.copy()
    out[move] += (PUSH_MARGIN - depth[move])[:, None] * n[idx[move]]
    return out
