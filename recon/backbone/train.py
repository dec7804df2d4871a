"""Train the volumetric stacked hourglass (``recon backbone train``).

Data: either ``recon synth`` shard folders, or ``--online``: SURREAL-like samples rendered on
the fly by the data-loader workers (``recon.synth.scene``; each worker draws its own pose and
shape pools, so W workers see W x 4,096 poses). Each image is cropped with the thesis' metric
2.5 m crop around the mean joint (scale/centre jittered), resized to the network input, and
augmented (colour, horizontal flip with the left/right point map, in-plane rotation). Loss:
softmax cross-entropy on every stack's volumes (thesis 2.4.1) against trilinear soft targets,
plus an L1 term on the soft-argmax coordinates (integral regression). Validation: MPJPE of the
decoded joints (pelvis-aligned) on the first images of synth-val, ground-truth crop as in the
thesis protocol; online runs render exactly those images (same generator, split and seed).
Checkpoints are resumable; the learning curve is written as JSON next to them.

End-to-end fine-tuning (thesis 2.4.5, ``--init <weights> --smplr-weight w``): the trained DAE and
SMPLR (Omega, Psi, body model), frozen, sit on the decoded J+ of the last stack, and their L1
errors (metres) against the ground truth are added, times ``w``, to the heatmap losses; low
learning rate (thesis: 1e-4). Model selection then follows the MPJPE of the whole chain.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, IterableDataset, get_worker_info

from recon import paths
from recon.backbone.crop import Crop, grid_to_camera
from recon.backbone.hourglass import SIZES, HourglassConfig, StackedHourglass
from recon.backbone.volumetric import soft_argmax_3d, volumetric_ce
from recon.body import skeleton
from recon.metrics import per_point_error
from recon.synth.dataset import BENCHMARKS, SynthDataset


@dataclass
class BackboneTrainConfig:
    size: str = "base"  # key of hourglass.SIZES
    batch: int = 16
    lr: float = 1e-3
    steps: int = 20000
    minutes: float = 0.0  # wall-clock budget (0: none); the cosine schedule follows steps or time, whichever is further
    run_minutes: float = 0.0  # stop this invocation (checkpointed) after this long; a re-run resumes
    eval_every: int = 500
    val_images: int = 256
    workers: int = 2
    augment: bool = True
    repeats: int = 1  # online data: augmented crops per rendered sample
    l1_weight: float = 10.0  # on grid coordinates in [0, 1] (x 2.5 m: 1 voxel of 32 = 0.3 of loss)
    seed: int = 0
    model: dict = field(default_factory=dict)  # overrides of HourglassConfig
    init: str = ""  # start from these weights (e.g. the shipped ones; its architecture wins over size/model)
    smplr_weight: float = 0.0  # > 0: end-to-end through the frozen DAE + SMPLR (see module doc)
    imagenet: bool = False  # start the stem from ImageNet weights (needs model={"stem": "efficientnet-lite0"})


def make_crop(s: dict, size: int, augment: bool, rng: np.random.Generator):
    """One sample -> (image (3,S,S) float tensor in [0,1], grid targets (42,3), crop vector, K, camera points)."""
    pts = s["points3d"].astype(np.float64)
    centre = pts[:24].mean(0)
    extent = 2.5
    if augment:
        centre = centre + rng.normal(0, 0.05, 3) * [1, 1, 0]
        extent *= rng.uniform(0.9, 1.1)
    crop = Crop.around(centre, s["K"].astype(np.float64), extent)
    img = crop.image(s["rgb"], size).astype(np.float32) / 255.0
    grid = crop.to_grid(pts)
    if augment:
        if rng.random() < 0.5:  # flip: mirror x, swap left/right points
            img = img[:, ::-1]
            grid = grid[list(skeleton.POINT_MIRROR)]
            grid[:, 0] = 1.0 - grid[:, 0]
        ang = rng.normal(0, 15)
        if abs(ang) > 1:
            m = cv2.getRotationMatrix2D((size / 2, size / 2), ang, 1.0)
            img = cv2.warpAffine(img, m, (size, size), borderMode=cv2.BORDER_CONSTANT)
            xy = grid[:, :2] * size  # the same affine map moves the targets
            grid[:, :2] = (xy @ m[:, :2].T + m[:, 2]) / size
        img = np.clip(img * rng.uniform(0.7, 1.3, 3) + rng.normal(0, 0.03), 0, 1)
    crop_vec = np.array([crop.u0, crop.v0, crop.side, crop.zc, crop.extent], np.float64)
    return (torch.from_numpy(np.ascontiguousarray(img.transpose(2, 0, 1))).float(),
            torch.from_numpy(grid).float(), torch.from_numpy(crop_vec), torch.from_numpy(s["K"].astype(np.float64)),
            torch.from_numpy(pts))


class CropDataset(Dataset):
    """Crops of stored ``recon synth`` samples."""

    def __init__(self, roots: list[Path], input_size: int, augment: bool, seed: int = 0):
        self.sets = [SynthDataset(r) for r in roots]
        self.index = [(i, j) for i, s in enumerate(self.sets) for j in range(len(s))]
        self.size, self.augment, self.seed = input_size, augment, seed

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, n: int):
        i, j = self.index[n]
        rng = np.random.default_rng([self.seed, n, int(time.time_ns() % 1_000_000) if self.augment else 0])
        return make_crop(self.sets[i][j], self.size, self.augment, rng)


def _scene_sampler(split: str, seed: int):
    import recon.body
    from recon.synth.scene import SceneSampler

    torch.set_num_threads(1)  # many workers: one thread each, or OpenCV/BLAS thread pools oversubscribe the CPU
    cv2.setNumThreads(1)
    return SceneSampler(recon.body.create(), split, seed)


class RenderedCrops(Dataset):
    """Samples 0..n-1 of a (split, seed) stream rendered on demand: with a benchmark's split and
    seed these are that benchmark's images."""

    def __init__(self, split: str, seed: int, n: int, input_size: int):
        self.split, self.seed, self.n, self.size = split, seed, n, input_size
        self.sampler = None

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int):
        if self.sampler is None:  # per worker process: its own GL context
            self.sampler = _scene_sampler(self.split, self.seed)
        return make_crop(self.sampler.sample(i), self.size, False, np.random.default_rng(0))


