"""Train SMPLR from generated 3D data (no images). One command: ``recon smplr train``.

Stages (thesis 2.3-2.4): ``dae3d`` and ``dae2d`` (L1 on J+ under mixed noise / with depth
zeroed), ``psi`` (L1 on shape), ``omega`` (L1 on rotation matrices), then ``finetune``
(L_R + L_beta + L1 on J+ through the body model). Each stage keeps the checkpoint with the
best validation loss and resumes from its last state if interrupted.
"""
from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from torch import nn

from recon import paths
from recon.smplr import features, noise
from recon.smplr.data import load_or_generate
from recon.smplr.networks import DAEConfig, DenoisingAutoencoder, PoseNet, ShapeNet, global_to_local, local_to_global

log = logging.getLogger(__name__)


@dataclass
class TrainConfig:
    train_size: int = 400_000
    val_size: int = 8_192
    pose_noise_deg: float = 8.0
    batch: int = 256
    lr: float = 1e-3
    steps: dict = field(default_factory=lambda: {"dae3d": 8000, "dae2d": 8000, "psi": 4000, "omega": 20000,
                                                  "finetune": 1200})
    eval_every: int = 500
    input_noise_mm: float = 10.0  # light Gaussian augmentation of Omega/Psi inputs (half the batches)
    point_weight: float = 10.0  # L1 on J+ in metres x this, in the fine-tune stage
    omega_width: int = 512
    omega_blocks: int = 3
    omega_global: bool = True  # predict world bone rotations (see PoseNet)
    psi_width: int = 256
    seed: int = 0


def work_dir() -> Path:
    d = paths.cache_dir() / "smplr-train"
    d.mkdir(parents=True, exist_ok=True)
    return d


def _cosine(opt, step, total, lr):
    for g in opt.param_groups:
        g["lr"] = 1e-5 + 0.5 * (lr - 1e-5) * (1 + math.cos(math.pi * min(step, total) / total))


def _augment(points, gen, sigma_mm):
    keep = torch.rand(points.shape[0], 1, 1, generator=gen) < 0.5
    noisy = noise.gaussian(points, sigma_max=sigma_mm / 1000.0, gen=gen)
    return torch.where(keep, points, noisy)


class Stage:
    """One training stage: builds its networks, computes its loss, evaluates on val."""

    def __init__(self, name, cfg: TrainConfig, body, template):
        self.name, self.cfg, self.body, self.template = name, cfg, body, template
        self.nets: dict[str, nn.Module] = {}
        if name in ("dae3d", "dae2d"):
            self.nets[name] = DenoisingAutoencoder(DAEConfig(lifting=name == "dae2d"))
        if name in ("psi", "finetune"):
            self.nets["psi"] = ShapeNet(body.num_shape_params, width=cfg.psi_width)
        if name in ("omega", "finetune"):
            self.nets["omega"] = PoseNet(cfg.omega_width, cfg.omega_blocks, cfg.omega_global)
        if name == "finetune":  # start from the isolated stages
            for k in ("psi", "omega"):
                self.nets[k].load_state_dict(torch.load(work_dir() / f"{k}.best.pt", weights_only=True)["state"])

    def loss(self, batch, gen, train: bool):
        pts, rot, shape = batch["points"], batch["rotmats"], batch["shape"]
        if self.name in ("dae3d", "dae2d"):
            # Centroid-centred in and out: the DAE fixes the shape of J+, not where it is.
            x = noise.mixed(pts, gen) if self.name == "dae3d" else pts
            return (self.nets[self.name](features.centre(x, self.name == "dae2d")) - features.centre(pts)).abs().mean()
        x = _augment(pts, gen, self.cfg.input_noise_mm) if train else pts
        total = 0.0
        if "psi" in self.nets:
            pred_s = self.nets["psi"](features.relative_distances(x, self.template))
            total = total + (pred_s - shape).abs().mean()
        if "omega" in self.nets:
            net = self.nets["omega"]
            raw = net.raw(features.normalized_relative(x))
            if net.global_rot:  # L1 on world rotations, plus on parent-relative ones
                pred_r = global_to_local(raw)
                total = total + (raw - local_to_global(rot)).abs().mean() + 0.5 * (pred_r - rot).abs().mean()
            else:
                pred_r = raw
                total = total + (pred_r - rot).abs().mean()
        if self.name == "finetune":
            out = self.body(pred_r, pred_s, points_only=True)
            total = total + self.cfg.point_weight * (out.points - pts).abs().mean()
        return total


