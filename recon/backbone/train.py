"""Train the volumetric stacked hourglass (``recon backbone train``) and export the result.

Data (``recon.backbone.crops``): either ``recon synth`` shard folders, or ``--online``:
SURREAL-like samples rendered on the fly by the data-loader workers, or by Ray actors on any
node of a cluster (``render_executor="ray"``) (``recon.synth.scene``; each worker draws its own
pose and shape pools, so W workers see W x 4,096 poses). Each image is cropped with the thesis' metric
2.5 m crop around the mean joint (scale/centre jittered) and resized to the network input; the
batch is then augmented on the training device (``CropAugmentation``: horizontal flip with the
left/right point map and in-plane rotation through kornia.augmentation, the targets moved with
the image; colour gains and offsets). Loss: softmax cross-entropy on every stack's volumes
(thesis 2.4.1) against trilinear soft targets, plus an L1 term on the soft-argmax coordinates
(integral regression). Validation: MPJPE of the decoded joints (pelvis-aligned) on the first
images of synth-val, ground-truth crop as in the thesis protocol; online runs render exactly
those images (same generator, split and seed). The loop is ``recon.training.Trainer``:
checkpoints are resumable and the learning curve is written as JSON next to them.

End-to-end fine-tuning (thesis 2.4.5, ``--init <weights> --smplr-weight w``): the trained DAE and
SMPLR (Omega, Psi, body model), frozen, sit on the decoded J+ of the last stack, and their L1
errors (metres) against the ground truth are added, times ``w``, to the heatmap losses; low
learning rate (thesis: 1e-4). Model selection then follows the MPJPE of the whole chain.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import kornia.augmentation as KA
import torch
from kornia.geometry.linalg import transform_points
from torch import nn
from torch.utils.data import DataLoader

from recon import camera, paths
from recon.backbone.calibrate import calibrated
from recon.backbone.crop import grid_to_camera
from recon.backbone.crops import CropDataset, OnlineCrops, RayCrops, RenderedCrops
from recon.backbone.hourglass import SIZES, HourglassConfig, StackedHourglass
from recon.backbone.model import WEIGHTS
from recon.backbone.volumetric import soft_argmax_3d, volumetric_ce
from recon.body import skeleton
from recon.errors import ReconError
from recon.metrics import per_point_error
from recon.smplr import SMPLR
from recon.synth.dataset import BENCHMARKS
from recon.training import Schedule, Trainer

LR_FLOOR = 0.02  # the cosine schedule decays to this fraction of the peak rate
# settings a resumed run may change: longer runs, other machines, other validation cadence
RESUMABLE_CHANGES = ("steps", "run_minutes", "workers", "eval_every", "render_executor", "ray_address")


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
    repeats: int = 1  # online data: crops per rendered sample (each jittered and augmented on its own)
    l1_weight: float = 10.0  # on grid coordinates in [0, 1] (x 2.5 m: 1 voxel of 32 = 0.3 of loss)
    seed: int = 0
    model: dict = field(default_factory=dict)  # overrides of HourglassConfig
    init: str = ""  # start from these weights (e.g. the shipped ones; its architecture wins over size/model)
    smplr_weight: float = 0.0  # > 0: end-to-end through the frozen DAE + SMPLR (see module doc)
    imagenet: bool = False  # start the stem from ImageNet weights (needs model={"stem": "efficientnet-lite0"})
    render_executor: str = "local"  # online data: "local" loader processes, or "ray" actors on any node
    ray_address: str | None = None  # render_executor "ray": the cluster (default $RAY_ADDRESS, else a local Ray)


class CropAugmentation(nn.Module):
    """Batch augmentation on the training device: a horizontal flip (p = 0.5; the left/right
    points swapped through the J+ mirror map), an in-plane rotation of ~ N(0, ``rotation_deg``)
    (none under 1 degree) and colour: per-channel gains in ``gain`` and one offset
    ~ N(0, ``offset``), clipped to [0, 1]. The geometric part is kornia.augmentation's; grid
    targets move with the image through each augmentation's transform matrix (pixel-index
    coordinates: a grid value g is the pixel g S - 0.5)."""

    def __init__(self, rotation_deg: float = 15.0, gain: tuple[float, float] = (0.7, 1.3), offset: float = 0.03):
        super().__init__()
        self.flip = KA.RandomHorizontalFlip(p=0.5)
        self.rotate = KA.RandomRotation(degrees=180.0, p=1.0)
        self.rotation_deg, self.gain, self.offset = rotation_deg, gain, offset
        self.register_buffer("mirror", torch.tensor(skeleton.POINT_MIRROR), persistent=False)

    def forward(self, img: torch.Tensor, grid: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b, size = img.shape[0], img.shape[-1]
        params = self.flip.forward_parameters(img.shape)
        img = self.flip(img, params=params)
        flipped = params["batch_prob"].to(grid.device) > 0.5
        grid = torch.where(flipped[:, None, None], grid[:, self.mirror], grid)  # left <-> right
        xy = transform_points(self.flip.transform_matrix.to(grid), grid[..., :2] * size - 0.5)
        params = self.rotate.forward_parameters(img.shape)
        deg = torch.randn(b) * self.rotation_deg
        params["degrees"] = torch.where(deg.abs() > 1.0, deg, torch.zeros_like(deg))
        img = self.rotate(img, params=params)
        xy = transform_points(self.rotate.transform_matrix.to(grid), xy)
        grid = torch.cat([(xy + 0.5) / size, grid[..., 2:]], -1)
        lo, hi = self.gain
        gains = lo + (hi - lo) * torch.rand(b, 3, 1, 1)
        offsets = self.offset * torch.randn(b, 1, 1, 1)
        return (img * gains.to(img) + offsets.to(img)).clamp(0.0, 1.0), grid


class EndToEnd(nn.Module):
    """The frozen DAE + SMPLR on top of the backbone (thesis 2.4.5). Targets are the ground-truth
    grid coordinates decoded with the same crop, so flips and in-plane rotations of the crop stay
    consistent with the image. Points go to SMPLR's view frame (``recon.camera.to_view``)."""

    def __init__(self, device: str = "cpu"):
        super().__init__()
        self.smplr = SMPLR.load().to(device).eval().requires_grad_(False)

    def chain(self, grid: torch.Tensor, crop_vec: torch.Tensor, k: torch.Tensor):
        """Grid J+ (B, 42, 3) -> (DAE output, body-model J+), both (B, 42, 3) in SMPLR's frame."""
        pts = camera.to_view(grid_to_camera(grid, crop_vec.float(), k.float()))
        out = self.smplr(pts, points_only=True)
        return out.points_in, out.body.points

    def forward(self, grid: torch.Tensor, grid_gt: torch.Tensor, crop_vec: torch.Tensor, k: torch.Tensor):
        target = camera.to_view(grid_to_camera(grid_gt, crop_vec.float(), k.float()))
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
                    body = camera.to_opencv(e2e.chain(g, crop_vec.to(device), k.to(device))[1])
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


