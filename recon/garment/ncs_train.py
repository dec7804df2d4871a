"""Unsupervised training of NCS outfits (``recon garment ncs``, thesis 6.3.4): the PBNS energies
(recon.garment.losses, the same fabric as the outfit's PBNS) plus the inertia term of eq. 6.9,
on windows of body motion cut from the retargeted mocap at 30 fps.

A sample is a window of ``window`` seconds ending at a frame t of a train clip. The network runs
over the window from a zero recurrent state and predicts the last three frames; the inertia term
compares x_t with 2 x_{t-1} - x_{t-2}, both detached (no gradient back in time), and the static
energies apply to x_t only (the thesis: applying them to all three biases the sampling).
Motion augmentation (6.4.6): in a fifth of each batch the dynamic code is swapped with another
sample's and only the static energies apply, with no gradient to the encoders.

Warm start: the outfit's trained PBNS gives the template, the blend weights and D, and the static
encoder is first distilled from PBNS's codes on the train frames, so training starts from PBNS's
quasi-static solution and spends its budget on the dynamics. Validation: windows of the val
split's clips (other performers). An interrupted run resumes from ``.<weights>.run/``.
"""
from __future__ import annotations

import json
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import roma
import torch

from recon.garment import losses as L
from recon.garment import store
from recon.garment.data import posed_bodies, trained_outfit
from recon.garment.metrics import collision_pct
from recon.garment.ncs import (
    FPS,
    NCS,
    InertiaConfig,
    InertiaLoss,
    NCSConfig,
    descriptors,
    hanging_part,
    smooth_time,
    vertex_masses,
)
from recon.garment.pbns import PBNS, pose_features
from recon.garment.templates import Outfit
from recon.garment.train import GarmentTrainConfig, candidates, edge_scale, run_dir_for
from recon.poses.mocap import MocapPoses
from recon.training import Trainer, epoch_batches

_FABRIC = GarmentTrainConfig()  # NCS trains on the fabric its PBNS was trained with
DYNAMIC_BRANCH = ("per_joint", "dynamic", "gru")  # NCS's modules that read the motion


@dataclass
class NCSTrainConfig:
    outfit: str = "tshirt-skirt"
    window: float = 1.0  # seconds of motion per sample (thesis: 0.5 s tight to 2 s loose garments)
    samples: int = 4800  # windows of the train split
    val_samples: int = 240  # windows of the val split
    epochs: int = 8
    batch: int = 16
    lr: float = 1e-3  # the static encoder and the blend weights
    lr_dynamic: float = 3e-3  # the dynamic encoder and the GRU (they start from scratch)
    lr_psd: float = 3e-4  # D, PBNS's rate
    # stiffness continuation (as PBNS's): edges start at this fraction of their weight, rising to
    # full by mid-training; soft edges let the slow swinging modes of the cloth develop
    edge_warmup: float = 1.0
    seed: int = 0
    candidates: int = 8
    motion_augmentation: float = 0.2  # fraction of each batch (thesis 6.4.6: 20 %)
    distil_steps: int = 1500  # static encoder <- PBNS codes, before training
    dynamic_init: float = 1.0  # scale of the dynamic encoder's last layer at the start (< 1: nearer PBNS)
    # the static encoder (distilled from PBNS), PBNS's rows of D and the blend weights stay as they
    # start: NCS at motion control 0 is PBNS; the dynamic branch (and D's dynamic-only rows) train
    freeze_static: bool = False
    # with ``freeze_static``: D's dynamic-only rows train too (False: they stay as initialised; the
    # swing modes along x and z stay horizontal, where training turns a third of them vertical)
    train_dynamic_rows: bool = True
    # when only the hanging part should move (the static part frozen, the dynamic code on the swing
    # rows only, no dynamic_modes), train on the hanging garments alone (2.7x faster steps on
    # tshirt-skirt): the energies of the rest are constants, except that trained swing rows would
    # grow columns on the rest (a skirt's swing moving the t-shirt) to relax its static residual
    # forces; here they stay zero there, as the modes start. Cloth-cloth collisions between the
    # two are left out
    hanging_only: bool = True
    # the dynamic part u = x - x_static is trained on E(x_s + u) - E(x_s) - F_s . u (+ inertia),
    # F_s = dE/dx at the static prediction x_s: the static model's residual force (on PBNS's cloth
    # ~100x the inertial force, eval/results/ncs-forces-tshirt-skirt.md) is left to the static
    # branch, the dynamic one sees the stiffness about x_s and the inertia
    remove_static_force: bool = False
    # Gaussian sigma (frames) of the training motions: the cloth follows the body, so mocap's
    # frame-to-frame jitter enters the inertia term as an unlearnable signal
    smooth_motion: float = 1.5
    # frames a second of the training motions (the pose set's 30, or 15 = every second frame): at
    # 15 the lag builds over half as many steps of the network's own predictions (thesis 6.4.4:
    # dynamics appear sooner); the model then runs at this rate (Dresser resamples)
    fps: float = FPS
    # "cuda" for a GPU (the thesis trains for hours there); the windows stay in CPU memory and
    # each batch is moved, the nearest-neighbour search of validation runs on the CPU
    device: str = "cpu"
    model: NCSConfig = field(default_factory=NCSConfig)
    edge: L.EdgeConfig = field(default_factory=lambda: _FABRIC.edge)
    bend: L.BendConfig = field(default_factory=lambda: _FABRIC.bend)
    collision: L.CollisionConfig = field(default_factory=lambda: _FABRIC.collision)
    gravity: L.GravityConfig = field(default_factory=lambda: _FABRIC.gravity)
    pin: L.PinConfig = field(default_factory=lambda: _FABRIC.pin)
    inertia: InertiaConfig = field(default_factory=lambda: InertiaConfig(weight=_FABRIC.gravity.weight / 9.81))


