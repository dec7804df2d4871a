"""Unsupervised training of PBNS outfits (``recon garment train``) and of their resizers
(``recon garment resize``): no simulation data, only poses (or body shapes) and the potential
energy of the outfit (edge + bending + collision + gravity + pinning, recon.garment.losses).

PBNS poses: retargeted mocap, train split, N = 3000 balanced poses (thesis 5.4.3: every pair
differs by >= 0.5 rad in some joint, global orientation ignored for the sampling), 85/15
train/val. Body shape is fixed during training (as in a simulation); the outfit is built for
that shape. Resizer conditions: sampled body shapes and tightness values (thesis 5.5.6). Both
loops are ``recon.training.Trainer``: an interrupted run resumes from ``.<weights>.run/`` beside
the weights file, removed when the weights are written.
"""
from __future__ import annotations

import json
import shutil
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import torch

from recon import paths
from recon.body.base import BodyModel
from recon.errors import ReconError
from recon.garment import losses, store
from recon.garment.data import MIN_POSE_DISTANCE, pose_set, posed_bodies
from recon.garment.metrics import collision_pct, rest_metrics
from recon.garment.pbns.data import Conditions, sample_conditions
from recon.garment.pbns.model import PBNS, PBNSConfig, initial_weights, trained_outfit
from recon.garment.resize import TIGHTNESS_PHENOTYPES, TIGHTNESS_RANGE, ResizeConfig, Resizer, Transfer
from recon.garment.self_intersection import SkinSelfIntersection
from recon.garment.templates import RestBody, hangs_free, make_outfit, outfit_name
from recon.training import Trainer, epoch_batches, run_dir_for


@dataclass
class GarmentTrainConfig:
    outfit: str = "tshirt-trousers"
    poses: int = 3000
    min_pose_distance: float = MIN_POSE_DISTANCE
    val_fraction: float = 0.15
    epochs: int = 6
    batch: int = 16
    lr: float = 1e-3
    lr_psd: float = 3e-4  # learning rate of the PSD matrix D
    seed: int = 0
    candidates: int = 8  # nearest-neighbour candidates per vertex and pose (collision search)
    # keep only "valid" training poses (thesis 5.4.3): at most this % of the covered skin inside the
    # posed body (recon.garment.self_intersection); None keeps all (ablation: valid-only)
    valid_max_self: float | None = None
    # stiffness continuation: the edge weight starts at this fraction and rises geometrically to
    # its full value by mid-training (1.0: constant). Soft edges first let the cloth sag under
    # gravity; the stiff edges then remove the strain of the sag (ablation, fifth round)
    edge_warmup: float = 0.1
    model: PBNSConfig = field(default_factory=PBNSConfig)
    edge: losses.EdgeConfig = field(default_factory=lambda: replace(losses.FABRIC.edge))
    bend: losses.BendConfig = field(default_factory=lambda: replace(losses.FABRIC.bend))
    collision: losses.CollisionConfig = field(default_factory=lambda: replace(losses.FABRIC.collision))
    gravity: losses.GravityConfig = field(default_factory=lambda: replace(losses.FABRIC.gravity))
    pin: losses.PinConfig = field(default_factory=lambda: replace(losses.FABRIC.pin))


# stored in float16: it moves no published number (eval/results/weights-float16.md); PBNS keeps
# float32 but for D (PBNS.save), since rounding its blend weights moves collision percentages
RESIZER_DTYPE = torch.float16


def edge_scale(warmup: float, step: int, steps: int) -> float:
    """Stiffness continuation: ``warmup`` at step 0, geometric rise to 1 at mid-training."""
    return warmup ** max(0.0, 1.0 - 2.0 * step / steps)


def _adam(net: torch.nn.Module, lr: float, lr_psd: float) -> torch.optim.Adam:
    """Adam with the PSD matrix D (PBNS or resizer) at its own rate: Adam moves every entry of D by
    ~lr per step, and dT = X . D sums 32 of them, so D gets a smaller rate than the MLP or the
    cloth jumps by centimetres per step (measured: diverges)."""
    return torch.optim.Adam([{"params": [net.D], "lr": lr_psd},
                             {"params": [p for n, p in net.named_parameters() if n != "D"], "lr": lr}])


