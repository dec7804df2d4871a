"""Training data and training of ``recon.shape.ShapeHead``.

Two kinds of crops, both with the truth's phenotypes:
- ``render_crops``: the renderer's visible-person mask around the true J+ 2D, the crop box
  jittered; ``augment`` then makes them look like MediaPipe's masks (edges smoothed, a pixel
  grown or eaten, an occluder merged in).
- ``mediapipe_crops``: MediaPipe's own mask around its J+ 2D, from the same keypoint source as
  ``recon run``: what the head reads at test time. Slow (a MediaPipe call per image), so used
  for a share of each batch and for selection.
"""
from __future__ import annotations

import itertools
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.nn import functional as F
from tqdm import tqdm

from recon import paths
from recon.body import default_body
from recon.keypoints import make_source
from recon.shape.head import PHENOTYPES, WEIGHTS, ShapeHead, ShapeHeadConfig, crop_box, crop_mask
from recon.synth.dataset import SynthDataset
from recon.training import Schedule, Trainer

STORE_DTYPE = torch.float16


def render_crops(root: Path, out: Path, n: int | None = None, size: int = 112, seed: int = 0,
                 jitter: bool = True) -> Path:
    """Crops of the rendered visible-person masks of a synth folder (first ``n`` images) into
    ``out`` (npz: masks (N, size, size) uint8, shape (N, 6)); kept if present."""
    if out.exists():
        return out
    ds = SynthDataset(root, keys=("mask", "points2d", "shape"))
    rng = np.random.default_rng(seed)
    masks, shapes = [], []
    for i in tqdm(range(min(n or len(ds), len(ds))), desc=f"crops {root.name}", unit="img"):
        s = ds[i]
        box = crop_box(s["points2d"], 1.0)
        if jitter:  # the detected J+ extent differs from the truth's: scale and shift the box
            box[2] *= rng.uniform(1.1, 1.4)
            box[:2] += rng.normal(0.0, 0.04, 2) * box[2]
        else:
            box[2] *= ShapeHeadConfig.margin
        masks.append(crop_mask(s["mask"], box, size))
        shapes.append(s["shape"])
    paths.atomic_write(out, lambda t: np.savez(t, masks=np.stack(masks), shape=np.stack(shapes)))
    return out


def mediapipe_crops(root: Path, out: Path, start: int = 0, n: int | None = None, size: int = 112) -> Path:
    """MediaPipe's masks (``recon run``'s source: heavy, retries, guard) cropped as at test time,
    for images ``start`` .. ``start + n`` of a synth folder, into ``out`` (npz: masks, shape,
    index); images where it finds nobody or gives no mask are left out. Kept if present."""
    if out.exists():
        return out
    ds = SynthDataset(root, keys=("rgb", "K", "shape"))
    source = make_source("mediapipe", default_body())
    masks, shapes, index = [], [], []
    for i in tqdm(range(start, min(start + (n or len(ds)), len(ds))), desc=f"mediapipe {root.name}", unit="img"):
        s = ds[i]
        kp = source(s["rgb"], s["K"].astype(np.float64))
        if kp is None or kp.mask is None:
            continue
        masks.append(crop_mask(kp.mask, crop_box(kp.points2d, ShapeHeadConfig.margin), size))
        shapes.append(s["shape"])
        index.append(i)
    paths.atomic_write(out, lambda t: np.savez(t, masks=np.stack(masks), shape=np.stack(shapes),
                                               index=np.array(index)))
    return out


