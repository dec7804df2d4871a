"""Outfit resizing with PBNS (thesis 5.5.6): body shape + tightness -> rest-pose outfit.

The pose input of PBNS is replaced by the body shape beta concatenated with the outfit
tightness gamma (R^2) and skinning is removed:

    V(beta, gamma) = E_T(beta, gamma) + f_X([beta, gamma]) . D        (rest pose)

E_T is the CLOTH3D resizing of the template (3.3.2): the rest-body displacement from the
template's shape to the *target* shape beta + gamma (gamma offsets anny's "weight" and
"height" phenotypes, CLOTH3D's fatness and size) moved to every cloth vertex from its nearest
body vertex and Laplacian-smoothed. Its edge lengths are the rest lengths of the edge energy.
Training is unsupervised with the PBNS energies on the rest body of shape beta (edge vs E_T,
bending, collision, cloth-to-cloth by layer, gravity, waist pins at E_T): the network fixes
what the displacement transfer gets wrong (cloth inside a fuller body, loose cloth that
should hang). gamma > 0 is looser.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from recon import paths
from recon.garment import losses as L
from recon.garment import mesh as gm
from recon.garment.mesh import smooth_vertex_values, vertex_normals
from recon.garment.templates import PRESETS
from recon.garment.train import Criterion, weights_path

RESIZE_WEIGHTS = str(Path(__file__).resolve().parent / "weights" / "resize_{outfit}.pt")
TIGHTNESS_PHENOTYPES = ("weight", "height")  # what gamma offsets (anny), like CLOTH3D's beta_0, beta_1
TIGHTNESS_RANGE = ((-0.1, 0.3), (-0.05, 0.1))  # sampling range per component, biased to loose (CLOTH3D)


def resize_weights_path(name: str, pbns_path: Path | None = None) -> Path:
    """The resizer of an outfit: shipped beside the presets, else beside its PBNS weights
    (default: where ``recon garment train`` wrote them)."""
    if name in PRESETS:
        return Path(RESIZE_WEIGHTS.format(outfit=name))
    return Path(pbns_path or weights_path(name)).parent / f"resize_{name}.pt"


@dataclass
class ResizeConfig:
    samples: int = 600  # (shape, tightness) training samples
    val_samples: int = 100
    epochs: int = 2  # measured: more epochs trade edge error for the 4 mm body margin (20 epochs: 0.27 % / 5.4 mm)
    batch: int = 16
    lr: float = 1e-3
    lr_psd: float = 3e-4
    hidden: int = 32
    layers: int = 4
    embedding: int = 32
    smooth: int = 10  # Laplacian iterations on the transferred displacement
    candidates: int = 8
    seed: int = 0
    edge: L.EdgeConfig = field(default_factory=L.EdgeConfig)
    bend: L.BendConfig = field(default_factory=L.BendConfig)
    collision: L.CollisionConfig = field(default_factory=lambda: L.CollisionConfig(weight=1e5))
    gravity: L.GravityConfig = field(default_factory=L.GravityConfig)
    pin: L.PinConfig = field(default_factory=L.PinConfig)


class Resizer(nn.Module):
    """[beta, gamma] -> 4 x 32 MLP -> X -> X . D: rest-pose correction of E_T (no skinning)."""

    def __init__(self, num_vertices: int, num_inputs: int, cfg: ResizeConfig = ResizeConfig()):
        super().__init__()
        dims = [num_inputs] + [cfg.hidden] * cfg.layers
        mlp: list[nn.Module] = []
        for a, b in zip(dims[:-1], dims[1:]):
            mlp += [nn.Linear(a, b), nn.ReLU()]
        self.mlp = nn.Sequential(*mlp, nn.Linear(cfg.hidden, cfg.embedding))
        self.D = nn.Parameter(torch.zeros(cfg.embedding, num_vertices, 3))

    def forward(self, shape: torch.Tensor, tightness: torch.Tensor) -> torch.Tensor:
        x = self.mlp(torch.cat([shape, tightness], -1))
        return torch.einsum("bk,knc->bnc", x, self.D)


class Transfer:
    """E_T: CLOTH3D displacement transfer (3.3.2) of an outfit's rest vertices, modelled on the
    body of shape ``shape0``, to other shapes: the rest-body displacement of each cloth vertex's
    nearest body vertex, Laplacian-smoothed so body detail does not print through."""

    def __init__(self, body, rest: np.ndarray, faces: np.ndarray, shape0: torch.Tensor, smooth: int = 10):
        from scipy.spatial import cKDTree

        self.body, self.rest, self.faces, self.smooth = body, rest, faces, smooth
        with torch.no_grad():
            self.v0 = body.rest_geometry(shape0.reshape(1, -1).to(body.mean_shape))[0][0].numpy()
        self.idx = cKDTree(self.v0).query(rest)[1]

    def target(self, shape: torch.Tensor, tightness: torch.Tensor) -> torch.Tensor:
        """Shape the garment is sized for: ``shape`` with gamma added to TIGHTNESS_PHENOTYPES."""
        cols = [list(self.body.shape_names).index(n) for n in TIGHTNESS_PHENOTYPES]
        t = shape.clone()
        t[..., cols] = (t[..., cols] + tightness).clamp(0, 1)
        return t

    def resize(self, shape: torch.Tensor) -> np.ndarray:
        """(B, S) target shapes -> (B, N, 3) resized rest vertices."""
        with torch.no_grad():
            v1 = self.body.rest_geometry(shape.to(self.body.mean_shape))[0].numpy()
        return np.stack([self.rest + smooth_vertex_values(v[self.idx] - self.v0[self.idx], self.faces, self.smooth)
                         for v in v1]).astype(np.float32)

    def __call__(self, shape: torch.Tensor, tightness: torch.Tensor) -> np.ndarray:
        """(B, S), (B, 2) -> (B, N, 3) rest vertices sized for shape + tightness."""
        return self.resize(self.target(shape, tightness))


def sample_conditions(body, n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    from recon.poses.sampler import ShapeSampler

    shape = ShapeSampler(body, seed=seed).sample(n).float()
    rng = np.random.default_rng(seed)
    tight = np.stack([rng.uniform(lo, hi, n) for lo, hi in TIGHTNESS_RANGE], 1)
    return shape, torch.from_numpy(tight).float()


class _Data:
    """Per condition: E_T vertices, its edge lengths, rest body of shape beta + normals, candidates."""

    def __init__(self, body, transfer: Transfer, shape, tight, edges: torch.Tensor, k: int):
        with torch.no_grad():
            bv = torch.cat([body.rest_geometry(shape[i:i + 64].to(body.mean_shape))[0] for i in range(0, len(shape), 64)])
        self.shape, self.tight = shape, tight
        self.base = torch.from_numpy(np.concatenate([transfer(shape[i:i + 64], tight[i:i + 64])
                                                     for i in range(0, len(shape), 64)]))
        self.rest_len = (self.base[:, edges[:, 0]] - self.base[:, edges[:, 1]]).norm(dim=-1)
        self.bv, self.bn = bv.float(), vertex_normals(bv.float(), body.faces)
        self.cand = L.nearest(self.bv, self.base, k).to(torch.int16 if bv.shape[1] < 32767 else torch.int32)


def rest_metrics(v: torch.Tensor, base: torch.Tensor, faces: np.ndarray, bv, bn) -> dict:
    """Vertices inside the body (%) and mean |edge - E_T edge| (mm)."""
    from recon.garment.evaluate import physical_metrics

    m = physical_metrics(v, faces, base, bv, bn)
    return {k: m[k] for k in ("collision_pct", "edge_mm")}


def _outfit_for(body, pbns_path: Path):
    from recon.garment.pbns import PBNS
    from recon.garment.templates import make_outfit

    model, ck = PBNS.load(pbns_path)
    meta = json.loads(ck["meta_json"])
    outfit = make_outfit(body, meta.get("source", meta["outfit"]), ck["shape"][None])  # source: a preset or a mesh
    if not np.allclose(outfit.vertices, model.rest.numpy(), atol=1e-5):
        raise RuntimeError(f"the {meta['outfit']} template changed since {pbns_path} was trained: retrain it")
    return outfit, ck["shape"], meta["outfit"]


def train(body, pbns_path: Path, out: Path, cfg: ResizeConfig = ResizeConfig(), log=print) -> dict:
    """Train the resizer of a trained PBNS outfit; writes ``out`` (+ .json with the curve)."""
    from tqdm import tqdm

    torch.manual_seed(cfg.seed)
    t0 = time.time()
    outfit, shape0, name = _outfit_for(body, Path(pbns_path))
    transfer = Transfer(body, outfit.vertices, outfit.faces, shape0, cfg.smooth)
    crit = Criterion(outfit, torch.from_numpy(outfit.vertices), cfg)
    tr = _Data(body, transfer, *sample_conditions(body, cfg.samples, cfg.seed), crit.edge.edges, cfg.candidates)
    va = _Data(body, transfer, *sample_conditions(body, cfg.val_samples, cfg.seed + 1), crit.edge.edges, 1)
    net = Resizer(len(outfit.vertices), body.num_shape_params + 2, cfg)
    opt = torch.optim.Adam([{"params": [net.D], "lr": cfg.lr_psd},
                            {"params": [p for n, p in net.named_parameters() if n != "D"], "lr": cfg.lr}])
    steps = cfg.epochs * (cfg.samples // cfg.batch)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    log(f"resizer {name}: {len(outfit.vertices)} vertices, {cfg.samples} train / {cfg.val_samples} val conditions; "
        f"set-up {time.time() - t0:.1f} s")
    base_val = rest_metrics(va.base, va.base, outfit.faces, va.bv, va.bn)
    curve = []
    bar = tqdm(total=steps, desc=f"resize {name}", unit="step")
    for ep in range(cfg.epochs):
        order = torch.randperm(cfg.samples)
        for b in range(cfg.samples // cfg.batch):
            i = order[b * cfg.batch:(b + 1) * cfg.batch]
            dv = net(tr.shape[i], tr.tight[i])
            v = tr.base[i] + dv
            loss = crit(v, dv, tr.bv[i], tr.bn[i], tr.cand[i], rest_len=tr.rest_len[i]).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            bar.update(1)
        with torch.no_grad():
            v = va.base + net(va.shape, va.tight)
        row = {"epoch": ep + 1, "seconds": round(time.time() - t0, 1)} | {
            f"val_{k}": x for k, x in rest_metrics(v, va.base, outfit.faces, va.bv, va.bn).items()}
        curve.append(row)
        bar.set_postfix(coll=f"{row['val_collision_pct']:.2f}%", edge=f"{row['val_edge_mm']:.2f}mm")
    bar.close()
    meta = {"outfit": name, "pbns": Path(pbns_path).name, "config": asdict(cfg), "train_seconds": round(time.time() - t0, 1),
            "threads": torch.get_num_threads(),
            "tightness_phenotypes": TIGHTNESS_PHENOTYPES, "tightness_range": TIGHTNESS_RANGE,
            "val_transfer_only": base_val, "curve": curve}
    state = {"state": net.state_dict(), "shape0": shape0, "num_inputs": body.num_shape_params + 2,
             "num_vertices": len(outfit.vertices), "meta_json": json.dumps(meta)}
    paths.atomic_write(Path(out), lambda t: torch.save(state, t))
    paths.atomic_write(Path(out).with_suffix(".json"), lambda t: Path(t).write_text(json.dumps(meta, indent=1)))
    return meta


class OutfitResizer:
    """Trained resizer: ``rest(shape, tightness)`` -> (B, N, 3) rest outfit on that body."""

    def __init__(self, body, path: Path, rest: np.ndarray, faces: np.ndarray):
        ck = paths.load_checkpoint(path, "recon garment resize")
        meta = json.loads(ck["meta_json"])
        cfg = ResizeConfig(**{k: v for k, v in meta["config"].items() if k in ("hidden", "layers", "embedding", "smooth")})
        self.net = Resizer(ck["num_vertices"], ck["num_inputs"], cfg).eval()
        self.net.load_state_dict(ck["state"])
        self.transfer = Transfer(body, rest, faces, ck["shape0"], cfg.smooth)

    @torch.no_grad()
    def rest(self, shape: torch.Tensor, tightness: torch.Tensor | None = None, corrected: bool = True) -> torch.Tensor:
        shape = shape.reshape(-1, shape.shape[-1]).float()
        tightness = torch.zeros(len(shape), 2) if tightness is None else tightness.reshape(-1, 2).float()
        base = torch.from_numpy(self.transfer(shape, tightness))
        return base + self.net(shape, tightness) if corrected else base


def evaluate(body, outfit: str, n: int = 200, seed: int = 1234, out_dir: Path = Path("eval/results")) -> Path:
    """Held-out (shape, tightness) conditions: E_T alone vs E_T + resizer, rest pose on the
    body of that shape. Writes ``garment-resize-<outfit>.md``/``.json``."""
    o, _, outfit = _outfit_for(body, weights_path(outfit))
    path = resize_weights_path(outfit)
    rz = OutfitResizer(body, path, o.vertices, o.faces)
    data = _Data(body, rz.transfer, *sample_conditions(body, n, seed), torch.from_numpy(gm.unique_edges(o.faces)), 1)
    t = time.perf_counter()
    with torch.no_grad():
        dv = rz.net(data.shape, data.tight)
    ms = (time.perf_counter() - t) * 1000 / n
    rows = {}
    loose = data.tight[:, 0] >= 0
    for subset, m in (("all", torch.ones_like(loose)), ("loose (gamma_weight >= 0)", loose), ("tight (gamma_weight < 0)", ~loose)):
        for name, v in (("transfer only (CLOTH3D E_T)", data.base), ("E_T + resizer (PBNS 5.5.6)", data.base + dv)):
            rows[f"{name}, {subset}"] = rest_metrics(v[m], data.base[m], o.faces, data.bv[m], data.bn[m])
    meta = json.loads(torch.load(path, map_location="cpu", weights_only=True)["meta_json"])
    res = {"outfit": outfit, "conditions": n, "seed": seed, "rows": rows, "ms_per_outfit_batched": ms,
           "train_seconds": meta["train_seconds"]}
    out_dir.mkdir(parents=True, exist_ok=True)
    paths.atomic_write(out_dir / f"garment-resize-{outfit}.json", lambda f: Path(f).write_text(json.dumps(res, indent=1)))
    lines = [f"Outfit resizing, {outfit}: {n} held-out (shape, tightness) conditions (seed {seed}; shapes from the "
             f"anny phenotype sampler, tightness gamma = offsets of {', '.join(TIGHTNESS_PHENOTYPES)} in "
             f"{TIGHTNESS_RANGE}), rest pose on the body of each shape. Collision = cloth vertices inside the "
             "body; edge = mean |edge length - E_T edge length|. `recon garment resize` then `recon garment eval`.",
             "", "| method | collision % | edge error mm |", "|---|---|---|"]
    lines += [f"| {k} | {r['collision_pct']:.2f} | {r['edge_mm']:.2f} |" for k, r in rows.items()]
    threads = meta.get("threads", 2)  # files from before it was recorded: 2 threads
    lines += ["", f"Resizer: trained in {meta['train_seconds'] / 60:.1f} min on {threads} CPU thread{'s' * (threads > 1)}; "
              f"{ms:.3f} ms per outfit (network only, batched)."]
    paths.atomic_write(out_dir / f"garment-resize-{outfit}.md", lambda f: Path(f).write_text("\n".join(lines) + "\n"))
    return out_dir / f"garment-resize-{outfit}.md"