class OnlineCrops(IterableDataset):
    """Endless augmented training crops rendered by each data-loader worker; worker w uses the
    stream (train, seed * 1000 + w) from sample ``start`` on. Each render gives ``repeats``
    differently augmented crops, mixed through a shuffle buffer (rendering is the bottleneck)."""

    def __init__(self, input_size: int, seed: int = 0, start: int = 0, repeats: int = 1, buffer: int = 64):
        self.size, self.seed, self.start, self.repeats, self.buffer = input_size, seed, start, repeats, buffer

    def __iter__(self):
        info = get_worker_info()
        w = info.id if info is not None else 0
        sampler = _scene_sampler("train", self.seed * 1000 + w)
        rng = np.random.default_rng([self.seed, w, self.start, 7])
        pool, i = [], self.start
        while True:
            s = sampler.sample(i)
            pool += [make_crop(s, self.size, True, rng) for _ in range(self.repeats)]
            i += 1
            while len(pool) > (self.buffer if self.repeats > 1 else 0):
                yield pool.pop(int(rng.integers(len(pool))))


class EndToEnd(torch.nn.Module):
    """The frozen DAE + SMPLR on top of the backbone (thesis 2.4.5). Targets are the ground-truth
    grid coordinates decoded with the same crop, so flips and in-plane rotations of the crop stay
    consistent with the image. Points go to SMPLR's frame (OpenCV axes times (1, -1, -1))."""

    def __init__(self, device: str = "cpu"):
        super().__init__()
        from recon.pipeline import OPENCV_TO_VIEW
        from recon.smplr import SMPLR

        self.smplr = SMPLR.load().to(device).eval().requires_grad_(False)
        self.register_buffer("flip", torch.as_tensor(OPENCV_TO_VIEW, dtype=torch.float32, device=device),
                             persistent=False)

    def chain(self, grid: torch.Tensor, crop_vec: torch.Tensor, k: torch.Tensor):
        """Grid J+ (B, 42, 3) -> (DAE output, body-model J+), both (B, 42, 3) in SMPLR's frame."""
        pts = grid_to_camera(grid, crop_vec.float(), k.float()) * self.flip
        out = self.smplr(pts, points_only=True)
        return out.points_in, out.body.points

    def forward(self, grid: torch.Tensor, grid_gt: torch.Tensor, crop_vec: torch.Tensor, k: torch.Tensor):
        target = grid_to_camera(grid_gt, crop_vec.float(), k.float()) * self.flip
        target = target - target[:, :1]
        dae, body = self.chain(grid, crop_vec, k)
        return (dae - dae[:, :1] - target).abs().mean() + (body - body[:, :1] - target).abs().mean()