def build(body: BodyModel, cfg: GarmentTrainConfig, shape: torch.Tensor | None = None):
    """Outfit template + untrained PBNS for a body shape (default: the body's mean shape)."""
    shape = body.mean_shape[None] if shape is None else shape.reshape(1, -1)
    outfit = make_outfit(body, cfg.outfit, shape)
    rb = RestBody(body, shape)
    skirted = any(hangs_free(rb, g) for g in outfit.garments)
    # skirts hang between the legs: their weights need more smoothing (thesis 5.3.2)
    mcfg = PBNSConfig(**{**asdict(cfg.model), "optimise_weights": skirted or cfg.model.optimise_weights,
                         "weight_diffusion": max(cfg.model.weight_diffusion, 20) if skirted
                         else cfg.model.weight_diffusion})
    w = initial_weights(rb, outfit, mcfg.weight_diffusion)
    model = PBNS(torch.from_numpy(outfit.vertices), torch.from_numpy(outfit.faces), torch.from_numpy(w), mcfg)
    return outfit, model, shape


@torch.no_grad()
def validate(model, crit, rot, bt, bv, bn, chunk: int = 64) -> dict:
    """Held-out poses: the energy, collision % and edge error (mm), as the evaluation counts them."""
    model.eval()
    agg: dict[str, list] = {"collision_pct": [], "edge_mm": [], "loss": []}
    for i in range(0, len(rot), chunk):
        v, dt = model(rot[i:i + chunk], bt[i:i + chunk])
        agg["loss"].append(crit(v, dt, bv[i:i + chunk], bn[i:i + chunk]))
        agg["edge_mm"].append(crit.edge.strain(v).abs().mean(1) * 1000)
        agg["collision_pct"].append(collision_pct(v, bv[i:i + chunk], bn[i:i + chunk]))
    return {k: float(torch.cat(x).mean()) for k, x in agg.items()}


def train(body: BodyModel, cfg: GarmentTrainConfig | None = None, out: Path | None = None, log=print,
          progress: bool = True) -> dict:
    """Train the PBNS of ``cfg.outfit``; writes ``out`` (default ``store.pbns_path``) with the
    training record inside and returns that record."""
    cfg = cfg or GarmentTrainConfig()
    torch.manual_seed(cfg.seed)
    out = Path(out or store.pbns_path(cfg.outfit))
    t0 = time.time()
    outfit, model, shape = build(body, cfg)
    poses = pose_set("train", cfg.poses, cfg.min_pose_distance, cfg.seed)
    bv, bn, bt = posed_bodies(body, poses, shape)
    if cfg.valid_max_self is not None:
        keep = SkinSelfIntersection(body, shape).percent(bv) <= cfg.valid_max_self
        poses, bv, bn, bt = poses[keep], bv[keep], bn[keep], bt[keep]
        if len(poses) < 2 * cfg.batch:
            raise ReconError(f"only {len(poses)} training poses have <= {cfg.valid_max_self} % body self-intersection")
    n_val = int(round(cfg.val_fraction * len(poses)))
    perm = torch.randperm(len(poses), generator=torch.Generator().manual_seed(cfg.seed))
    val_idx, tr_idx = perm[:n_val], perm[n_val:]
    crit = losses.Criterion(outfit, model.rest, cfg)
    body_c, cloth_c = losses.candidates(model, crit, poses, bt, bv, cfg.candidates)
    inside = SkinSelfIntersection(body, shape)(bv) if cfg.collision.skip_self_intersection else None
    opt = _adam(model, cfg.lr, cfg.lr_psd)
    per_epoch = len(tr_idx) // cfg.batch
    steps = cfg.epochs * per_epoch
    name = outfit_name(cfg.outfit)
    log(f"outfit {cfg.outfit}: {len(outfit.vertices)} vertices, {len(outfit.faces)} faces; "
        f"{len(tr_idx)} train / {len(val_idx)} val poses; set-up {time.time() - t0:.1f} s")
    trainer = Trainer({"pbns": model}, opt, steps, eval_every=per_epoch, out_dir=run_dir_for(out),
                      config=asdict(cfg), desc=f"pbns {name}", steps_per_epoch=per_epoch, progress=progress)

    def step(batch):
        model.train()
        crit.edge.scale = edge_scale(cfg.edge_warmup, trainer.step, steps)
        i = tr_idx[batch]
        v, dt = model(poses[i], bt[i])
        loss = crit(v, dt, bv[i], bn[i], body_c[i], [c[i] for c in cloth_c],
                    body_inside=None if inside is None else inside[i]).mean()
        return loss, crit.terms

    def held_out() -> dict:
        return {f"val_{k}": v for k, v in validate(model, crit, poses[val_idx], bt[val_idx], bv[val_idx],
                                                    bn[val_idx]).items()}

    log_ = trainer.fit(epoch_batches(len(tr_idx), cfg.batch, trainer.step), step, held_out)
    # "model": the PBNS config in effect (skirted outfits override weight diffusion/optimisation)
    meta = {"outfit": name, "source": cfg.outfit, "config": asdict(cfg), "model": asdict(model.cfg),
            "vertices": int(len(outfit.vertices)), "faces": int(len(outfit.faces)),
            "train_seconds": round(time.time() - t0, 1), "threads": torch.get_num_threads(),
            "shape": shape[0].tolist(), "garments": [g.name for g in outfit.garments], "curve": log_["history"]}
    model.save(out, {"meta_json": json.dumps(meta), "layer": torch.from_numpy(outfit.layer),
                     "garment_id": torch.from_numpy(outfit.garment_id), "shape": shape[0]})
    shutil.rmtree(run_dir_for(out), ignore_errors=True)
    return meta