def _endless(loader):
    while True:
        yield from loader


def train(train_roots: list[Path] | None, val: Path | str, out_dir: Path, cfg: BackboneTrainConfig | None = None,
          device: str = "cpu", progress: bool = True) -> dict:
    """``train_roots=None`` renders training data online. ``val``: a synth folder, or a benchmark
    name rendered online (``"synth-val"``). Resumes from ``out_dir`` if it holds a run."""
    cfg = cfg or BackboneTrainConfig()
    if cfg.imagenet and cfg.model.get("stem", "hourglass") == "hourglass" and not cfg.init:
        raise ReconError("--imagenet initialises the EfficientNet stem: add --stem efficientnet-lite0")
    torch.manual_seed(cfg.seed)
    init = paths.load_checkpoint(cfg.init, "recon backbone train") if cfg.init else None
    mcfg = HourglassConfig(**(init["config"] if init else {**asdict(SIZES[cfg.size]), **cfg.model}))
    cuda = device.startswith("cuda")
    net = StackedHourglass(mcfg, imagenet=cfg.imagenet and not init)
    if init:
        net.load_state_dict(init["net"])
    net = net.to(device).to(memory_format=torch.channels_last)
    augment = CropAugmentation().to(device) if cfg.augment else None
    e2e = EndToEnd(device) if cfg.smplr_weight > 0 else None
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    trainer = Trainer({"net": net}, opt, cfg.steps, schedule=Schedule(floor=LR_FLOOR), eval_every=cfg.eval_every,
                      out_dir=out_dir, select="val_chain_mpjpe_mm" if e2e else "val_mpjpe_mm", minutes=cfg.minutes,
                      run_minutes=cfg.run_minutes, desc="train backbone", config=asdict(cfg),
                      identity={k: v for k, v in asdict(cfg).items() if k not in RESUMABLE_CHANGES},
                      extra={"config": asdict(mcfg)}, progress=progress)
    if train_roots is None and cfg.render_executor == "ray":
        loader = RayCrops(mcfg.input_size, cfg.batch, max(cfg.workers, 1), cfg.seed,
                          start=trainer.step * cfg.batch // max(cfg.workers, 1), repeats=cfg.repeats,
                          address=cfg.ray_address)
    elif train_roots is None:
        data = OnlineCrops(mcfg.input_size, cfg.seed, start=trainer.step * cfg.batch // max(cfg.workers, 1),
                           repeats=cfg.repeats)
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

    def validate() -> dict:
        if e2e is None:
            return {"val_mpjpe_mm": evaluate(net, val_batches, device)}
        m, chain = evaluate(net, val_batches, device, e2e)
        return {"val_mpjpe_mm": m, "val_chain_mpjpe_mm": chain}

    def step(batch):
        img, grid, crop_vec, k, _ = batch
        img = img.to(device, non_blocking=True)
        g = grid.to(device, non_blocking=True)
        if augment is not None:
            img, g = augment(img, g)
        with torch.autocast(device_type=device.split(":")[0], dtype=torch.bfloat16, enabled=cuda):
            outs = net(img.contiguous(memory_format=torch.channels_last))
        loss = 0.0
        for o in outs:
            o = o[:, :skeleton.NUM_POINTS].float()
            coords = soft_argmax_3d(o)
            loss = loss + volumetric_ce(o, g) + cfg.l1_weight * (coords - g).abs().mean()
        if e2e is not None:  # on the last stack's J+
            loss = loss + cfg.smplr_weight * e2e(coords, g, crop_vec.to(device), k.to(device))
        return loss

    if init and trainer.step == 0 and not trainer.history:  # the starting point, for the curve and as the best so far
        trainer.validate_now(validate, tag="init")
    batches = _endless(loader)
    try:
        log = trainer.fit(batches, step, validate)
    finally:
        batches.close()  # Ray's rendering actors stop with it
    return {"best_val_mpjpe_mm": log["best"], "steps": log["steps"], "history": log["history"],
            "seconds": log["seconds"]}


def export(run_dir: Path, out: Path = WEIGHTS, calibrate_on: int = 300) -> Path:
    """``recon backbone export``: shipped weights from a training run: its best checkpoint, the
    training config and curve, and the crop-depth factors calibrated on the first
    ``calibrate_on`` synth-val images (``recon.backbone.search``)."""
    run_dir = Path(run_dir)
    best = paths.load_checkpoint(run_dir / "best.pt", "recon backbone train")
    curve = json.loads((run_dir / "curve.json").read_text())
    ck = {"net": best["net"], "config": best["config"], "step": best["step"],
          "val_mpjpe_mm": best["metrics"]["val_mpjpe_mm"], "train_config": curve["config"],
          "curve_json": json.dumps(curve["history"])}
    if curve["config"].get("init"):  # fine-tuned: keep the starting weights' provenance
        start = paths.load_checkpoint(curve["config"]["init"], "recon backbone train")
        ck["fine_tuned_from"] = {k: start[k] for k in ("train_config", "step", "val_mpjpe_mm", "fine_tuned_from")
                                 if k in start}
    ck = calibrated(ck, calibrate_on)
    paths.atomic_write(out, lambda t: torch.save(ck, t))
    return out