class MotionWindows:
    """Windows of ``frames`` frames of a mocap split, ending at ``n`` random frames: per frame the
    NCS descriptors; per window the body transforms of its last three frames and the posed body
    (vertices, normals) at its last frame, all moved horizontally so that the mocap's root
    translation is above the origin at that frame (inertia only sees differences; float32 keeps
    its precision). ``smooth``: Gaussian sigma (frames) applied to the clips' motion."""

    def __init__(self, body, split: str, shape: torch.Tensor, frames: int, n: int, seed: int, chunk: int = 256,
                 smooth: float = 0.0, fps: float = FPS):
        m = MocapPoses.load(split)
        step = max(1, int(round(FPS / fps)))  # the pose set is at 30 fps
        rots, trs, static, dynamic, trans = [], [], [], [], []
        ends = []
        start = 0
        for c in np.unique(m.clip):  # clips are contiguous runs of frames
            idx = np.nonzero(m.clip == c)[0]
            rot = roma.rotvec_to_rotmat(torch.from_numpy(m.rotvec[idx]).float())
            transl = torch.from_numpy(m.transl[idx]).float()
            if smooth > 0:
                rot = roma.special_procrustes(smooth_time(rot[None], smooth)[0])
                transl = smooth_time(transl[None], smooth)[0]
            rot, transl = rot[::step], transl[::step]
            f = len(rot)
            with torch.no_grad():
                outs = [body(rot[i:i + chunk], shape.expand(len(rot[i:i + chunk]), -1), transl=transl[i:i + chunk],
                             points_only=True) for i in range(0, f, chunk)]
                glob = torch.cat([o.global_rotmats for o in outs])
                joints = torch.cat([o.joints for o in outs])
                s, d = descriptors(rot[None], glob[None], joints[None], FPS / step)
            rots.append(rot)
            trs.append(transl)
            static.append(s[0])
            dynamic.append(d[0])
            trans.append(torch.cat([o.transforms for o in outs]))
            ends.extend(range(start + frames - 1, start + f))
            start += f
        rot, transl = torch.cat(rots), torch.cat(trs)
        self.static, self.dynamic = torch.cat(static), torch.cat(dynamic)
        self.rot, self.transl = rot, transl
        transforms = torch.cat(trans)
        rng = np.random.default_rng(seed)
        self.ends = torch.from_numpy(np.sort(rng.choice(np.array(ends), min(n, len(ends)), replace=False)))
        self.offsets = torch.arange(-frames + 1, 1)
        e = self.ends
        off = transl[e] * torch.tensor([1.0, 0.0, 1.0])
        t3 = transforms[e[:, None] + torch.arange(-2, 1)].clone()  # (n, 3, 24, 3, 4)
        t3[..., 3] -= off[:, None, None]
        self.transforms = t3
        self.body_v, self.body_n, _ = posed_bodies(body, rot[e], shape, transl=transl[e] - off)

    def __len__(self) -> int:
        return len(self.ends)

    def window(self, i: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Descriptors (B, frames, K, 9) and (B, frames, K, 12) of windows ``i``."""
        f = self.ends[i][:, None] + self.offsets
        return self.static[f], self.dynamic[f]


def distil_static(model: NCS, pbns: PBNS, data: MotionWindows, steps: int, seed: int, batch: int = 512) -> float:
    """Fit the static encoder to PBNS's codes on every frame of ``data``: NCS starts as PBNS for
    motionless input. Returns the mean rest-pose displacement error (mm) left on 512 frames."""
    g = torch.Generator().manual_seed(seed)
    device = model.D.device
    x = data.static.flatten(1).to(device)
    with torch.no_grad():
        target = torch.cat([pbns.mlp(pose_features(data.rot[i:i + 4096])) for i in range(0, len(x), 4096)])
    target = target.to(device)
    opt = torch.optim.Adam(model.static.parameters(), lr=1e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    for _ in range(steps):
        j = torch.randint(len(x), (batch,), generator=g).to(device)
        loss = ((model.static(x[j]) - target[j]) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    with torch.no_grad():
        j = torch.randperm(len(x), generator=g)[:512].to(device)
        miss = model.static(x[j]) - target[j]
        err = (miss @ model.D[:miss.shape[-1]]).view(len(j), -1, 3).norm(dim=-1).mean()  # PBNS's rows
    return float(err) * 1000


def hanging_part_to_train(model: NCS, outfit, cfg: NCSTrainConfig) -> np.ndarray | None:
    """The vertices training can move, when that is the hanging part alone (``cfg.hanging_only``:
    the static part frozen, the dynamic code on the swing rows only) and less than the outfit;
    else None."""
    m = model.cfg
    if not (cfg.hanging_only and cfg.freeze_static and m.swing_modes and not m.dynamic_in_static_rows
            and not m.dynamic_modes):
        return None
    hanging, _ = hanging_part(outfit)
    return np.nonzero(hanging)[0] if not hanging.all() else None


def part_outfit(outfit: Outfit, vertices: np.ndarray) -> Outfit:
    """The outfit's garments whose vertices are ``vertices`` (whole garments, in order)."""
    ids = np.unique(outfit.garment_id[vertices])
    part = Outfit([outfit.garments[i] for i in ids])
    if len(part.vertices) != len(vertices):
        raise ValueError("a part of an outfit is made of whole garments")
    return part


def param_groups(model: NCS, cfg: NCSTrainConfig) -> list[dict]:
    """The optimiser's groups: the dynamic branch, D, the rest (static encoder, blend weights),
    each at its rate; with ``cfg.freeze_static`` the dynamic branch alone and the dynamic-only rows
    of D (``NCSConfig.dynamic_modes``, ``swing_modes``; not with ``cfg.train_dynamic_rows`` False),
    the rest frozen."""
    branch = {n: n.split(".")[0] in DYNAMIC_BRANCH for n, _ in model.named_parameters()}
    dynamic = [p for n, p in model.named_parameters() if branch[n]]
    rest = [p for n, p in model.named_parameters() if n != "D" and not branch[n]]
    if cfg.freeze_static:
        for p in rest:
            p.requires_grad_(False)
        e = model.cfg.embedding
        if len(model.D) == e or not cfg.train_dynamic_rows:
            model.D.requires_grad_(False)
            return [{"params": dynamic, "lr": cfg.lr_dynamic}]
        model.D.register_hook(lambda g: torch.cat([torch.zeros_like(g[:e]), g[e:]]))  # PBNS's rows stay
        return [{"params": dynamic, "lr": cfg.lr_dynamic}, {"params": [model.D], "lr": cfg.lr_psd}]
    return [{"params": dynamic, "lr": cfg.lr_dynamic}, {"params": [model.D], "lr": cfg.lr_psd},
            {"params": rest, "lr": cfg.lr}]


class Step:
    """One training step's loss on windows ``i``: static energies on x_t, inertia on x_t against
    the detached x_{t-1}, x_{t-2}; the last ``augmented`` windows of the batch get another
    window's dynamic code, static energies only and no gradient to the encoders."""

    def __init__(self, model: NCS, crit: L.Criterion, inertia: InertiaLoss, data: MotionWindows,
                 body_c=None, cloth_c=None, augmentation: float = 0.0, remove_static_force: bool = False):
        self.model, self.crit, self.inertia, self.data = model, crit, inertia, data
        self.body_c, self.cloth_c, self.augmentation = body_c, cloth_c, augmentation
        self.remove_static_force = remove_static_force

    @property
    def device(self) -> torch.device:
        return self.model.D.device

    def body(self, i: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The posed body's vertices and normals at the last frame of windows ``i``."""
        return self.data.body_v[i].to(self.device), self.data.body_n[i].to(self.device)

    def predict(self, i: torch.Tensor, augmented: int = 0, motion: float = 1.0):
        """Posed last three frames (B, 3, N, 3) and their dT."""
        s, d = (x.to(self.device) for x in self.data.window(i))
        zs, zd, _ = self.model.codes(s, d)
        zs, zd = zs[:, -3:], zd[:, -3:]
        if augmented:
            k = len(i) - augmented
            swap = torch.randperm(len(i))[:augmented].to(self.device)
            zs = torch.cat([zs[:k], zs[k:].detach()])
            zd = torch.cat([zd[:k], zd[swap].detach()])
        dt = self.model.decode(zs + motion * zd)
        return self.model.skin_frames(self.model.rest + dt, self.data.transforms[i].to(self.device)), dt

    def __call__(self, i: torch.Tensor):
        b = len(i)
        augmented = int(round(self.augmentation * b))
        x, dt = self.predict(i, augmented)
        bc = None if self.body_c is None else self.body_c[i].to(self.device)
        cc = None if self.cloth_c is None else [c[i].to(self.device) for c in self.cloth_c]
        body = self.body(i)
        if self.remove_static_force:
            static = self._about_static(i, augmented, x[:, 2], dt[:, 2], body, bc, cc)
        else:
            static = self.crit(x[:, 2], dt[:, 2], *body, bc, cc)
        inertia = self.inertia(x[:, 2], x[:, 1], x[:, 0])
        keep = torch.arange(b, device=self.device) < b - augmented  # augmented windows: static energies only
        loss = (static + torch.where(keep, inertia, torch.zeros_like(inertia))).mean()
        return loss, {**self.crit.terms, "inertia": inertia[keep]}

    def _about_static(self, i, augmented, x, dt, body, bc, cc):
        """E(x_s) for the static branch plus, for the dynamic part u = x - x_s (decoding and
        skinning are linear: u depends on the dynamic code and D only), E(x_s + u) - E(x_s) -
        F_s . u with F_s = dE/dx(x_s) held constant. ``crit.terms`` are those of x."""
        xs, dts = self.predict(i, augmented, motion=0.0)
        xs, dts = xs[:, 2], dts[:, 2]
        if not xs.requires_grad:  # a frozen static part
            xs = xs.detach().requires_grad_(True)
        e_static = self.crit(xs, dts, *body, bc, cc)
        force = torch.autograd.grad(e_static.sum(), xs, retain_graph=True)[0]
        u = x - xs  # no gradient to the static branch through u: the two cancel
        e = self.crit(xs.detach() + u, dt, *body, bc, cc)
        return e_static + e - e_static.detach() - (force * u).sum((1, 2))


@torch.no_grad()
def validate(step: Step, chunk: int = 32) -> dict:
    """Held-out windows: energies, inertia, collision % and edge error (mm) at the last frame, and
    how far the dynamics move the cloth (mm, mean over vertices: NCS against motion control 0)."""
    step.model.eval()
    data, crit = step.data, step.crit
    agg: dict[str, list] = {"loss": [], "inertia": [], "collision_pct": [], "edge_mm": [], "dynamic_mm": []}
    for a in range(0, len(data), chunk):
        i = torch.arange(a, min(len(data), a + chunk))
        x, dt = step.predict(i)
        still, _ = step.predict(i, motion=0.0)
        v, (bv, bn) = x[:, 2], step.body(i)
        inertia = step.inertia(v, x[:, 1], x[:, 0])
        agg["loss"].append(crit(v, dt[:, 2], bv, bn) + inertia)
        agg["inertia"].append(inertia)
        agg["edge_mm"].append(crit.edge.strain(v).abs().mean(1) * 1000)
        agg["collision_pct"].append(collision_pct(v, bv, bn))
        agg["dynamic_mm"].append((v - still[:, 2]).norm(dim=-1).mean(1) * 1000)
    step.model.train()
    return {k: float(torch.cat(x).mean()) for k, x in agg.items()}


def train(body, cfg: NCSTrainConfig | None = None, out: Path | None = None, log=print, progress: bool = True) -> dict:
    """Train the NCS of ``cfg.outfit`` from its PBNS; writes ``out`` (default
    ``store.ncs_path``) with the training record inside and returns that record."""
    cfg = cfg or NCSTrainConfig()
    torch.manual_seed(cfg.seed)
    t0 = time.time()
    pbns_path = store.pbns_path(cfg.outfit)
    outfit, shape, name = trained_outfit(body, pbns_path)
    out = Path(out or store.ncs_path(name))
    pbns, _ = PBNS.load(pbns_path)
    model = NCS.from_pbns(pbns, NCSConfig(**{**asdict(cfg.model), "fps": cfg.fps}), outfit)
    with torch.no_grad():
        model.dynamic[-1].weight.mul_(cfg.dynamic_init)  # start near PBNS: a small dynamic code
    frames = int(round(cfg.window * cfg.fps))
    train_w = MotionWindows(body, "train", shape[None], frames, cfg.samples, cfg.seed, smooth=cfg.smooth_motion,
                            fps=cfg.fps)
    val_w = MotionWindows(body, "val", shape[None], frames, cfg.val_samples, cfg.seed + 1, smooth=cfg.smooth_motion,
                          fps=cfg.fps)
    model = model.to(cfg.device)
    distil_mm = distil_static(model, pbns, train_w, cfg.distil_steps, cfg.seed)
    part = hanging_part_to_train(model, outfit, cfg)
    cloth = outfit if part is None else part_outfit(outfit, part)  # what the energies see
    trained = model if part is None else model.part(part, cloth.faces)

    def criteria(o, rest):
        masses = torch.from_numpy(vertex_masses(o.vertices, o.faces))
        return L.Criterion(o, rest, cfg).to(cfg.device), InertiaLoss(masses, cfg.fps, cfg.inertia).to(cfg.device)

    crit, inertia = criteria(cloth, trained.rest)
    body_c, cloth_c = candidates(trained, crit, train_w.ends, train_w.transforms[:, 2], train_w.body_v,
                                 cfg.candidates)
    step = Step(trained, crit, inertia, train_w, body_c, cloth_c, cfg.motion_augmentation, cfg.remove_static_force)
    val_step = Step(model, *criteria(outfit, model.rest), val_w)  # the whole outfit, the part written back first
    log(f"ncs {name}: {len(cloth.vertices)} of {len(outfit.vertices)} vertices trained; windows of {frames} frames, "
        f"{len(train_w)} train / {len(val_w)} val; static encoder distilled from PBNS to {distil_mm:.2f} mm; "
        f"set-up {time.time() - t0:.1f} s")

    def val():
        if part is not None:
            model.set_part(part, trained)
        return validate(val_step)

    start = val()
    opt = torch.optim.Adam(param_groups(trained, cfg))
    per_epoch = len(train_w) // cfg.batch
    trainer = Trainer({"ncs": trained}, opt, cfg.epochs * per_epoch, eval_every=per_epoch, out_dir=run_dir_for(out),
                      config=asdict(cfg), desc=f"ncs {name}", steps_per_epoch=per_epoch, progress=progress)
    def train_step(i):
        crit.edge.scale = edge_scale(cfg.edge_warmup, trainer.step, trainer.steps)
        return step(i)

    curve = trainer.fit(epoch_batches(len(train_w), cfg.batch, trainer.step), train_step,
                        lambda: {f"val_{k}": v for k, v in val().items()})
    if part is not None:
        model.set_part(part, trained)
    meta = {"outfit": name, "pbns": pbns_path.name, "config": asdict(cfg), "model": asdict(model.cfg),
            "vertices": int(len(outfit.vertices)), "trained_vertices": int(len(cloth.vertices)),
            "window_frames": frames, "distil_mm": round(distil_mm, 3),
            "val_start": start, "train_seconds": round(time.time() - t0, 1), "threads": torch.get_num_threads(),
            "garments": [g.name for g in outfit.garments], "curve": curve["history"]}
    model.cpu().save(out, {"meta_json": json.dumps(meta), "layer": torch.from_numpy(outfit.layer),
                     "garment_id": torch.from_numpy(outfit.garment_id), "shape": shape})
    shutil.rmtree(run_dir_for(out), ignore_errors=True)
    return meta