def evaluate(net: StackedHourglass, batches, device: str, e2e: EndToEnd | None = None) -> float | tuple[float, float]:
    """Mean pelvis-aligned joint error (mm) of the last stack's soft-argmax; with ``e2e`` also that
    of the whole chain (backbone -> DAE -> SMPLR -> body model joints)."""
    net.eval()
    errs, chain = [], []
    with torch.no_grad(), torch.autocast(device_type=device.split(":")[0], dtype=torch.bfloat16,
                                         enabled=device.startswith("cuda")):
        for img, _, crop_vec, k, pts in batches:
            g = soft_argmax_3d(net(img.to(device))[-1][:, :skeleton.NUM_POINTS].float())
            if e2e is not None:
                with torch.autocast(device_type=device.split(":")[0], enabled=False):
                    body = e2e.chain(g, crop_vec.to(device), k.to(device))[1] * e2e.flip
                chain.append(per_point_error(body.double().cpu()[:, :24], pts[:, :24]))
            errs.append(per_point_error(grid_to_camera(g.double().cpu(), crop_vec, k)[:, :24], pts[:, :24]))
    net.train()
    mm = lambda e: float(torch.cat(e).mean() * 1000)  # noqa: E731
    return mm(errs) if e2e is None else (mm(errs), mm(chain))


def _loader(ds, batch: int, workers: int, device: str, shuffle: bool | None = None, drop_last: bool = False):
    kw = {"num_workers": workers, "pin_memory": device.startswith("cuda"), "drop_last": drop_last}
    if workers > 0:  # spawn: workers own GL contexts and must not inherit CUDA state
        kw.update(multiprocessing_context="spawn", persistent_workers=True, prefetch_factor=4)
    return DataLoader(ds, batch_size=batch, shuffle=shuffle, **kw)


