"""Training data and training of the MediaPipe -> J+ adapter (``recon keypoints collect``,
``recon keypoints train``).

Data: MediaPipe run over ``recon synth`` renders whose ground truth J+ is known, cached per
shard. Training: ``recon.training.Trainer`` (AdamW, one-cycle learning rate, best validation
MPJPE kept), left/right flips of every sample; the weights file holds the training record.
"""
from __future__ import annotations

import json
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from recon import camera, paths
from recon.body import skeleton
from recon.errors import MissingFile
from recon.keypoints.adapter import WEIGHTS, AdapterConfig, KeypointAdapter, assemble_features, normalise_2d
from recon.people.mediapipe import DEFAULT_MODEL, MP_MIRROR, NUM_MP, MediaPipePose, model_file
from recon.synth.dataset import SynthDataset
from recon.training import Schedule, Trainer, epoch_batches

STORE_DTYPE = torch.float32  # float16 would move published numbers: eval/results/weights-float16.md


def collect(root: Path, out: Path, shards: list[int] | None = None, truncate: float = 0.0,
            model: str = DEFAULT_MODEL) -> list[Path]:
    """Run MediaPipe over ``recon synth`` shards of ``root``; one npz per shard in ``out``
    (written atomically, skipped when present: resumable and splittable over processes).

    ``truncate``: fraction of images cut below a random height between the chest and the knees
    (deterministic per index), so the adapter also learns half-body photos, where the legs are
    out of the frame. Cutting rows keeps the intrinsics unchanged. ``model``: MediaPipe's landmark
    model (the adapter is trained on the outputs of the one it will read)."""
    if not model_file(model).is_file():  # training on another model's outputs would be silently wrong
        raise MissingFile(f"MediaPipe's {model} landmark model is not installed: scripts/setup.sh adds it")
    ds = SynthDataset(root)
    n_shards = -(-len(ds) // ds.shard_size)
    todo = [k for k in (shards if shards is not None else range(n_shards)) if not (out / f"mp-{k:05d}.npz").exists()]
    mp = MediaPipePose(model, segmentation=False)
    written = []
    for k in tqdm(todo, desc=f"mediapipe {root.name}", unit="shard"):
        rows = []
        for i in range(k * ds.shard_size, min((k + 1) * ds.shard_size, len(ds))):
            s = ds[i]
            rgb, cut = s["rgb"], rgb_rows(s, i, truncate)
            r = mp(np.ascontiguousarray(rgb[:cut]))
            rows.append((r, s | {"cut": cut}))
        found = np.array([r is not None for r, _ in rows])
        xy, world, vis = (np.zeros((len(rows), *shape), np.float32) for shape in ((NUM_MP, 2), (NUM_MP, 3), (NUM_MP,)))
        for i, (r, _) in enumerate(rows):
            if r is not None:
                xy[i], world[i], vis[i] = r.image_xy, r.world, r.visibility
        arrays = dict(found=found, xy=xy, world=world, vis=vis, cut=np.array([s["cut"] for _, s in rows]),
                      K=np.stack([s["K"] for _, s in rows]).astype(np.float32),
                      points3d=np.stack([s["points3d"] for _, s in rows]).astype(np.float32),
                      points2d=np.stack([s["points2d"] for _, s in rows]).astype(np.float32))
        path = out / f"mp-{k:05d}.npz"
        paths.atomic_write(path, lambda t: np.savez(t, **arrays))  # noqa: B023
        written.append(path)
    mp.close()
    return written


def rgb_rows(s: dict, i: int, truncate: float) -> int:
    """Rows of sample i kept by the truncation augmentation (all rows when not truncated)."""
    h = s["rgb"].shape[0]
    rng = np.random.default_rng([7, i])
    if truncate <= 0 or rng.random() >= truncate:
        return h
    v = s["points2d"][:, 1]
    names = skeleton.POINT_NAMES
    top, bottom = v[names.index("spine3")], 0.5 * (v[names.index("left_knee")] + v[names.index("right_knee")])
    return int(np.clip(rng.uniform(min(top, bottom), max(top, bottom)), h // 3, h))


def load_collected(folder: Path) -> dict[str, np.ndarray]:
    files = sorted(folder.glob("mp-*.npz"))
    if not files:
        raise MissingFile(f"no MediaPipe results in {folder}: run `recon keypoints collect`")
    parts = [dict(np.load(f)) for f in files]
    keys = set.intersection(*(set(p) for p in parts)) - {"cut"}
    d = {key: np.concatenate([p[key] for p in parts]) for key in keys}
    return {key: v[d["found"]] for key, v in d.items() if key != "found"} | {"found_rate": d["found"].mean()}


def targets(d: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Collected arrays -> (inputs (N,198), J+ 3D root-relative (N,42,3), J+ 2D scaled (N,42,2))."""
    k = d["K"]
    rel, hip, s = normalise_2d(d["xy"], k)
    x = assemble_features(rel, d["world"], d["vis"])
    p3 = d["points3d"] - d["points3d"][:, :1]
    n2 = camera.normalized(d["points2d"], k)
    p2 = (n2 - hip[:, None]) / s[:, None, None]
    return x, p3.astype(np.float32), p2.astype(np.float32)


@torch.no_grad()
def errors(model: KeypointAdapter, x: torch.Tensor, p3: torch.Tensor, p2: torch.Tensor) -> tuple[float, float]:
    """The 24 joints' 3D error (root-relative, camera axes, no alignment; mm) and the J+ 2D error
    (scaled units) of an adapter in eval mode on ``targets``."""
    y3, y2 = model.eval()(x)
    return float((y3 - p3)[:, :24].norm(dim=-1).mean()) * 1000, float((y2 - p2).norm(dim=-1).mean())


def evaluate(model: KeypointAdapter, folder: Path) -> dict[str, float]:
    """An adapter on a collected folder: ``errors`` on the images MediaPipe found, as in training."""
    d = load_collected(folder)
    x, p3, p2 = (torch.from_numpy(a) for a in targets(d))
    mpjpe, err_2d = errors(model, x, p3, p2)
    return {"found_rate": float(d["found_rate"]), "samples": len(x), "mpjpe_mm": mpjpe, "error_2d_scaled": err_2d}


def flip(x: np.ndarray, p3: np.ndarray, p2: np.ndarray):
    """Mirror a batch left/right (x -> -x, swap sides) for augmentation."""
    x = x.reshape(len(x), NUM_MP, 6)[:, list(MP_MIRROR)].copy()
    x[..., 0] *= -1  # 2D x
    x[..., 2] *= -1  # world x
    p3, p2 = p3[:, list(skeleton.POINT_MIRROR)].copy(), p2[:, list(skeleton.POINT_MIRROR)].copy()
    p3[..., 0] *= -1
    p2[..., 0] *= -1
    return x.reshape(len(x), -1), p3, p2


@dataclass
class AdapterTrainConfig:
    epochs: int = 40
    batch: int = 256
    lr: float = 1e-3
    weight_2d: float = 0.05  # 2D targets are in scaled units (~0.3 per body): balance against metres
    seed: int = 0


ONE_CYCLE = Schedule(warmup=0.3, start=1 / 25, floor=1 / 25 / 1e4)  # OneCycleLR's defaults (no momentum cycling)


def train(train_dirs: list[Path], val_dir: Path, out: Path = WEIGHTS, cfg: AdapterTrainConfig | None = None,
          model_cfg: AdapterConfig | None = None, run_dir: Path | None = None, progress: bool = True,
          keypoint_model: str = DEFAULT_MODEL) -> dict:
    """Train on collected train folders, select on val (best validation MPJPE), write the weights
    (with the training record inside). Resumes from ``run_dir`` (default in the cache) if an
    earlier run was interrupted; the folder is removed once the weights are written.
    ``keypoint_model``: the MediaPipe landmark model the folders were collected with (recorded)."""
    cfg, model_cfg = cfg or AdapterTrainConfig(), model_cfg or AdapterConfig()
    run_dir = Path(run_dir or paths.cache_dir() / "runs" / f"keypoint-adapter-{keypoint_model}")
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    x, p3, p2 = (np.concatenate(a) for a in zip(*[targets(load_collected(d)) for d in train_dirs], strict=True))
    fx, f3, f2 = flip(x, p3, p2)
    x, p3, p2 = np.concatenate([x, fx]), np.concatenate([p3, f3]), np.concatenate([p2, f2])
    vd = load_collected(val_dir)
    vx, v3, v2 = (torch.from_numpy(a) for a in targets(vd))
    x, p3, p2 = torch.from_numpy(x), torch.from_numpy(p3), torch.from_numpy(p2)
    model = KeypointAdapter(model_cfg)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=1e-4)
    per_epoch = len(x) // cfg.batch
    config = {"train": asdict(cfg), "model": asdict(model_cfg), "train_dirs": [str(d) for d in train_dirs],
              "val_dir": str(val_dir), "keypoint_model": keypoint_model}
    trainer = Trainer({"adapter": model}, opt, cfg.epochs * per_epoch, schedule=ONE_CYCLE, eval_every=per_epoch,
                      out_dir=run_dir, select="val_mpjpe_mm", generators=[rng], config=config, desc="adapter",
                      steps_per_epoch=per_epoch, progress=progress)

    def step(idx):
        model.train()
        y3, y2 = model(x[idx])
        return (y3 - p3[idx]).norm(dim=-1).mean() + cfg.weight_2d * (y2 - p2[idx]).norm(dim=-1).mean()

    def validate() -> dict:
        mpjpe, err_2d = errors(model, vx, v3, v2)
        return {"val_mpjpe_mm": mpjpe, "val_2d_scaled": err_2d}

    log = trainer.fit(epoch_batches(len(x), cfg.batch, trainer.step, rng), step, validate)
    trainer.load_best()
    meta = config | {"train_samples": int(len(x)), "val_found_rate": float(vd["found_rate"]),
                     "best_val_mpjpe_mm": log["best"], "train_seconds": log["seconds"], "curve": log["history"]}
    out = Path(out)
    state = paths.cast_floats(model.state_dict(), STORE_DTYPE)
    paths.atomic_write(out, lambda t: torch.save({"cfg": asdict(model_cfg), "state": state,
                                                  "meta_json": json.dumps(meta)}, t))
    shutil.rmtree(run_dir, ignore_errors=True)
    return meta