def augment(masks: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Rendered masks made to look like MediaPipe's: a pixel grown or eaten, edges smoothed
    (thin limbs vanish, gaps close), and now and then an occluder merged into the person."""
    out = masks.copy()
    kernel = np.ones((3, 3), np.uint8)
    for m in out:
        r = rng.random()
        if r < 0.3:
            cv2.dilate(m, kernel, dst=m)
        elif r < 0.5:
            cv2.erode(m, kernel, dst=m)
        if rng.random() < 0.5:
            m[...] = (cv2.GaussianBlur(m, (0, 0), rng.uniform(0.8, 2.0)) > 127) * 255
        if rng.random() < 0.25:
            ys, xs = np.nonzero(m > 127)
            if len(ys):
                k = rng.integers(len(ys))
                axes = (int(rng.integers(5, 20)), int(rng.integers(5, 20)))
                cv2.ellipse(m, (int(xs[k]), int(ys[k])), axes, float(rng.uniform(0, 180)), 0, 360, 255, -1)
    return out


def loss_terms(raw: torch.Tensor, shape: torch.Tensor, weight: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(gender cross-entropy, smooth-L1 of the other phenotypes) for raw outputs and true shapes.
    Gender: female or not (the true gender above 0.5), each sample weighted by how far its gender lies
    from 0.5 (1 for the classic renders' 0 and 1; an any-shape body at 0.5 is neither and says
    nothing), so the head learns a probability that stays near 0.5 where an outline does not tell."""
    g = shape[:, 0].clamp(0.0, 1.0)
    w = (2.0 * g - 1.0).abs()
    ce = F.binary_cross_entropy_with_logits(raw[:, 0], (g > 0.5).float(), reduction="none")
    gender = (w * ce).sum() / w.sum().clamp_min(1e-6)
    return gender, weight * F.smooth_l1_loss(raw[:, 1:], shape[:, 1:], beta=0.1)


def metrics(model: ShapeHead, masks: np.ndarray, shape: np.ndarray) -> dict[str, float]:
    """Gender right (on the people whose true gender is < 0.2 or > 0.8), per-phenotype mean |error|
    and Pearson r of a head on crops (``ShapeHead.read``)."""
    p = np.concatenate([model.read(masks[i:i + 256], temperature=1.0) for i in range(0, len(masks), 256)])
    sure = np.abs(shape[:, 0] - 0.5) > 0.3
    res = {"gender_acc": float(((p[sure, 0] > 0.5) == (shape[sure, 0] > 0.5)).mean()) if sure.any() else None}
    for j, name in enumerate(PHENOTYPES):
        res[f"{name}_mae"] = float(np.abs(p[:, j] - shape[:, j]).mean())
        if j and shape[:, j].std() > 0:
            res[f"{name}_r"] = float(np.corrcoef(p[:, j], shape[:, j])[0, 1])
    return res


@dataclass
class ShapeTrainConfig:
    minutes: float = 40.0  # wall-clock budget: the schedule follows steps or time, whichever is further
    steps: int = 20000
    batch: int = 64
    lr: float = 2e-3
    phenotype_weight: float = 5.0  # against the gender cross-entropy
    mediapipe_share: float = 0.3  # share of batches drawn from MediaPipe's crops
    eval_every: int = 300
    seed: int = 0


def train(render: list[Path], mediapipe: list[Path], val: Path, out: Path = WEIGHTS,
          cfg: ShapeTrainConfig | None = None, model_cfg: ShapeHeadConfig | None = None,
          run_dir: Path | None = None, progress: bool = True) -> dict:
    """Train on render crops (augmented) and MediaPipe crops, select on MediaPipe's crops of
    ``val`` (lowest validation loss), write the weights with the training record inside."""
    cfg, model_cfg = cfg or ShapeTrainConfig(), model_cfg or ShapeHeadConfig()
    run_dir = Path(run_dir or paths.cache_dir() / "runs" / "shape-head")
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    rd = [np.load(p) for p in render]
    rm, rs = np.concatenate([d["masks"] for d in rd]), np.concatenate([d["shape"] for d in rd]).astype(np.float32)
    md = [np.load(p) for p in mediapipe]
    mm = np.concatenate([d["masks"] for d in md]) if md else None
    ms = np.concatenate([d["shape"] for d in md]).astype(np.float32) if md else None
    vd = np.load(val)
    vm, vs = vd["masks"], vd["shape"].astype(np.float32)
    model = ShapeHead(model_cfg)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=1e-4)
    config = {"train": asdict(cfg), "model": asdict(model_cfg), "render": [str(p) for p in render],
              "mediapipe": [str(p) for p in mediapipe], "val": str(val)}
    trainer = Trainer({"head": model}, opt, cfg.steps, schedule=Schedule(), eval_every=cfg.eval_every,
                      out_dir=run_dir, select="val_loss", minutes=cfg.minutes, generators=[rng], config=config,
                      desc="shape head", progress=progress)

    def step(_):
        model.train()
        if mm is not None and rng.random() < cfg.mediapipe_share:
            idx = rng.integers(0, len(mm), cfg.batch)
            m, s = mm[idx], ms[idx]
        else:
            idx = rng.integers(0, len(rm), cfg.batch)
            m, s = augment(rm[idx], rng), rs[idx]
        x = torch.from_numpy(m).float()[:, None] / 255.0
        if rng.random() < 0.5:
            x = x.flip(3)
        gender, pheno = loss_terms(model(x), torch.from_numpy(s), cfg.phenotype_weight)
        return gender + pheno, {"gender": gender.item(), "phenotypes": pheno.item()}

    def validate() -> dict:
        model.eval()
        with torch.no_grad():
            x = torch.from_numpy(vm).float()[:, None] / 255.0
            g, p = loss_terms(model(x), torch.from_numpy(vs), cfg.phenotype_weight)
        m = metrics(model, vm, vs)
        return {"val_loss": float(g + p), "val_gender_acc": m["gender_acc"], "val_weight_mae": m["weight_mae"]}

    log = trainer.fit(itertools.repeat(None), step, validate)  # step draws its own batch
    trainer.load_best()
    meta = config | {"train_render": int(len(rm)), "train_mediapipe": 0 if mm is None else int(len(mm)),
                     "val_samples": int(len(vm)), "best_val_loss": log["best"], "train_seconds": log["seconds"],
                     "val_metrics": metrics(model, vm, vs), "curve": log["history"]}
    model.save(out, meta, STORE_DTYPE)
    shutil.rmtree(run_dir, ignore_errors=True)
    return meta


def evaluate(model: ShapeHead, crops: Path) -> dict[str, float]:
    d = np.load(crops)
    return {"samples": int(len(d["masks"]))} | metrics(model, d["masks"], d["shape"].astype(np.float32))

