"""MediaPipe -> J+ adapter: a small MLP that maps MediaPipe's 33 landmarks (image + metric world)
to our 24 joints + 18 surface landmarks, in 3D (root-relative, metres) and 2D.

Why: MediaPipe's keypoints are not our joints (its hips sit on the surface, it has no spine,
collars or surface landmarks), and its 3D is coarse. The adapter learns the mapping from
synthetic renders where both are known (MediaPipe run on ``recon synth`` images, ground truth
from the generator), so the rest of the pipeline (DAE -> SMPLR) gets the J+ it was trained on.
It sees only keypoints, never pixels, so the synthetic-to-real gap is MediaPipe's, not ours.

Frames: inputs and outputs are in OpenCV camera axes (x right, y down, z forward). 2D values
are normalised camera coordinates (u - cx) / f, centred on MediaPipe's mid-hip and divided by
the 2D scale ``s`` (RMS distance of the landmarks to it), so the adapter is independent of
image size, focal length and distance.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from recon import paths
from recon.body import skeleton
from recon.keypoints.mediapipe import NUM_MP, MPPose

WEIGHTS = Path(__file__).resolve().parent / "weights" / "mp_adapter.pt"

# Left/right flip map of MediaPipe Pose's 33 landmarks.
MP_MIRROR = (0, 4, 5, 6, 1, 2, 3, 8, 7, 10, 9) + tuple(i + 1 if i % 2 else i - 1 for i in range(11, 33))
MP_HIPS = (23, 24)
IN_DIM = NUM_MP * 6  # xy (2) + world (3) + visibility (1)
OUT_DIM = skeleton.NUM_POINTS * 5  # 3D (3) + 2D (2)


def normalise_2d(xy: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels (..., P, 2) with intrinsics (..., 3, 3) -> (coords centred on MediaPipe's mid-hip and
    divided by their RMS spread, mid-hip (..., 2) in normalised camera coords, spread (...))."""
    n = (xy - k[..., None, :2, 2]) / k[..., None, :1, 0]
    hip = n[..., MP_HIPS, :].mean(-2)
    rel = n - hip[..., None, :]
    s = np.sqrt((rel ** 2).sum(-1).mean(-1))
    return rel / np.maximum(s, 1e-6)[..., None, None], hip, s


