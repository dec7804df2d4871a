"""Training of the camera-aware lifter (``recon smplr train-lifter``) on unlimited generated data.

Each batch draws J+ of SMPLR's generated 3D set (mocap train-split poses x shapes x view
rotations, ``recon.smplr.data``) and places them in a random camera:

* half the batches like the synthetic benchmarks (focal 300-700 px for a 256 px square image,
  the body 55-90 % of the image height, within 8 % of the centre);
* half wide: 4:3, 3:4, 16:9, 9:16 or square frames, focal 0.6-3 x the long side, the body
  25-100 % of the image height, its centre anywhere in the middle 70 % of the width and
  25-85 % of the height, so people are small, off-centre and cut by the frame.

Points outside the frame are masked (the lifter never reads them). 2D noise: a residual field
measured on a real keypoint source (MediaPipe + adapter on renders no model saw: the
``residuals`` file, eval/collect_sources.py), scaled by the person's box height and by a random
factor in [0, 1.5] (15 % of the samples clean); without that file, Gaussian noise of 2 % of the
box height per point (``CameraConfig``).
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from recon import camera, paths
from recon.body import default_body, skeleton
from recon.errors import ReconError
from recon.smplr.data import load_or_generate
from recon.smplr.lifter import WEIGHTS, Lifter, LifterConfig, LiftInput, prepare
from recon.training import Schedule, Trainer

STORE_DTYPE = torch.float16  # moves the J+ by float noise only (the lifter's model card)


@dataclass
class CameraConfig:
    bench_share: float = 0.5
    bench_focal: tuple[float, float] = (300 / 256, 700 / 256)  # x image side
    bench_fill: tuple[float, float] = (0.55, 0.9)
    bench_shift: float = 0.08
    wide_focal: tuple[float, float] = (0.6, 3.0)  # x long side, log-uniform
    wide_fill: tuple[float, float] = (0.25, 1.0)
    aspects: tuple[float, ...] = (1.0, 4 / 3, 3 / 4, 16 / 9, 9 / 16)  # width / height
    noise_scale: tuple[float, float] = (0.0, 1.5)  # x the residual field of the keypoint source
    clean_share: float = 0.15  # batches' samples without any 2D noise
    drop_prob: float = 0.03  # seen points masked at random (occlusions the source flags)
    gaussian_box: float = 0.02  # fallback noise (no residual bank): sigma / box height


@dataclass
class LifterTrainConfig:
    train_size: int = 400_000
    val_size: int = 8_192
    steps: int = 30_000
    batch: int = 256
    lr: float = 1e-3
    depth_weight: float = 0.1  # |log depth error| against metres of J+ error
    eval_every: int = 1000
    seed: int = 0
    init: str = ""  # continue from these lifter weights (a warm restart of the schedule)
    camera: CameraConfig = field(default_factory=CameraConfig)


def residual_bank(path: Path | None) -> torch.Tensor | None:
    """(N, 42, 2) residual fields of a keypoint source in units of the person's box height (and
    their mirror images), from an eval/collect_sources.py file; None without one."""
    if path is None:
        return None
    z = np.load(path)
    found = z["found"]
    gt = z["gt_points2d"][found]
    res = (z["points2d"][found] - gt) / box_height(gt)[:, None, None]
    mirror = res[:, list(skeleton.POINT_MIRROR)] * np.array([-1.0, 1.0])
    return torch.tensor(np.concatenate([res, mirror]), dtype=torch.float32)


def box_height(uv):
    """Height (px, at least 1) of the box around 2D points (..., P, 2); numpy or torch in, same out."""
    return np.maximum(uv[..., 1].max(-1) - uv[..., 1].min(-1), 1.0) if isinstance(uv, np.ndarray) else \
        (uv[..., 1].amax(-1) - uv[..., 1].amin(-1)).clamp_min(1.0)


def _uniform(n, lo, hi, gen):
    return lo + (hi - lo) * torch.rand(n, generator=gen)


def place_in_cameras(points_view: torch.Tensor, cfg: CameraConfig, gen: torch.Generator,
                     bank: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """J+ in the view frame (B, 42, 3) -> a random camera each: noisy pixels (B, 42, 2), K
    (B, 3, 3), visibility (B, 42), clean pixels, and the camera-frame J+ (B, 42, 3)."""
    b = points_view.shape[0]
    p = camera.to_opencv(points_view - points_view[:, :1])
    extent = (p[..., 1].amax(1) - p[..., 1].amin(1)) * 1.15  # J+ span -> head top to soles, roughly
    bench = torch.rand(b, generator=gen) < cfg.bench_share
    aspect = torch.tensor(cfg.aspects)[torch.randint(len(cfg.aspects), (b,), generator=gen)]
    aspect = torch.where(bench, torch.ones(b), aspect)
    w = torch.where(aspect >= 1, torch.full((b,), 1000.0), 1000.0 * aspect)
    h = w / aspect
    long = torch.maximum(w, h)
    lf, hf = math.log(cfg.wide_focal[0]), math.log(cfg.wide_focal[1])
    f_wide = torch.exp(_uniform(b, lf, hf, gen)) * long
    f = torch.where(bench, _uniform(b, *cfg.bench_focal, gen) * long, f_wide)
    fill = torch.where(bench, _uniform(b, *cfg.bench_fill, gen), _uniform(b, *cfg.wide_fill, gen))
    # where the body's middle lands: near the centre (bench) or anywhere central (wide)
    cu = torch.where(bench, 0.5 + _uniform(b, -cfg.bench_shift, cfg.bench_shift, gen), _uniform(b, 0.15, 0.85, gen))
    cv = torch.where(bench, 0.5 + _uniform(b, -cfg.bench_shift, cfg.bench_shift, gen), _uniform(b, 0.25, 0.85, gen))
    dist = f * extent / (fill * h)
    k = torch.zeros(b, 3, 3)
    k[:, 0, 0], k[:, 1, 1], k[:, 0, 2], k[:, 1, 2], k[:, 2, 2] = f, f, w / 2, h / 2, 1.0
    centre = p.mean(1)  # the J+ centroid goes to (cu, cv) at depth dist
    t = torch.stack([(cu * w - w / 2) * dist / f, (cv * h - h / 2) * dist / f, dist], 1) - centre
    cam = p + t[:, None]
    cam = torch.cat([cam[..., :2], cam[..., 2:].clamp_min(0.2)], -1)
    uv = camera.project(cam, k)
    hbox = box_height(uv)
    if bank is not None:
        field_ = bank[torch.randint(len(bank), (b,), generator=gen)]
    else:
        field_ = torch.randn(b, skeleton.NUM_POINTS, 2, generator=gen) * cfg.gaussian_box
    scale = _uniform(b, *cfg.noise_scale, gen) * (torch.rand(b, generator=gen) >= cfg.clean_share)
    noisy = uv + field_ * (scale * hbox)[:, None, None]
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < w[:, None]) & (uv[..., 1] >= 0) & (uv[..., 1] < h[:, None])
    vis = inside & (torch.rand(b, skeleton.NUM_POINTS, generator=gen) >= cfg.drop_prob)
    vis[:, 0] = True  # the pelvis ray anchors the virtual camera (guessed when cut, as a source would)
    return {"uv": noisy, "K": k, "visible": vis, "uv_clean": uv, "points": cam}


def targets(inp: LiftInput, cam: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Camera-frame J+ -> (root-relative J+ in the virtual camera, log(pelvis distance x size))."""
    rel = (cam - cam[:, :1]) @ inp.rotation.transpose(-1, -2)
    return rel, (cam[:, 0].norm(dim=-1) * inp.size).log()