def train(train_roots: list[Path] | None, val: Path | str, out_dir: Path,
          cfg: BackboneTrainConfig = BackboneTrainConfig(), device: str = "cpu") -> dict:
    """``train_roots=None`` renders training data online. ``val``: a synth folder, or a benchmark
    name rendered online (``"synth-val"``)."""
    from tqdm import tqdm

    torch.manual_seed(cfg.seed)
    init = paths.load_checkpoint(cfg.init, "recon backbone train") if cfg.init else None
    mcfg = HourglassConfig(**(init["config"] if init else {**asdict(SIZES[cfg.size]), **cfg.model}))
    cuda = device.startswith("cuda")
    net = StackedHourglass(mcfg, imagenet=cfg.imagenet and not init)
    if init:
        net.load_state_dict(init["net"])
    net = net.to(device).to(memory_format=torch.channels_last)
    e2e = EndToEnd(device) if cfg.smplr_weight > 0 else None
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    out_dir.mkdir(parents=True, exist_ok=True)
    # optimiser moments apart from the weights: each file stays small enough to move around
    state_path, opt_path = out_dir / "state.pt", out_dir / "optimizer.pt"
    best_path, curve_path = out_dir / "best.pt", out_dir / "curve.json"
    step, best, history, spent = 0, float("inf"), [], 0.0
    if state_path.exists():
        s = torch.load(state_path, map_location=device, weights_only=True)
        net.load_state_dict(s["net"])
        opt.load_state_dict(torch.load(opt_path, map_location=device, weights_only=True))
        step, best, history, spent = s["step"], s["best"], s["history"], s.get("seconds", 0.0)
    if train_roots is None:
        data = OnlineCrops(mcfg.input_size, cfg.seed, start=step * cfg.batch // max(cfg.workers, 1), repeats=cfg.repeats)
        loader = _loader(data, cfg.batch, cfg.workers, device)
    else:
        loader = _loader(CropDataset(train_roots, mcfg.input_size, cfg.augment, cfg.seed), cfg.batch, cfg.workers,
                         device, shuffle=True, drop_last=True)
    if isinstance(val, str) and val in BENCHMARKS:
        b = BENCHMARKS[val]
        vset = RenderedCrops(b["split"], b["seed"], min(cfg.val_images, b["n"]), mcfg.input_size)
        val_batches = list(_loader(vset, cfg.batch, min(cfg.workers, 8), "cpu"))
    else:
        vset = CropDataset([Path(val)], mcfg.input_size, False)
        vset.index = vset.index[:cfg.val_images]
        val_batches = list(DataLoader(vset, batch_size=cfg.batch, num_workers=0))

    def validate() -> tuple[float, dict]:
        """Selection metric (the backbone's MPJPE, or the whole chain's when end-to-end) + log."""
        if e2e is None:
            m = evaluate(net, val_batches, device)
            return m, {"val_mpjpe_mm": m}
        m, chain = evaluate(net, val_batches, device, e2e)
        return chain, {"val_mpjpe_mm": m, "val_chain_mpjpe_mm": chain}

    def save(tag: str, mpjpe: float, loss: float | None, metrics: dict):
        nonlocal best
        history.append({"step": step, "loss": loss, **metrics, "time_s": spent + time.time() - t0,
                        "lr": opt.param_groups[0]["lr"], "tag": tag})
        if mpjpe < best:
            best = mpjpe
            paths.atomic_write(best_path, lambda t: torch.save({"net": net.state_dict(), "config": asdict(mcfg),
                                                                "val_mpjpe_mm": metrics["val_mpjpe_mm"], "step": step,
                                                                "val_metrics": metrics}, t))
        paths.atomic_write(opt_path, lambda t: torch.save(opt.state_dict(), t))
        paths.atomic_write(state_path, lambda t: torch.save({"net": net.state_dict(), "step": step, "best": best, "history": history,
                                                             "seconds": spent + time.time() - t0}, t))
        paths.atomic_write(curve_path, lambda t: Path(t).write_text(json.dumps(
            {"config": asdict(cfg), "model": asdict(mcfg), "history": history}, indent=1)))

    bar = tqdm(total=cfg.steps, initial=step, desc="train backbone", unit="step", mininterval=10)
    t0 = time.time()
    done, loss = step >= cfg.steps, torch.zeros(())
    if init and step == 0:  # the starting point, for the curve and as the best so far
        m, metrics = validate()
        save("init", m, None, metrics)
    while not done:
        for img, grid, crop_vec, k, _ in loader:
            elapsed = spent + time.time() - t0
            frac = step / cfg.steps
            if cfg.minutes > 0:
                frac = max(frac, elapsed / (60 * cfg.minutes))
            for g in opt.param_groups:  # cosine decay to 2 % of the initial rate
                g["lr"] = cfg.lr * (0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * min(frac, 1.0))))
            img = img.to(device, non_blocking=True).to(memory_format=torch.channels_last)
            g = grid.to(device, non_blocking=True)
            with torch.autocast(device_type=device.split(":")[0], dtype=torch.bfloat16, enabled=cuda):
                outs = net(img)
            loss = 0.0
            for o in outs:
                o = o[:, :skeleton.NUM_POINTS].float()
                coords = soft_argmax_3d(o)
                loss = loss + volumetric_ce(o, g) + cfg.l1_weight * (coords - g).abs().mean()
            if e2e is not None:  # on the last stack's J+
                loss = loss + cfg.smplr_weight * e2e(coords, g, crop_vec.to(device), k.to(device))
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            step += 1
            bar.update(1)
            done = step >= cfg.steps or (cfg.minutes > 0 and elapsed >= 60 * cfg.minutes)
            done = done or (cfg.run_minutes > 0 and time.time() - t0 >= 60 * cfg.run_minutes)
            if step % cfg.eval_every == 0 or done:
                mpjpe, metrics = validate()
                save("eval", mpjpe, loss.item(), metrics)
                bar.set_postfix(loss=f"{loss.item():.3f}", val_mm=f"{mpjpe:.1f}")
            if done:
                break
    bar.close()
    return {"best_val_mpjpe_mm": best, "steps": step, "history": history}
