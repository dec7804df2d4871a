"""Training the authoring model (``recon garment train --model author``): the simulations of
``author.data`` as frames (offsets, motion signatures, parameter sets), then the shape descriptor
(L2 + Laplacian reconstruction, section 3.3) and the motion encoder with the motion-invariant
autoencoder (Var(z) + lambda |S - S*| over batches of parameter sets, section 3.4), Adam on the CPU.
Variants for the paper's ablations: "concat" (motion concatenated, a standard autoencoder) and
"embedding" (the encoder trained to keep distances of the parameters, then the decoder alone).
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
import torch

from recon.body import default_body
from recon.body.base import BodyModel
from recon.garment import store
from recon.garment.author.data import (
    AuthorDataConfig,
    Sim,
    generate,
    missing,
    plan,
    sim_folder,
    teacher_config,
)
from recon.garment.author.model import (
    AuthorConfig,
    AuthorModel,
    IntrinsicAutoencoder,
    ShapeDescriptor,
    base_ncs,
    clip_inputs,
    heading,
)
from recon.garment.mesh import neighbour_mean
from recon.garment.ncs.data import Motions, moving_part, part_outfit
from recon.garment.pbns.model import PBNS, trained_outfit


@dataclass
class AuthorTrainConfig:
    data: AuthorDataConfig = field(default_factory=AuthorDataConfig)
    model: AuthorConfig = field(default_factory=AuthorConfig)
    variant: str = "ours"  # "ours", "concat" (architecture ablation), "embedding" (training ablation)
    descriptor_epochs: int = 300
    descriptor_batch: int = 64
    steps: int = 5000  # autoencoder steps
    groups: int = 8  # parameter sets per batch
    frames: int = 16  # frames per parameter set in a batch
    lr: float = 1e-3
    weight_decay: float = 0.05  # the autoencoder's (AdamW)
    descriptor_from: str = ""  # a model file whose shape descriptor (same data) to keep
    seed: int = 0


class Frames(NamedTuple):
    """Simulated frames: hanging-part offsets from the base cloth in the heading frame (F, n, 3),
    motion signatures (F, D), the parameter set's global id, its intrinsics in [0, 1] (F, 6), the
    simulation's index in the plan and the frame within the simulation."""
    offsets: torch.Tensor
    sig: torch.Tensor
    set_id: torch.Tensor
    theta: torch.Tensor
    sim: torch.Tensor
    frame: torch.Tensor


class Outfit(NamedTuple):
    """The outfit's hanging part as the simulations have it: vertex ids, faces, body shape."""
    index: torch.Tensor
    faces: np.ndarray
    shape: torch.Tensor


def hanging_outfit(body: BodyModel, outfit: str) -> Outfit:
    cfg = teacher_config(outfit)
    full, shape, _ = trained_outfit(body, store.trained_pbns(outfit))
    hanging, _ = moving_part(body, full, shape[None], cfg)
    idx = np.nonzero(hanging)[0]
    return Outfit(torch.from_numpy(idx), part_outfit(full, idx).faces, shape)


def clip_motion(body: BodyModel, motions: Motions, sim: Sim, cfg: AuthorConfig):
    """A simulation's motion: rotations, translation, heading (T, 3, 3), joints (T, 24, 3), signatures."""
    rot, transl = motions.motion(sim.chunk)
    with torch.no_grad():
        joints = body(rot, motions.shape.expand(len(rot), -1), transl=transl, points_only=True).joints
    yaw = heading(rot[:, 0])
    return rot, transl, yaw, joints, cfg.signature(joints, yaw)