def loss_terms(model: Lifter, batch: dict, depth_weight: float) -> tuple[torch.Tensor, dict]:
    inp = prepare(batch["uv"], batch["K"], batch["visible"])
    rel, log_zs = targets(inp, batch["points"])
    pred, pred_zs = model.raw(inp)
    mpjpe = (pred - rel).norm(dim=-1).mean()
    depth = (pred_zs - log_zs).abs().mean()
    return mpjpe + depth_weight * depth, {"mpjpe_m": mpjpe, "log_depth": depth}


def train(out: Path = WEIGHTS, cfg: LifterTrainConfig | None = None, model_cfg: LifterConfig | None = None,
          residuals: Path | None = None, run_dir: Path | None = None, progress: bool = True) -> dict:
    cfg, model_cfg = cfg or LifterTrainConfig(), model_cfg or LifterConfig()
    run_dir = Path(run_dir or paths.cache_dir() / "runs" / "lifter")
    body = default_body()
    data = load_or_generate(body, "train", cfg.train_size, cfg.seed, 8.0)["points"]
    val_points = load_or_generate(body, "val", cfg.val_size, cfg.seed + 100, 0.0)["points"]
    bank = residual_bank(residuals)
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    vgen = torch.Generator().manual_seed(1234)
    val = place_in_cameras(val_points, cfg.camera, vgen, bank)
    model = Lifter(model_cfg)
    if cfg.init:
        start = Lifter.load(cfg.init)
        if start.cfg != model_cfg:
            raise ReconError(f"{cfg.init} is a {start.cfg} lifter; asked for {model_cfg}")
        model.load_state_dict(start.state_dict())
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=1e-4)
    config = {"train": asdict(cfg), "model": asdict(model_cfg), "residuals": str(residuals) if residuals else None}
    trainer = Trainer({"lifter": model}, opt, cfg.steps, schedule=Schedule(floor=0.01), eval_every=cfg.eval_every,
                      out_dir=run_dir, select="val_mpjpe_mm", generators=[gen], config=config, desc="lifter",
                      progress=progress)

    def batches():
        while True:
            idx = torch.randint(0, len(data), (cfg.batch,), generator=gen)
            yield place_in_cameras(data[idx], cfg.camera, gen, bank)

    def step(batch):
        model.train()
        return loss_terms(model, batch, cfg.depth_weight)

    @torch.no_grad()
    def validate() -> dict:
        model.eval()
        tot, dep = 0.0, 0.0
        for i in range(0, len(val_points), 2048):
            part = {k: v[i:i + 2048] for k, v in val.items()}
            _, terms = loss_terms(model, part, cfg.depth_weight)
            tot += float(terms["mpjpe_m"]) * len(part["uv"])
            dep += float(terms["log_depth"]) * len(part["uv"])
        return {"val_mpjpe_mm": 1000 * tot / len(val_points), "val_log_depth": dep / len(val_points)}

    log = trainer.fit(batches(), step, validate)
    trainer.load_best()
    meta = config | {"best_val_mpjpe_mm": log["best"], "train_seconds": log["seconds"], "curve": log["history"]}
    if cfg.init:  # continued: keep the starting weights' record
        meta["init_record"] = json.loads(paths.load_checkpoint(cfg.init, "recon smplr train-lifter")["meta_json"])
    state = paths.cast_floats(model.state_dict(), STORE_DTYPE)
    paths.atomic_write(Path(out), lambda t: torch.save({"cfg": asdict(model_cfg), "state": state,
                                                        "meta_json": json.dumps(meta)}, t))
    return meta