def train_stage(name: str, cfg: TrainConfig, body, train, val) -> dict:
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed + hash(name) % 1000)
    template = features.template_distances(body)
    st = Stage(name, cfg, body, template)
    params = [p for n in st.nets.values() for p in n.parameters()]
    opt = torch.optim.Adam(params, lr=cfg.lr if name != "finetune" else cfg.lr * 0.1)
    total = cfg.steps[name]
    state_path = work_dir() / f"{name}.state.pt"
    step, best, history = 0, float("inf"), []
    if state_path.exists():  # resume
        s = torch.load(state_path, weights_only=True)
        for k, n in st.nets.items():
            n.load_state_dict(s["nets"][k])
        opt.load_state_dict(s["opt"])
        step, best, history = s["step"], s["best"], s["history"]
        log.info("%s: resuming at step %d", name, step)
    n_train = train["points"].shape[0]
    t0 = time.time()
    from tqdm import tqdm

    bar = tqdm(total=total, initial=step, desc=f"train {name}", unit="step", mininterval=10)
    while step < total:
        for n in st.nets.values():
            n.train()
        idx = torch.randint(0, n_train, (cfg.batch,), generator=gen)
        loss = st.loss({k: v[idx] for k, v in train.items()}, gen, True)
        _cosine(opt, step, total, opt.defaults["lr"])
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        bar.update(1)
        if step % cfg.eval_every == 0 or step == total:
            for n in st.nets.values():
                n.eval()
            vgen = torch.Generator().manual_seed(123)
            with torch.no_grad():
                vl = sum(float(st.loss({k: v[i:i + 1024] for k, v in val.items()}, vgen, False)) *
                         min(1024, val["points"].shape[0] - i) for i in range(0, val["points"].shape[0], 1024))
            vl /= val["points"].shape[0]
            history.append({"step": step, "train_loss": loss.item(), "val_loss": vl, "time_s": time.time() - t0})
            bar.set_postfix(train=f"{loss.item():.4f}", val=f"{vl:.4f}")
            if vl < best:
                best = vl
                for k, n in st.nets.items():
                    paths.atomic_write(work_dir() / f"{k}.best.pt" if name != "finetune" else work_dir() / f"ft_{k}.best.pt",
                                       lambda tmp, n=n: torch.save({"state": n.state_dict()}, tmp))
            paths.atomic_write(state_path, lambda tmp: torch.save(
                {"nets": {k: n.state_dict() for k, n in st.nets.items()}, "opt": opt.state_dict(),
                 "step": step, "best": best, "history": history}, tmp))
    bar.close()
    return {"stage": name, "best_val_loss": best, "steps": total, "history": history}


def export(cfg: TrainConfig, body, out: Path) -> Path:
    """Bundle the best networks into one weights file (loaded by SMPLR.load)."""
    w = work_dir()
    missing = [k for k in ("omega", "psi") if not (w / f"{k}.best.pt").exists()]
    if missing:
        raise FileNotFoundError(f"no trained {missing} in {w}: run `recon smplr train` first")
    ck = {"num_shape": body.num_shape_params, "train_config": json.dumps(asdict(cfg)),
          "omega_cfg": {"width": cfg.omega_width, "blocks": cfg.omega_blocks, "global_rot": cfg.omega_global},
          "psi_cfg": {"width": cfg.psi_width}}
    for k, f in (("omega", "ft_omega"), ("psi", "ft_psi")):
        src = w / f"{f}.best.pt" if (w / f"{f}.best.pt").exists() else w / f"{k}.best.pt"
        ck[k] = torch.load(src, weights_only=True)["state"]
    for k in ("dae3d", "dae2d"):
        if (w / f"{k}.best.pt").exists():
            ck[k] = torch.load(w / f"{k}.best.pt", weights_only=True)["state"]
            ck[k + "_cfg"] = asdict(DAEConfig(lifting=k == "dae2d"))
    paths.atomic_write(out, lambda tmp: torch.save(ck, tmp))
    return out


def run(stages: list[str], cfg: TrainConfig | None = None) -> list[dict]:
    """Train the given stages in order (each resumes if interrupted); returns their logs."""
    from recon.body import default_body

    cfg = cfg or TrainConfig()
    body = default_body()
    train = load_or_generate(body, "train", cfg.train_size, cfg.seed, cfg.pose_noise_deg)
    val = load_or_generate(body, "val", cfg.val_size, cfg.seed + 100, 0.0)
    logs = []
    for s in stages:
        logs.append(train_stage(s, cfg, body, train, val))
        paths.atomic_write(work_dir() / f"{s}.log.json", lambda tmp: Path(tmp).write_text(json.dumps(logs[-1], indent=1)))
    return logs