def load_frames(cfg: AuthorDataConfig, split: str, model: AuthorConfig, body: BodyModel | None = None, log=print,
                dtype: torch.dtype = torch.float32) -> tuple[Frames, list[Sim], int]:
    """Every frame after the lead of ``split``'s simulations of ``plan(cfg)`` (the train split: of
    its ``train_sets`` first sets), the offsets from ``model.base``'s cloth in ``dtype`` (float16: the
    files' own precision, half the memory of 100k frames); also those sims and the lead."""
    folder = sim_folder(cfg)
    sims = [s for s in plan(cfg) if s.split == split]
    gone = missing(folder, sims)
    if gone:
        raise FileNotFoundError(f"{len(gone)} {split} simulations of {cfg.outfit} are not in {folder}: run `recon "
                                f"garment train --model author --outfit {cfg.outfit} --train-sets {cfg.train_sets}`")
    body = body or default_body()
    outfit = hanging_outfit(body, cfg.outfit)
    motions = Motions(body, outfit.shape[None], teacher_config(cfg.outfit).smooth_motion)
    ncs = base_ncs(cfg.outfit, model)
    pbns = PBNS.load(store.trained_pbns(cfg.outfit))[0] if ncs is not None else None
    parts = []
    for k, s in enumerate(sims):
        x = torch.from_numpy(np.load(folder / f"{s.name}.npy").astype(np.float32))
        rot, transl, yaw, _, sig = clip_motion(body, motions, s, model)
        keep = slice(cfg.lead, None)
        if ncs is not None:  # the simulations are offsets from PBNS's drape: from NCS's cloth instead
            static = clip_inputs(body, pbns, outfit.shape, rot, transl)[0][:, outfit.index]
            x = x - (clip_inputs(body, pbns, outfit.shape, rot, transl, ncs)[0][:, outfit.index] - static)
        off = torch.einsum("tji,tnj->tni", yaw[keep], x[keep]).to(dtype)
        n = len(off)
        gid = {"train": 0, "val": 1000, "test": 2000}[split] + s.set
        parts.append((off, sig[keep], torch.full((n,), gid), torch.from_numpy(s.params.vector()).float().expand(n, -1),
                      torch.full((n,), k), torch.arange(cfg.lead, cfg.lead + n)))
    if not parts:
        raise ValueError(f"the plan of {cfg.outfit} has no {split} simulation")
    log(f"{split}: {len(parts)} simulations, {sum(len(p[0]) for p in parts)} frames")
    return Frames(*[torch.cat(c) for c in zip(*parts)]), sims, cfg.lead


def laplacian(faces: np.ndarray, n: int) -> sp.csr_matrix:
    """The uniform (umbrella) Laplacian I - mean of the neighbours (Taubin 1995)."""
    return (sp.identity(n, format="csr") - neighbour_mean(faces, n)).tocsr()


PCA_FRAMES = 10000  # frames the principal directions are taken from at most (evenly spaced)
CHUNK = 4096  # frames a matrix product takes at a time (memory, not results)


def in_chunks(fn, x: torch.Tensor, size: int = CHUNK) -> torch.Tensor:
    """``fn`` of ``x``'s rows ``size`` at a time in float32, concatenated."""
    return torch.cat([fn(x[i:i + size].float()) for i in range(0, len(x), size)])


