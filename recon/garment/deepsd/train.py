"""DeePSD's training (thesis 4.4.3), in two stages:

1. supervised: Phi, Omega, Psi and Theta on the drapes, L_data = |V_data - V_PBS|^2 (eq. 4.3);
   each step one outfit at its poses, the per-vertex heads on a random sample of its vertices
   (they are independent per vertex; Phi sees the whole mesh);
2. physics: chi alone (the rest frozen, "not helpful until the supervised training has
   converged"), L_phys = L_edge + L_bend + lambda_c L_collision (eq. 4.4-4.6, epsilon 5 mm) plus
   an L2 penalty on chi's displacements, at the outfit's poses and, with ``extra_poses``, at
   random poses of the train performers (the losses need no drape).

The variants of the ablation (``VARIANTS``) share the recipe.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import roma
import torch

from recon.body import default_body
from recon.body.base import BodyModel
from recon.body.lbs import blend_transforms
from recon.garment import losses, mesh, store
from recon.garment.data import pose_set, posed_bodies
from recon.garment.deepsd.data import DeePSDDataConfig, folder, generate, load_split
from recon.garment.deepsd.model import DeePSD, DeePSDConfig, OutfitGraph
from recon.garment.metrics import penetration
from recon.garment.pbns.model import BlendShapeGarment
from recon.garment.templates import RestBody


@dataclass
class PhysicsConfig:
    edge: float = 5.0e4  # per squared metre of mean edge-length error (5x losses.EdgeConfig: selected on val)
    bend: float = 0.02  # on the mean squared normal difference of adjacent faces (losses.BendConfig)
    collision: float = 25.0e3  # on the mean squared penetration (losses.CollisionConfig)
    eps: float = 0.005  # m (eq. 4.5)
    displacement: float = 100.0  # L2 on chi's displacements, per mean squared metre


@dataclass
class DeePSDTrainConfig:
    model: DeePSDConfig = field(default_factory=DeePSDConfig)
    data: DeePSDDataConfig = field(default_factory=DeePSDDataConfig)
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    steps: int = 3000  # supervised steps (one outfit each)
    physics_steps: int = 1500  # 0: no physics branch (the "no phys." row)
    extra_poses: bool = True  # the physics branch also at random train poses (the "+poses" row)
    lr: float = 1e-3
    vertices: int = 1500  # vertices per supervised step
    seed: int = 0
    name: str = "deepsd"  # the weights' file (store.deepsd_path)
    # start from a trained model's supervised part (Phi, Omega, Psi, Theta) and train chi alone
    init_from: str | None = None


VARIANTS = {
    "ours": {},
    "no-global": {"model": {"global_": 0}, "physics_steps": 0},
    "deformations": {"model": {"blend_shapes": False}, "physics_steps": 0},
    "physics-no-extra-poses": {"extra_poses": False, "init_from": "deepsd", "steps": 0},
}


def variant_config(name: str, base: DeePSDTrainConfig | None = None) -> DeePSDTrainConfig:
    base = base or DeePSDTrainConfig()
    v = VARIANTS[name]
    model = replace(base.model, **v.get("model", {}))
    rest = {k: x for k, x in v.items() if k != "model"}
    return replace(base, model=model, name="deepsd" if name == "ours" else f"deepsd_{name}", **rest)


class Sample:
    """One draped outfit prepared for training: its graph, poses, joint transforms, posed bodies
    (vertices, normals) and drapes."""

    def __init__(self, rec: dict, body: BodyModel, rb: RestBody):
        self.graph = OutfitGraph(rec["rest"].numpy(), rec["faces"].numpy(), rec["lbs_weights"].numpy(), rb.v, rb.n)
        self.rotmats = roma.rotvec_to_rotmat(rec["rotvec"])
        self.body_v, self.body_n, self.transforms = posed_bodies(body, self.rotmats, body.mean_shape[None])
        self.drapes = rec["drapes"]
        self.family, self.split = rec["family"], rec["split"]
        self.layer = rec["layer"].numpy() if "layer" in rec else None  # (N,) garment layer; None: one layer
        self._phys = None

    def physics_terms(self) -> tuple[losses.EdgeLoss, losses.BendLoss]:
        if self._phys is None:
            self._phys = (losses.EdgeLoss(self.graph.rest, self.graph.faces),
                          losses.BendLoss(self.graph.faces))
        return self._phys


def load_samples(body: BodyModel, split: str, data: DeePSDDataConfig) -> list[Sample]:
    rb = RestBody(body)
    return [Sample(r, body, rb) for r in load_split(folder(data), split)]


def collision_loss(v: torch.Tensor, body_v: torch.Tensor, body_n: torch.Tensor, eps: float) -> torch.Tensor:
    """Mean over vertices of min(d - eps, 0)^2, d along the nearest body vertex's normal (eq. 4.5)."""
    idx = mesh.nearest(body_v, v)
    return (penetration(v, body_v, body_n, idx, eps) ** 2).mean(1)