def train_resizer(body: BodyModel, pbns_path: Path, out: Path | None = None, cfg: ResizeConfig | None = None, log=print,
                  progress: bool = True) -> dict:
    """Train the resizer of a trained PBNS outfit; writes ``out`` (default beside the PBNS
    weights, ``store.resizer_path``) with the training record inside and returns that record."""
    cfg = cfg or ResizeConfig()
    torch.manual_seed(cfg.seed)
    t0 = time.time()
    outfit, shape0, name = trained_outfit(body, Path(pbns_path))
    out = Path(out or store.resizer_path(name, pbns_path))
    transfer = Transfer(body, outfit.vertices, outfit.faces, shape0, cfg.smooth)
    crit = losses.Criterion(outfit, torch.from_numpy(outfit.vertices), cfg)
    tr = Conditions(body, transfer, *sample_conditions(body, cfg.samples, cfg.seed), crit.edge.edges, cfg.candidates)
    va = Conditions(body, transfer, *sample_conditions(body, cfg.val_samples, cfg.seed + 1), crit.edge.edges, 1)
    net = Resizer(len(outfit.vertices), body.num_shape_params + 2, cfg)
    opt = _adam(net, cfg.lr, cfg.lr_psd)
    per_epoch = cfg.samples // cfg.batch
    log(f"resizer {name}: {len(outfit.vertices)} vertices, {cfg.samples} train / {cfg.val_samples} val conditions; "
        f"set-up {time.time() - t0:.1f} s")
    base_val = rest_metrics(va.base, va.base, outfit.faces, va.bv, va.bn)
    trainer = Trainer({"resizer": net}, opt, cfg.epochs * per_epoch, eval_every=per_epoch, out_dir=run_dir_for(out),
                      config=asdict(cfg), desc=f"resize {name}", steps_per_epoch=per_epoch, progress=progress)

    def step(i):
        dv = net(tr.shape[i], tr.tight[i])
        loss = crit(tr.base[i] + dv, dv, tr.bv[i], tr.bn[i], tr.cand[i], rest_len=tr.rest_len[i]).mean()
        return loss, crit.terms

    @torch.no_grad()
    def held_out() -> dict:
        v = va.base + net(va.shape, va.tight)
        return {f"val_{k}": x for k, x in rest_metrics(v, va.base, outfit.faces, va.bv, va.bn).items()}

    log_ = trainer.fit(epoch_batches(cfg.samples, cfg.batch, trainer.step), step, held_out)
    meta = {"outfit": name, "pbns": Path(pbns_path).name, "config": asdict(cfg),
            "train_seconds": round(time.time() - t0, 1), "threads": torch.get_num_threads(),
            "tightness_phenotypes": TIGHTNESS_PHENOTYPES, "tightness_range": TIGHTNESS_RANGE,
            "val_transfer_only": base_val, "curve": log_["history"]}
    state = {"state": paths.cast_floats(net.state_dict(), RESIZER_DTYPE), "shape0": shape0,
             "num_inputs": body.num_shape_params + 2,
             "num_vertices": len(outfit.vertices), "meta_json": json.dumps(meta)}
    paths.atomic_write(out, lambda t: torch.save(state, t))
    shutil.rmtree(run_dir_for(out), ignore_errors=True)
    return meta
