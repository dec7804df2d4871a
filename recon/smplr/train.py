"""Train SMPLR from generated 3D data (no images). One command: ``recon smplr train``.

Stages (thesis 2.3-2.4): ``dae3d`` and ``dae2d`` (L1 on J+ under mixed noise / with depth
zeroed), ``psi`` (L1 on shape), ``omega`` (L1 on rotation matrices), then ``finetune``
(L_R + L_beta + L1 on J+ through the body model). Each stage keeps the checkpoint with the
best validation loss (``<cache>/smplr-train/<stage>/best.pt``) and resumes from its last state
if interrupted (``recon.training.Trainer``).
"""
from __future__ import annotations

import json
import logging
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from torch import nn

from recon import paths
from recon.body import default_body
from recon.body.base import BodyModel
from recon.errors import MissingFile
from recon.smplr import features, noise
from recon.smplr.data import load_or_generate
from recon.smplr.networks import DAEConfig, DenoisingAutoencoder, PoseNet, ShapeNet, global_to_local, local_to_global
from recon.training import Schedule, Trainer

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


STAGES = ("dae3d", "dae2d", "psi", "omega", "finetune")
MIN_LR = 1e-5  # the cosine schedule's end


def work_dir() -> Path:
    d = paths.cache_dir() / "smplr-train"
    d.mkdir(parents=True, exist_ok=True)
    return d


def _best(stage: str) -> dict:
    path = work_dir() / stage / "best.pt"
    if not path.exists():
        raise MissingFile(f"no trained {stage} in {path.parent}: run `recon smplr train --stages {stage}` first")
    return torch.load(path, map_location="cpu", weights_only=True)


def _augment(points, gen, sigma_mm):
    keep = torch.rand(points.shape[0], 1, 1, generator=gen) < 0.5
    noisy = noise.gaussian(points, sigma_max=sigma_mm / 1000.0, gen=gen)
    return torch.where(keep, points, noisy)


class Stage:
    """One training stage: builds its networks, computes its loss, evaluates on val."""

    def __init__(self, name, cfg: TrainConfig, body: BodyModel, template):
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
                self.nets[k].load_state_dict(_best(k)[k])

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


def train_stage(name: str, cfg: TrainConfig, body: BodyModel, train, val, progress: bool = True) -> dict:
    """Train one stage (resuming from ``work_dir()/name`` if it was interrupted); returns its log."""
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed + zlib.crc32(name.encode()) % 1000)
    st = Stage(name, cfg, body, features.template_distances(body))
    lr = cfg.lr if name != "finetune" else cfg.lr * 0.1
    opt = torch.optim.Adam([p for n in st.nets.values() for p in n.parameters()], lr=lr)
    trainer = Trainer(st.nets, opt, cfg.steps[name], schedule=Schedule(floor=MIN_LR / lr), eval_every=cfg.eval_every,
                      out_dir=work_dir() / name, select="val_loss", generators=[gen], desc=f"train {name}",
                      config={"stage": name, **asdict(cfg)}, progress=progress)
    n_train, n_val = train["points"].shape[0], val["points"].shape[0]

    def batches():
        while True:
            idx = torch.randint(0, n_train, (cfg.batch,), generator=gen)
            yield {k: v[idx] for k, v in train.items()}

    def step(batch):
        for n in st.nets.values():
            n.train()
        return st.loss(batch, gen, True)

    @torch.no_grad()
    def validate() -> dict:
        for n in st.nets.values():
            n.eval()
        vgen = torch.Generator().manual_seed(123)
        total = sum(float(st.loss({k: v[i:i + 1024] for k, v in val.items()}, vgen, False)) * min(1024, n_val - i)
                    for i in range(0, n_val, 1024))
        return {"val_loss": total / n_val}

    log = trainer.fit(batches(), step, validate)
    return {"stage": name, "best_val_loss": log["best"], "steps": log["steps"], "history": log["history"]}


def export(cfg: TrainConfig, body: BodyModel, out: Path) -> Path:
    """Bundle the best networks of every stage into one weights file (loaded by SMPLR.load):
    Omega and Psi from the fine-tuning stage when it ran, else from their own stages."""
    ck = {"num_shape": body.num_shape_params, "train_config": json.dumps(asdict(cfg)),
          "omega_cfg": {"width": cfg.omega_width, "blocks": cfg.omega_blocks, "global_rot": cfg.omega_global},
          "psi_cfg": {"width": cfg.psi_width}}
    tuned = (work_dir() / "finetune" / "best.pt").exists()
    for k in ("omega", "psi"):
        ck[k] = _best("finetune" if tuned else k)[k]
    for k in ("dae3d", "dae2d"):
        if (work_dir() / k / "best.pt").exists():
            ck[k] = _best(k)[k]
            ck[k + "_cfg"] = asdict(DAEConfig(lifting=k == "dae2d"))
    paths.atomic_write(out, lambda tmp: torch.save(ck, tmp))
    return out


def run(stages: list[str], cfg: TrainConfig | None = None) -> list[dict]:
    """Train the given stages in order (each resumes if interrupted); returns their logs."""
    cfg = cfg or TrainConfig()
    body = default_body()
    train = load_or_generate(body, "train", cfg.train_size, cfg.seed, cfg.pose_noise_deg)
    val = load_or_generate(body, "val", cfg.val_size, cfg.seed + 100, 0.0)
    return [train_stage(s, cfg, body, train, val) for s in stages]