def physics_loss(model: DeePSD, s: Sample, cached: tuple, rotmats, transforms, body_v, body_n,
                 cfg: PhysicsConfig) -> tuple[torch.Tensor, dict]:
    """L_phys of chi at the given poses, the supervised part (``cached``: descriptors, weights,
    D_data) frozen."""
    desc, w, d_data = cached
    k = model.keys(rotmats).detach()
    d_phys = torch.einsum("bp,npk->bnk", k, model.chi(desc).view(len(desc), -1, 3))
    x = s.graph.rest + torch.einsum("bp,npk->bnk", k, d_data) + d_phys
    v = BlendShapeGarment.apply_blend(x, blend_transforms(w, transforms))
    edge, bend = s.physics_terms()
    terms = {"edge": cfg.edge * edge.strain(v).pow(2).mean(1).mean(), "bend": cfg.bend * bend.energy(v).mean(),
             "collision": cfg.collision * collision_loss(v, body_v, body_n, cfg.eps).mean(),
             "displacement": cfg.displacement * d_phys.pow(2).sum(-1).mean()}
    return sum(terms.values()), {k: float(x.detach()) for k, x in terms.items()}


def train(cfg: DeePSDTrainConfig, log=print, generate_data: bool = True) -> dict:
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    if generate_data:
        generate(cfg.data, log)
    body = default_body()
    samples = load_samples(body, "train", cfg.data)
    if not samples:
        raise RuntimeError(f"no DeePSD drapes in {folder(cfg.data)}: run the generation first")
    model = DeePSD(cfg.model)
    if cfg.init_from:  # its supervised part; chi as initialised (zero output)
        trained = DeePSD.load(store.deepsd_path(cfg.init_from))[0].state_dict()
        model.load_state_dict({k: v for k, v in trained.items() if not k.startswith("chi.")}, strict=False)
    t0 = time.time()
    sup = [p for n, p in model.named_parameters() if not n.startswith("chi.")]
    opt = torch.optim.Adam(sup, lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(1, cfg.steps), eta_min=cfg.lr * 0.05)
    history = []
    for step in range(cfg.steps):
        s = samples[rng.integers(len(samples))]
        n = len(s.graph.rest)
        subset = torch.from_numpy(rng.choice(n, min(n, cfg.vertices), replace=False))
        pred = model(s.graph, s.rotmats, s.transforms, physics=False, subset=subset)
        loss = (pred - s.drapes[:, subset]).pow(2).sum(-1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        history.append(float(loss.detach()))
        if (step + 1) % 250 == 0:
            log(f"supervised {step + 1}/{cfg.steps}: rms {np.sqrt(np.mean(history[-250:])) * 1000:.1f} mm "
                f"({time.time() - t0:.0f} s)")
    sup_seconds = time.time() - t0
    phys_log: list[dict] = []
    if cfg.physics_steps:
        phys_log = train_physics(model, samples, body, cfg, rng, log)
    meta = {"config": asdict(cfg), "train_outfits": len(samples),
            "train_drapes": int(sum(len(s.drapes) for s in samples)),
            "supervised_seconds": sup_seconds, "train_seconds": time.time() - t0,
            "final_rms_mm": float(np.sqrt(np.mean(history[-250:])) * 1000) if history else None,
            "physics": phys_log[-1:] or None}
    model.save(store.deepsd_path(cfg.name), {"meta_json": json.dumps(meta)})
    return meta


def train_physics(model: DeePSD, samples: list[Sample], body: BodyModel, cfg: DeePSDTrainConfig, rng,
                  log) -> list[dict]:
    """Stage 2: chi alone on L_phys."""
    for p in model.parameters():
        p.requires_grad_(False)
    for p in model.chi.parameters():
        p.requires_grad_(True)
    extra = None
    if cfg.extra_poses:
        r = pose_set("train", 256, cfg.data.min_pose_distance, cfg.seed + 7)
        extra = (r, *posed_bodies(body, r, body.mean_shape[None]))
    opt = torch.optim.Adam(model.chi.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.physics_steps, eta_min=cfg.lr * 0.05)
    cache: dict[int, tuple] = {}
    t0, out, window = time.time(), [], []
    for step in range(cfg.physics_steps):
        i = int(rng.integers(len(samples)))
        s = samples[i]
        if i not in cache:
            with torch.no_grad():
                desc = model.descriptors(s.graph)
                cache[i] = (desc, model.weights(s.graph.lbs_weights, desc), model.blend_shapes(desc, physics=False))
        if extra is not None and rng.random() < 0.5:
            k = torch.from_numpy(rng.choice(len(extra[0]), len(s.rotmats), replace=False))
            rot, bv, bn, tr = extra[0][k], extra[1][k], extra[2][k], extra[3][k]
        else:
            rot, bv, bn, tr = s.rotmats, s.body_v, s.body_n, s.transforms
        loss, terms = physics_loss(model, s, cache[i], rot, tr, bv, bn, cfg.physics)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        window.append(terms)
        if (step + 1) % 250 == 0:
            mean = {k: float(np.mean([w[k] for w in window])) for k in window[0]}
            out.append({"step": step + 1, **mean})
            window = []
            log(f"physics {step + 1}/{cfg.physics_steps}: " + " ".join(f"{k} {v:.4g}" for k, v in mean.items())
                + f" ({time.time() - t0:.0f} s)")
    return out