def features(xy: np.ndarray, world: np.ndarray, vis: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(..., 33, 2) pixels, (..., 33, 3) world, (..., 33) visibility, K (..., 3, 3) -> (..., 198) input."""
    return _assemble(normalise_2d(xy, k)[0], world, vis)


def _assemble(rel: np.ndarray, world: np.ndarray, vis: np.ndarray) -> np.ndarray:
    x = np.concatenate([rel, world, vis[..., None]], -1)
    return x.reshape(*x.shape[:-2], -1).astype(np.float32)


@dataclass
class AdapterConfig:
    width: int = 1024
    blocks: int = 2
    dropout: float = 0.1


class _Block(nn.Module):
    def __init__(self, w: int, p: float):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(w, w), nn.BatchNorm1d(w), nn.ReLU(), nn.Dropout(p),
                                 nn.Linear(w, w), nn.BatchNorm1d(w), nn.ReLU(), nn.Dropout(p))

    def forward(self, x):
        return x + self.net(x)


class KeypointAdapter(nn.Module):
    """(B, 198) -> J+ 3D (B, 42, 3) root-relative metres and J+ 2D (B, 42, 2) in the input's
    centred, scaled 2D coordinates (Martinez et al.-style residual MLP)."""

    def __init__(self, cfg: AdapterConfig = AdapterConfig()):
        super().__init__()
        self.cfg = cfg
        self.inp = nn.Sequential(nn.Linear(IN_DIM, cfg.width), nn.BatchNorm1d(cfg.width), nn.ReLU())
        self.blocks = nn.Sequential(*[_Block(cfg.width, cfg.dropout) for _ in range(cfg.blocks)])
        self.out = nn.Linear(cfg.width, OUT_DIM)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        y = self.out(self.blocks(self.inp(x))).view(-1, skeleton.NUM_POINTS, 5)
        return y[..., :3], y[..., 3:]

    @classmethod
    def load(cls, path: str | Path | None = None) -> "KeypointAdapter":
        ck = paths.load_checkpoint(path or WEIGHTS, "recon keypoints train")
        m = cls(AdapterConfig(**ck["cfg"]))
        m.load_state_dict(ck["state"])
        return m.eval()

    @torch.no_grad()
    def predict(self, mp: MPPose, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """MediaPipe result + intrinsics -> (J+ 3D root-relative (42,3) metres, J+ 2D (42,2) pixels)."""
        x = torch.from_numpy(features(mp.image_xy, mp.world, mp.visibility, k))[None]
        p3, p2 = self(x)
        _, hip, s = normalise_2d(mp.image_xy, k)
        uv = (p2[0].numpy() * s + hip) * k[0, 0] + k[:2, 2]
        return p3[0].numpy().astype(np.float64), uv


# --- training data: MediaPipe run over synth folders, cached per shard ------------------------------

def collect(root: Path, out: Path, shards: list[int] | None = None, truncate: float = 0.0) -> list[Path]:
    """Run MediaPipe over ``recon synth`` shards of ``root``; one npz per shard in ``out``
    (written atomically, skipped when present: resumable and splittable over processes).

    ``truncate``: fraction of images cut below a random height between the chest and the knees
    (deterministic per index), so the adapter also learns half-body photos, where the legs are
    out of the frame. Cutting rows keeps the intrinsics unchanged."""
    from tqdm import tqdm

    from recon.keypoints.mediapipe import MediaPipePose
    from recon.synth.dataset import SynthDataset

    ds = SynthDataset(root)
    n_shards = -(-len(ds) // ds.shard_size)
    todo = [k for k in (shards if shards is not None else range(n_shards)) if not (out / f"mp-{k:05d}.npz").exists()]
    mp = MediaPipePose(segmentation=False)
    written = []
    for k in tqdm(todo, desc=f"mediapipe {root.name}", unit="shard"):
        rows = []
        for i in range(k * ds.shard_size, min((k + 1) * ds.shard_size, len(ds))):
            s = ds[i]
            rgb, cut = s["rgb"], rgb_rows(s, i, truncate)
            r = mp(np.ascontiguousarray(rgb[:cut]))
            rows.append((r, s | {"cut": cut}))
        found = np.array([r is not None for r, _ in rows])
        z = lambda shape: np.zeros((len(rows),) + shape, np.float32)  # noqa: E731
        xy, world, vis = z((NUM_MP, 2)), z((NUM_MP, 3)), z((NUM_MP,))
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
        raise FileNotFoundError(f"no MediaPipe results in {folder}: run `recon keypoints collect`")
    parts = [dict(np.load(f)) for f in files]
    keys = set.intersection(*(set(p) for p in parts)) - {"cut"}
    d = {key: np.concatenate([p[key] for p in parts]) for key in keys}
    return {key: v[d["found"]] for key, v in d.items() if key != "found"} | {"found_rate": d["found"].mean()}


def targets(d: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Collected arrays -> (inputs (N,198), J+ 3D root-relative (N,42,3), J+ 2D scaled (N,42,2))."""
    k = d["K"]
    rel, hip, s = normalise_2d(d["xy"], k)
    x = _assemble(rel, d["world"], d["vis"])
    p3 = d["points3d"] - d["points3d"][:, :1]
    n2 = (d["points2d"] - k[:, None, :2, 2]) / k[:, None, :1, 0]
    p2 = (n2 - hip[:, None]) / s[:, None, None]
    return x, p3.astype(np.float32), p2.astype(np.float32)


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


def train(train_dirs: list[Path], val_dir: Path, out: Path = WEIGHTS, cfg: AdapterTrainConfig = AdapterTrainConfig(),
          model_cfg: AdapterConfig = AdapterConfig()) -> dict:
    """Train on collected train folders, select on val, export weights + a metrics JSON."""
    from tqdm import tqdm

    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    tr = [load_collected(d) for d in train_dirs]
    xs, p3s, p2s = zip(*[targets(d) for d in tr])
    x, p3, p2 = np.concatenate(xs), np.concatenate(p3s), np.concatenate(p2s)
    fx, f3, f2 = flip(x, p3, p2)
    x, p3, p2 = np.concatenate([x, fx]), np.concatenate([p3, f3]), np.concatenate([p2, f2])
    vd = load_collected(val_dir)
    vx, v3, v2 = (torch.from_numpy(a) for a in targets(vd))
    x, p3, p2 = torch.from_numpy(x), torch.from_numpy(p3), torch.from_numpy(p2)
    model = KeypointAdapter(model_cfg)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=1e-4)
    steps = cfg.epochs * (len(x) // cfg.batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, cfg.lr, total_steps=steps)
    curve, best, t0 = [], (float("inf"), None), time.time()
    for ep in tqdm(range(cfg.epochs), desc="adapter", unit="epoch"):
        model.train()
        perm = torch.from_numpy(rng.permutation(len(x)))
        for b in range(len(x) // cfg.batch):
            idx = perm[b * cfg.batch:(b + 1) * cfg.batch]
            y3, y2 = model(x[idx])
            loss = (y3 - p3[idx]).norm(dim=-1).mean() + cfg.weight_2d * (y2 - p2[idx]).norm(dim=-1).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
        model.eval()
        with torch.no_grad():
            y3, y2 = model(vx)
            mpjpe = float((y3 - v3)[:, :24].norm(dim=-1).mean()) * 1000
            err2 = float((y2 - v2).norm(dim=-1).mean())
        curve.append({"epoch": ep + 1, "val_mpjpe_mm": mpjpe, "val_2d_scaled": err2, "loss": float(loss)})
        if mpjpe < best[0]:
            best = (mpjpe, {k: v.clone() for k, v in model.state_dict().items()})
    model.load_state_dict(best[1])
    meta = {"cfg": asdict(model_cfg), "train_cfg": asdict(cfg), "train_samples": int(len(x)),
            "train_dirs": [str(d) for d in train_dirs], "val_dir": str(val_dir),
            "val_found_rate": float(vd["found_rate"]), "best_val_mpjpe_mm": best[0],
            "train_seconds": time.time() - t0}
    out = Path(out)
    paths.atomic_write(out, lambda t: torch.save({"cfg": asdict(model_cfg), "state": model.state_dict()}, t))
    paths.atomic_write(out.with_suffix(".json"),
                       lambda t: Path(t).write_text(json.dumps(meta | {"curve": curve}, indent=1)))
    return meta
