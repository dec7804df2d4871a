"""Train the volumetric stacked hourglass on synthetic shards (``recon backbone train``).

Samples come from ``recon synth`` folders. Each image is cropped with the thesis' metric
2.5 m crop around the mean joint (scale/centre jittered), resized to the network input, and
augmented (colour, horizontal flip with the left/right point map, in-plane rotation). Loss:
softmax cross-entropy on every stack's volumes (thesis 2.4.1). Validation: MPJPE of the
decoded joints on a fixed slice of synth-val (ground-truth crop, as in the thesis protocol).
Checkpoints are resumable; the learning curve is written as JSON next to them.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from recon import paths
from recon.backbone.crop import Crop
from recon.backbone.hourglass import SIZES, HourglassConfig, StackedHourglass
from recon.backbone.volumetric import soft_argmax_3d, volumetric_ce
from recon.body import skeleton
from recon.synth.dataset import SynthDataset


@dataclass
class BackboneTrainConfig:
    size: str = "cpu"  # key of hourglass.SIZES
    batch: int = 16
    lr: float = 2.5e-4
    steps: int = 20000
    eval_every: int = 500
    val_images: int = 256
    workers: int = 2
    augment: bool = True
    seed: int = 0
    model: dict = field(default_factory=dict)  # overrides of HourglassConfig


class CropDataset(Dataset):
    """(image tensor (3,S,S) in [0,1], grid targets (42,3), crop parameters) per sample."""

    def __init__(self, roots: list[Path], input_size: int, augment: bool, seed: int = 0):
        self.sets = [SynthDataset(r) for r in roots]
        self.index = [(i, j) for i, s in enumerate(self.sets) for j in range(len(s))]
        self.size, self.augment, self.seed = input_size, augment, seed

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, n: int):
        i, j = self.index[n]
        s = self.sets[i][j]
        rng = np.random.default_rng([self.seed, n, int(time.time_ns() % 1_000_000) if self.augment else 0])
        pts = s["points3d"].astype(np.float64)
        centre = pts[:24].mean(0)
        extent = 2.5
        if self.augment:
            centre = centre + rng.normal(0, 0.05, 3) * [1, 1, 0]
            extent *= rng.uniform(0.9, 1.1)
        crop = Crop.around(centre, s["K"].astype(np.float64), extent)
        img = crop.image(s["rgb"], self.size).astype(np.float32) / 255.0
        grid = crop.to_grid(pts)
        if self.augment:
            if rng.random() < 0.5:  # flip: mirror x, swap left/right points
                img = img[:, ::-1]
                grid = grid[list(skeleton.POINT_MIRROR)]
                grid[:, 0] = 1.0 - grid[:, 0]
            ang = rng.normal(0, 15)
            if abs(ang) > 1:
                m = cv2.getRotationMatrix2D((self.size / 2, self.size / 2), ang, 1.0)
                img = cv2.warpAffine(img, m, (self.size, self.size), borderMode=cv2.BORDER_CONSTANT)
                xy = grid[:, :2] * self.size  # the same affine map moves the targets
                grid[:, :2] = (xy @ m[:, :2].T + m[:, 2]) / self.size
            img = np.clip(img * rng.uniform(0.7, 1.3, 3) + rng.normal(0, 0.03), 0, 1)
        crop_vec = np.array([crop.u0, crop.v0, crop.side, crop.zc, crop.extent], np.float64)
        return (torch.from_numpy(np.ascontiguousarray(img.transpose(2, 0, 1))).float(),
                torch.from_numpy(grid).float(), torch.from_numpy(crop_vec), torch.from_numpy(s["K"].astype(np.float64)),
                torch.from_numpy(pts))


def decode(grid: np.ndarray, crop_vec: np.ndarray, k: np.ndarray) -> np.ndarray:
    u0, v0, side, zc, extent = crop_vec
    return Crop(u0, v0, side, zc, k, extent).from_grid(grid)


def evaluate(net: StackedHourglass, loader: DataLoader, device: str) -> float:
    """Mean pelvis-aligned joint error (mm) of the last stack's soft-argmax."""
    net.eval()
    errs = []
    with torch.no_grad():
        for img, _, crop_vec, k, pts in loader:
            g = soft_argmax_3d(net(img.to(device))[-1][:, :skeleton.NUM_POINTS].float()).cpu().numpy()
            for b in range(len(g)):
                p = decode(g[b].astype(np.float64), crop_vec[b].numpy(), k[b].numpy())
                gt = pts[b].numpy()
                errs.append(np.linalg.norm((p[:24] - p[:1]) - (gt[:24] - gt[:1]), axis=1).mean())
    net.train()
    return float(np.mean(errs) * 1000)


def train(train_roots: list[Path], val_root: Path, out_dir: Path, cfg: BackboneTrainConfig = BackboneTrainConfig(),
          device: str = "cpu") -> dict:
    from tqdm import tqdm

    torch.manual_seed(cfg.seed)
    mcfg = HourglassConfig(**{**asdict(SIZES[cfg.size]), **cfg.model})
    net = StackedHourglass(mcfg).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    out_dir.mkdir(parents=True, exist_ok=True)
    state_path, best_path, curve_path = out_dir / "state.pt", out_dir / "best.pt", out_dir / "curve.json"
    step, best, history = 0, float("inf"), []
    if state_path.exists():
        s = torch.load(state_path, map_location=device, weights_only=True)
        net.load_state_dict(s["net"])
        opt.load_state_dict(s["opt"])
        step, best, history = s["step"], s["best"], s["history"]
    data = CropDataset(train_roots, mcfg.input_size, cfg.augment, cfg.seed)
    val = CropDataset([val_root], mcfg.input_size, False)
    val.index = val.index[:cfg.val_images]
    loader = DataLoader(data, batch_size=cfg.batch, shuffle=True, num_workers=cfg.workers, drop_last=True,
                        persistent_workers=cfg.workers > 0)
    val_loader = DataLoader(val, batch_size=cfg.batch, num_workers=0)
    bar = tqdm(total=cfg.steps, initial=step, desc="train backbone", unit="step", mininterval=10)
    t0 = time.time()
    while step < cfg.steps:
        for img, grid, *_ in loader:
            outs = net(img.to(device))
            g = grid.to(device)
            loss = sum(volumetric_ce(o[:, :skeleton.NUM_POINTS].float(), g) for o in outs)
            opt.zero_grad()
            loss.backward()
            opt.step()
            step += 1
            bar.update(1)
            if step % cfg.eval_every == 0 or step == cfg.steps:
                mpjpe = evaluate(net, val_loader, device)
                history.append({"step": step, "loss": loss.item(), "val_mpjpe_mm": mpjpe, "time_s": time.time() - t0})
                bar.set_postfix(loss=f"{loss.item():.3f}", val_mm=f"{mpjpe:.1f}")
                if mpjpe < best:
                    best = mpjpe
                    paths.atomic_write(best_path, lambda t: torch.save({"net": net.state_dict(), "config": asdict(mcfg),
                                                                        "val_mpjpe_mm": mpjpe, "step": step}, t))
                paths.atomic_write(state_path, lambda t: torch.save({"net": net.state_dict(), "opt": opt.state_dict(),
                                                                     "step": step, "best": best, "history": history}, t))
                paths.atomic_write(curve_path, lambda t: Path(t).write_text(json.dumps(
                    {"config": asdict(cfg), "model": asdict(mcfg), "history": history}, indent=1)))
            if step >= cfg.steps:
                break
    bar.close()
    return {"best_val_mpjpe_mm": best, "steps": step, "history": history}