def principal_basis(offsets: torch.Tensor, dims: int, max_frames: int = PCA_FRAMES
                    ) -> tuple[torch.Tensor, torch.Tensor, float]:
    """Mean (3n,), the first ``dims`` principal directions (3n, dims) and the RMS of their
    coefficients, of offsets (F, n, 3) (eigenvectors of the frames' Gram matrix, of at most
    ``max_frames`` evenly spaced frames about the mean of all: its memory grows with their square)."""
    f, d = len(offsets), offsets[0].numel()
    mean = sum(offsets[i:i + CHUNK].reshape(-1, d).double().sum(0) for i in range(0, f, CHUNK)) / f
    x = offsets[::-(-f // max_frames)].reshape(-1, d).double() - mean
    evals, evecs = torch.linalg.eigh(x @ x.T)
    order = torch.argsort(evals, descending=True)[:dims]
    basis = x.T @ evecs[:, order] / evals[order].clamp(min=1e-12).sqrt()
    del x
    squares = sum(float(((offsets[i:i + CHUNK].reshape(-1, d).double() - mean) @ basis).pow(2).sum())
                  for i in range(0, f, CHUNK))
    return mean.float(), basis.float(), (squares / (f * basis.shape[1])) ** 0.5


def laplacian_form(basis: torch.Tensor, lap: sp.csr_matrix, coeffs: torch.Tensor) -> torch.Tensor:
    """Q (P, P): |L P d|^2 = d Q d for coefficient errors d, scaled so that on the data's
    coefficients the Laplacian and L2 energies are equal (omega weighs them as equals)."""
    n = lap.shape[0]
    lb = torch.from_numpy(lap @ basis.double().numpy().reshape(n, -1)).reshape(-1, basis.shape[1])
    q = lb.T @ lb
    c = coeffs.double()
    return (q * (c.pow(2).sum(1).mean() / ((c @ q) * c).sum(1).mean())).float()


def descriptor_loss(desc: ShapeDescriptor, c: torch.Tensor, q: torch.Tensor, omega: float) -> torch.Tensor:
    d = desc.decode_coefficients(desc.encode_coefficients(c)) - c
    return d.pow(2).sum(1).mean() + omega * ((d @ q) * d).sum(1).mean()


def train_descriptor(train: torch.Tensor, faces: np.ndarray, cfg: AuthorTrainConfig, dims: int | None = None,
                     log=print) -> ShapeDescriptor:
    """The shape descriptor (N_E, N_D) of ``dims`` (default ``cfg.model.shape_dims``) on offsets (F, n, 3)."""
    torch.manual_seed(cfg.seed)
    m = cfg.model
    mean, basis, scale = principal_basis(train, m.pca_dims)
    desc = ShapeDescriptor(mean, basis, scale, dims or m.shape_dims, m.shape_hidden)
    with torch.no_grad():
        c = in_chunks(desc.coefficients, train)
    q = laplacian_form(basis, laplacian(faces, train.shape[1]), c)
    opt = torch.optim.Adam(desc.parameters(), lr=cfg.lr)
    steps = cfg.descriptor_epochs * max(1, len(c) // cfg.descriptor_batch)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    g = torch.Generator().manual_seed(cfg.seed)
    desc.train()
    for step in range(steps):
        idx = torch.randint(len(c), (cfg.descriptor_batch,), generator=g)
        loss = descriptor_loss(desc, c[idx], q, m.laplacian)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % 5000 == 0 or step == steps - 1:
            log(f"descriptor {dims or m.shape_dims}: step {step + 1}/{steps} loss {loss.item():.4f}")
    return desc.eval()


def group_batches(set_id: torch.Tensor, groups: int, frames: int, g: torch.Generator) -> torch.Tensor:
    """Indices (groups * frames,) of ``frames`` random frames from each of ``groups`` random sets."""
    sets = torch.unique(set_id)
    chosen = sets[torch.randperm(len(sets), generator=g)[:groups]]
    out = []
    for s in chosen:
        mine = torch.nonzero(set_id == s)[:, 0]
        out.append(mine[torch.randint(len(mine), (frames,), generator=g)])
    return torch.cat(out)


def within_variance(z: torch.Tensor, groups: int) -> torch.Tensor:
    """Mean over groups (consecutive equal blocks of the batch) of z's variance in each, over z's
    variance in the whole batch: Var(z) of the paper without the way out of shrinking z."""
    return z.view(groups, -1, z.shape[-1]).var(1).mean() / z.var(0).mean().clamp(min=1e-12)


def theta_distance_loss(z: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    """The embedding loss: pairwise distances of z against those of the parameters, each scaled by
    its mean (the ablation's encoder keeps the parameter space's geometry)."""
    dz, dt = torch.cdist(z, z), torch.cdist(theta, theta)
    return ((dz / dz.mean().clamp(min=1e-8) - dt / dt.mean().clamp(min=1e-8)) ** 2).mean()


def train_autoencoder(s: torch.Tensor, sig: torch.Tensor, frames: Frames, cfg: AuthorTrainConfig,
                      log=print) -> IntrinsicAutoencoder:
    """F_E, F_D and M_E on shape descriptors ``s`` (F, N_S) and signatures ``sig`` (F, D)."""
    torch.manual_seed(cfg.seed)
    m = cfg.model if cfg.variant != "concat" else replace(cfg.model, architecture="concat")
    ae = IntrinsicAutoencoder(sig.shape[1], m)
    with torch.no_grad():
        ae.motion_mean.copy_(sig.mean(0))
        ae.motion_std.copy_(sig.std(0).clamp(min=1e-2))
    g = torch.Generator().manual_seed(cfg.seed)
    stages = [("joint", list(ae.parameters()))]
    if cfg.variant == "embedding":
        enc = [p for n, p in ae.named_parameters() if not n.startswith("f_d")]
        stages = [("encoder", enc), ("decoder", list(ae.f_d.parameters()))]
    for stage, params in stages:
        opt = torch.optim.AdamW([p for p in params if p.requires_grad], lr=cfg.lr, weight_decay=cfg.weight_decay)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.steps)
        ae.train()
        for step in range(cfg.steps):
            idx = group_batches(frames.set_id, cfg.groups, cfg.frames, g)
            md = ae.motion_descriptor(sig[idx])
            if stage == "decoder":
                with torch.no_grad():
                    ae.eval()
                    z = ae.encode(s[idx], ae.motion_descriptor(sig[idx]))
                    ae.train()
                loss = (ae.decode(z, md) - s[idx]).pow(2).mean()
            else:
                z = ae.encode(s[idx], md)
                rec = (ae.decode(z, md) - s[idx]).pow(2).mean()
                if stage == "encoder":
                    loss = theta_distance_loss(z, frames.theta[idx])
                else:
                    loss = within_variance(z, cfg.groups) + m.lam * rec
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            if step % 1000 == 0 or step == cfg.steps - 1:
                log(f"autoencoder ({cfg.variant}, {stage}): step {step + 1}/{cfg.steps} loss {loss.item():.4f}")
    return ae.eval()


def model_name(outfit: str, variant: str = "ours", train_sets: int | None = None) -> str:
    """The model file's name: the outfit's, plus the variant and a train-set count not the default's."""
    name = outfit if variant == "ours" else f"{outfit}-{variant}"
    return name if train_sets in (None, AuthorDataConfig.train_sets) else f"{name}-{train_sets}sets"


def model_path(cfg: AuthorTrainConfig) -> Path:
    """Where ``train(cfg)`` writes its model."""
    return store.author_path(model_name(cfg.data.outfit, cfg.variant, cfg.data.train_sets))


def is_trained(cfg: AuthorTrainConfig) -> bool:
    """Whether ``cfg``'s model file holds a model of ``cfg`` on the simulations it would use now."""
    path = model_path(cfg)
    if not path.exists():
        return False
    meta = AuthorModel.load(path)[1]

    def plain(c: dict) -> dict:  # tuples as lists, as JSON has them; the workers change no result
        return json.loads(json.dumps({**c, "data": {**c["data"], "workers": 0}}))

    return meta.get("data_folder") == sim_folder(cfg.data).name and plain(meta["config"]) == plain(asdict(cfg))


def train(cfg: AuthorTrainConfig, log=print, simulate: bool = True, path: Path | None = None) -> tuple[Path, dict]:
    """Generate the data if missing (``simulate``; else the train simulations must be there), fit
    the networks, write ``path`` (default ``model_path(cfg)``); returns the path and the timings."""
    t0 = time.time()
    folder = generate(cfg.data, log=log) if simulate else sim_folder(cfg.data)
    timing = folder / "timing.json"
    t_data = json.loads(timing.read_text())["seconds"] if timing.exists() else None
    torch.set_num_threads(max(1, torch.get_num_threads()))
    body = default_body()
    outfit = hanging_outfit(body, cfg.data.outfit)
    frames, _, _ = load_frames(cfg.data, "train", cfg.model, body, log, torch.float16)
    t1 = time.time()
    if cfg.descriptor_from:  # the same data's descriptor, already trained
        desc = AuthorModel.load(Path(cfg.descriptor_from))[0].descriptor
    else:
        desc = train_descriptor(frames.offsets, outfit.faces, cfg, log=log)
    with torch.no_grad():
        s = in_chunks(desc.encode, frames.offsets)
    t2 = time.time()
    ae = train_autoencoder(s, frames.sig, frames, cfg, log)
    t3 = time.time()
    model = AuthorModel(outfit.index, desc, ae, cfg.data.outfit, ae.cfg)
    meta = {"config": asdict(cfg), "data_folder": folder.name, "frames": len(frames.offsets),
            "sets": int(len(torch.unique(frames.set_id))), "seconds": {
                "data": t_data and round(t_data, 1), "load": round(t1 - t0, 1), "descriptor": round(t2 - t1, 1),
                "autoencoder": round(t3 - t2, 1)}}
    path = model.save(path or model_path(cfg), meta)
    log(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB): {meta['seconds']}")
    return path, meta
