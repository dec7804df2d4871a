"""Unsupervised PBNS training (``recon garment train``): no simulation data, only poses and the
potential energy of the outfit (edge + bending + collision + gravity + pinning).

Poses: retargeted mocap, train split, N = 3000 balanced poses (thesis 5.4.3: every pair differs
by >= 0.5 rad in some joint, global orientation ignored for the sampling), 85/15 train/val.
Body shape is fixed during training (as in a simulation); the outfit is built for that shape.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from recon import paths
from recon.garment import losses as L
from recon.garment.mesh import vertex_normals
from recon.garment.pbns import PBNS, PBNSConfig, initial_weights
from recon.garment.templates import PRESETS, RestBody, hangs_free, make_outfit, outfit_name

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"


def user_weights_dir() -> Path:
    """Where outfits trained from your own garment meshes go (the shipped ones: WEIGHTS_DIR)."""
    return paths.cache_dir() / "garments"


def weights_path(outfit: str) -> Path:
    """PBNS weights of a preset (shipped), of your own garment (by name or mesh path), or a .pt path."""
    if outfit.endswith(".pt"):
        return Path(outfit)
    name = outfit_name(outfit)
    return (WEIGHTS_DIR if name in PRESETS else user_weights_dir()) / f"pbns_{name}.pt"


@dataclass
class GarmentTrainConfig:
    outfit: str = "tshirt-trousers"
    poses: int = 3000
    min_pose_distance: float = 0.5  # radians (thesis 5.4.3)
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
    # 10x stiffer edges than the fourth round (3e4) meet the 0.7 mm strain target; 5x gravity and
    # 5x bending keep the sag and the smoothness they would lose (ablation, fifth round)
    edge: L.EdgeConfig = field(default_factory=lambda: L.EdgeConfig(weight=3e5))
    bend: L.BendConfig = field(default_factory=lambda: L.BendConfig(weight=1.0))
    collision: L.CollisionConfig = field(default_factory=lambda: L.CollisionConfig(weight=1e5))
    gravity: L.GravityConfig = field(default_factory=lambda: L.GravityConfig(weight=5.0))
    pin: L.PinConfig = field(default_factory=L.PinConfig)


def edge_scale(warmup: float, step: int, steps: int) -> float:
    """Stiffness continuation: ``warmup`` at step 0, geometric rise to 1 at mid-training."""
    return warmup ** max(0.0, 1.0 - 2.0 * step / steps)


def balanced_poses(rotvec: np.ndarray, n: int, min_distance: float, seed: int) -> np.ndarray:
    """Greedy subset in random order: keep a pose if it differs from every kept one by at least
    ``min_distance`` rad in some non-root parameter."""
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
    import roma

    from recon.poses.mocap import MocapPoses

    m = MocapPoses.load(split)
    idx = balanced_poses(m.rotvec, n, min_distance, seed)
    return roma.rotvec_to_rotmat(torch.from_numpy(m.rotvec[idx]).float())


class Criterion(torch.nn.Module):
    """Sum of the PBNS energies; ``terms`` keeps each one for logging."""

    def __init__(self, outfit, rest: torch.Tensor, cfg: GarmentTrainConfig):
        super().__init__()
        self.edge = L.EdgeLoss(rest, outfit.faces, cfg.edge)
        self.bend = L.BendLoss(outfit.faces, cfg.bend)
        self.collision = L.CollisionLoss(outfit.layer, cfg.collision)
        self.gravity = L.GravityLoss(cfg.gravity)
        self.pin = L.PinLoss(outfit.pinned, cfg.pin)
        self.register_buffer("faces", torch.from_numpy(np.ascontiguousarray(outfit.faces)).long())

    def forward(self, v, dt, body_v, body_n, body_cand=None, cloth_cand=None, rest_len=None, body_inside=None):
        self.terms = {"edge": self.edge(v, rest_len), "bend": self.bend(v),
                      "collision": self.collision(v, body_v, body_n, self.faces, body_cand, cloth_cand, body_inside),
                      "gravity": self.gravity(v), "pin": self.pin(dt)}
        return sum(self.terms.values())


def build(body, cfg: GarmentTrainConfig, shape: torch.Tensor | None = None):
    """Outfit template + untrained PBNS for a body shape (default: the body's mean shape)."""
    shape = body.mean_shape[None] if shape is None else shape.reshape(1, -1)
    outfit = make_outfit(body, cfg.outfit, shape)
    rb = RestBody(body, shape)
    skirted = any(hangs_free(rb, g) for g in outfit.garments)
    # skirts hang between the legs: their weights need more smoothing (thesis 5.3.2)
    mcfg = PBNSConfig(**{**asdict(cfg.model), "optimise_weights": skirted or cfg.model.optimise_weights,
                         "weight_diffusion": max(cfg.model.weight_diffusion, 20) if skirted else cfg.model.weight_diffusion})
    w = initial_weights(rb, outfit, mcfg.weight_diffusion)
    model = PBNS(torch.from_numpy(outfit.vertices), torch.from_numpy(outfit.faces), torch.from_numpy(w), mcfg)
    return outfit, model, shape


def posed_bodies(body, rotmats: torch.Tensor, shape: torch.Tensor, chunk: int = 64):
    """Body vertices, vertex normals and joint transforms for all poses (no gradient)."""
    vs, ns, ts = [], [], []
    with torch.no_grad():
        for i in range(0, len(rotmats), chunk):
            r = rotmats[i:i + chunk]
            o = body(r, shape.expand(len(r), -1))
            vs.append(o.vertices)
            ns.append(vertex_normals(o.vertices, body.faces))
            ts.append(o.transforms)
    return torch.cat(vs), torch.cat(ns), torch.cat(ts)


@torch.no_grad()
def candidates(model: PBNS, crit: Criterion, rot, bt, bv, k: int, chunk: int = 64):
    """Per pose, the k nearest body vertices (and inner-layer vertices) of every vertex of the
    skinned template (dT = 0): the prediction moves a few cm at most, so its nearest neighbour is
    almost always among them. int16/int32 to keep 3,000 poses in memory."""
    from recon.garment.losses import nearest

    body_c, cloth_c = [], [[] for _ in crit.collision.pairs()]
    for i in range(0, len(rot), chunk):
        v = model.skin(model.rest, bt[i:i + chunk])
        body_c.append(nearest(bv[i:i + chunk], v, k).to(torch.int16 if bv.shape[1] < 32767 else torch.int32))
        for j, (inner, outer) in enumerate(crit.collision.pairs()):
            cloth_c[j].append(nearest(v[:, inner], v[:, outer], k).to(torch.int32))
    return torch.cat(body_c), [torch.cat(c) for c in cloth_c]


def train(body, cfg: GarmentTrainConfig = GarmentTrainConfig(), out: Path | None = None, log=print) -> dict:
    from tqdm import tqdm

    torch.manual_seed(cfg.seed)
    out = Path(out or weights_path(cfg.outfit))
    t0 = time.time()
    outfit, model, shape = build(body, cfg)
    poses = pose_set("train", cfg.poses, cfg.min_pose_distance, cfg.seed)
    bv, bn, bt = posed_bodies(body, poses, shape)
    if cfg.valid_max_self is not None:
        from recon.garment.self_intersection import SkinSelfIntersection

        keep = SkinSelfIntersection(body, shape).percent(bv) <= cfg.valid_max_self
        poses, bv, bn, bt = poses[keep], bv[keep], bn[keep], bt[keep]
        if len(poses) < 2 * cfg.batch:
            raise ValueError(f"only {len(poses)} training poses have <= {cfg.valid_max_self} % body self-intersection")
    n_val = int(round(cfg.val_fraction * len(poses)))
    perm = torch.randperm(len(poses), generator=torch.Generator().manual_seed(cfg.seed))
    val_idx, tr_idx = perm[:n_val], perm[n_val:]
    crit = Criterion(outfit, model.rest, cfg)
    body_c, cloth_c = candidates(model, crit, poses, bt, bv, cfg.candidates)
    inside = None
    if cfg.collision.skip_self_intersection:
        from recon.garment.self_intersection import SkinSelfIntersection

        inside = SkinSelfIntersection(body, shape)(bv)
    # Adam moves every entry of D by ~lr per step, and dT = X . D sums 32 of them: D gets a
    # smaller rate than the MLP or the cloth jumps by centimetres per step (measured: diverges).
    opt = torch.optim.Adam([{"params": [model.D], "lr": cfg.lr_psd},
                            {"params": [p for n, p in model.named_parameters() if n != "D"], "lr": cfg.lr}])
    per_epoch = len(tr_idx) // cfg.batch
    steps = cfg.epochs * per_epoch
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    curve, t_setup = [], time.time() - t0
    log(f"outfit {cfg.outfit}: {len(outfit.vertices)} vertices, {len(outfit.faces)} faces; "
        f"{len(tr_idx)} train / {len(val_idx)} val poses; set-up {t_setup:.1f} s")
    bar = tqdm(total=steps, desc=f"pbns {cfg.outfit}", unit="step")
    for ep in range(cfg.epochs):
        model.train()
        order = tr_idx[torch.randperm(len(tr_idx))]
        sums: dict[str, float] = {}
        for b in range(per_epoch):
            i = order[b * cfg.batch:(b + 1) * cfg.batch]
            crit.edge.scale = edge_scale(cfg.edge_warmup, ep * per_epoch + b, steps)
            v, dt = model(poses[i], bt[i])
            loss = crit(v, dt, bv[i], bn[i], body_c[i], [c[i] for c in cloth_c],
                        body_inside=None if inside is None else inside[i]).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            for k, t in crit.terms.items():
                sums[k] = sums.get(k, 0.0) + float(t.detach().mean())
            bar.update(1)
        row = {"epoch": ep + 1, "seconds": round(time.time() - t0, 1)} | {k: s / per_epoch for k, s in sums.items()}
        row |= {f"val_{k}": v for k, v in validate(model, crit, poses[val_idx], bt[val_idx], bv[val_idx], bn[val_idx]).items()}
        curve.append(row)
        bar.set_postfix(coll=f"{row['val_collision_pct']:.2f}%", edge=f"{row['val_edge_mm']:.2f}mm")
    bar.close()
    # "model": the PBNS config in effect (skirted outfits override weight diffusion/optimisation)
    meta = {"outfit": outfit_name(cfg.outfit), "source": cfg.outfit, "config": asdict(cfg), "model": asdict(model.cfg), "vertices": int(len(outfit.vertices)),
            "faces": int(len(outfit.faces)), "train_seconds": round(time.time() - t0, 1),
            "shape": shape[0].tolist(), "garments": [g.name for g in outfit.garments], "curve": curve}
    model.save(out, {"meta_json": json.dumps(meta), "layer": torch.from_numpy(outfit.layer),
                     "garment_id": torch.from_numpy(outfit.garment_id), "shape": shape[0]})
    paths.atomic_write(out.with_suffix(".json"), lambda t: Path(t).write_text(json.dumps(meta, indent=1)))
    return meta


@torch.no_grad()
def validate(model, crit, rot, bt, bv, bn, chunk: int = 64) -> dict:
    model.eval()
    agg: dict[str, list] = {"collision_pct": [], "edge_mm": [], "loss": []}
    for i in range(0, len(rot), chunk):
        v, dt = model(rot[i:i + chunk], bt[i:i + chunk])
        agg["loss"].append(crit(v, dt, bv[i:i + chunk], bn[i:i + chunk]))
        agg["edge_mm"].append(crit.edge.strain(v).abs().mean(1) * 1000)
        pen = L.CollisionLoss.penetration(v, bv[i:i + chunk], bn[i:i + chunk], L.nearest(bv[i:i + chunk], v), 0.0)
        agg["collision_pct"].append((pen < 0).float().mean(1) * 100)
    return {k: float(torch.cat(x).mean()) for k, x in agg.items()}
