"""The GCVAE's data, training and evaluation (thesis 3.4-3.5) on the outfit distribution of
``recon.garment.outfits``: single garments on the rest (mean) body, registered as offsets and
masks (``gcvae.register``); train garments from the train distribution, test garments from the
held-out one (held-out parameter bands; the held-out family's garments are its dress and
trousers, types the model knows).

``recon garment train --model gcvae`` -> ``<cache>/garments/gcvae.pt``;
``recon garment eval --model gcvae`` -> eval/results/garment-gcvae.{json,md};
``recon garment sample --type dress -n 8`` (``recon.garment.gcvae.sample``).
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree
from tqdm import tqdm

from recon import paths, report
from recon.body import default_body
from recon.executor import ExecutorConfig, WorkerSpec, map_strict
from recon.garment import mesh, store
from recon.garment.gcvae.model import GCVAE, BodyGraph, GCVAEConfig, garment_mesh, one_hot, register
from recon.garment.outfits import OutfitSampler
from recon.garment.templates import RestBody, make_outfit


@dataclass
class GCVAEDataConfig:
    train_garments: int = 500
    test_garments: int = 100
    chunk: int = 50  # garments per file (the unit of resuming)
    seed: int = 0
    workers: int = 2


@dataclass
class GCVAELossConfig:
    offsets: float = 100.0  # L1 on offsets (m)
    normals: float = 1.0  # L1 on covered face normals
    mask: float = 1.0  # binary cross-entropy
    collision: float = 100.0  # max(0, -o . n)
    cvar: float = 0.1  # the type regressed from the encoder
    kl: float = 1e-3


@dataclass
class GCVAETrainConfig:
    model: GCVAEConfig = field(default_factory=GCVAEConfig)
    data: GCVAEDataConfig = field(default_factory=GCVAEDataConfig)
    loss: GCVAELossConfig = field(default_factory=GCVAELossConfig)
    epochs: int = 25
    batch: int = 16
    lr: float = 1e-3
    name: str = "gcvae"


VARIANTS = {"ours": {}, "no-normals": {"normals": 0.0}, "no-collision": {"collision": 0.0}}


def data_folder(cfg: GCVAEDataConfig) -> Path:
    key = json.dumps({"seed": cfg.seed, "chunk": cfg.chunk}, sort_keys=True)
    return paths.cache_dir() / "gcvae-data" / hashlib.sha256(key.encode()).hexdigest()[:12]


class ChunkMaker:
    """A worker (``recon.executor``) registering generated garments on the body graph, made once
    per process; ``maker((split, chunk, size, seed))`` is ``make_chunk``."""

    def __init__(self):
        self.body = default_body()
        self.graph = BodyGraph(RestBody(self.body), GCVAEConfig())

    def __call__(self, task: tuple[str, int, int, int]) -> dict:
        return self.make_chunk(*task)

    def make_chunk(self, split: str, chunk: int, size: int, seed: int) -> dict:
        """``size`` garments of ``split``: offsets, masks, types (and, for test, the garment meshes)."""
        body, graph = self.body, self.graph
        rng = np.random.default_rng([seed, {"train": 0, "test": 2}[split], chunk])
        sampler = OutfitSampler(held_out=split == "test")
        out = {"offsets": [], "mask": [], "kind": [], "vertices": [], "faces": []}
        while len(out["kind"]) < size:
            _, specs = sampler(rng)
            spec = specs[int(rng.integers(len(specs)))]
            g = make_outfit(body, [replace(spec, layer=0)]).garments[0]
            o, m = register(graph, g.vertices, g.faces)
            out["offsets"].append(o)
            out["mask"].append(m)
            out["kind"].append(spec.kind)
            if split == "test":
                out["vertices"].append(g.vertices)
                out["faces"].append(g.faces)
        return {"offsets": np.stack(out["offsets"]), "mask": np.stack(out["mask"]), "kind": out["kind"],
                "vertices": out["vertices"], "faces": out["faces"]}


def generate(cfg: GCVAEDataConfig, log=print) -> Path:
    """Every chunk not yet in ``data_folder(cfg)`` (``<split>-<chunk>.npz``)."""
    folder = data_folder(cfg)
    folder.mkdir(parents=True, exist_ok=True)
    todo = [(s, c) for s, n in (("test", cfg.test_garments), ("train", cfg.train_garments))
            for c in range(-(-n // cfg.chunk)) if not (folder / f"{s}-{c:03d}.npz").exists()]
    if todo:
        log(f"registering {len(todo)} chunks of {cfg.chunk} garments in {cfg.workers} processes -> {folder}")
        jobs = map_strict(WorkerSpec(ChunkMaker), [(s, c, cfg.chunk, cfg.seed) for s, c in todo],
                         ExecutorConfig(workers=cfg.workers, threads=1))
        for k, d in tqdm(jobs, total=len(todo), desc="garment chunks"):
            s, c = todo[k]
            paths.atomic_write(folder / f"{s}-{c:03d}.npz", lambda t, d=d: _save(t, d))
    return folder


def _save(path, d: dict) -> None:
    with open(path, "wb") as f:
        np.savez_compressed(f, offsets=d["offsets"], mask=d["mask"], kind=np.array(d["kind"]),
                            meshes=np.array(json.dumps([[v.tolist(), f_.tolist()] for v, f_ in
                                                        zip(d["vertices"], d["faces"])])))


def load(cfg: GCVAEDataConfig, split: str) -> dict:
    n = cfg.train_garments if split == "train" else cfg.test_garments
    files = sorted(data_folder(cfg).glob(f"{split}-*.npz"))[:-(-n // cfg.chunk)]
    parts = [np.load(f) for f in files]
    meshes = [m for p in parts for m in json.loads(str(p["meshes"]))]
    return {"offsets": torch.from_numpy(np.concatenate([p["offsets"] for p in parts])[:n]),
            "mask": torch.from_numpy(np.concatenate([p["mask"] for p in parts])[:n]),
            "kind": [str(k) for p in parts for k in p["kind"]][:n], "meshes": meshes[:n]}


def face_normals(graph: BodyGraph, offsets: torch.Tensor) -> torch.Tensor:
    return mesh.face_normals(graph.v + offsets, torch.from_numpy(graph.faces).long())


def losses(model: GCVAE, batch: dict, cfg: GCVAELossConfig) -> tuple[torch.Tensor, dict]:
    """Eq. 3.2-3.4 on a batch of (offsets, mask, kind one-hot)."""
    g = model.graph
    o_gt, m_gt, kind = batch["offsets"], batch["mask"], batch["onehot"]
    o, m_logit, mu, logvar, type_logits = model(o_gt, m_gt, kind)
    covered = m_gt[:, torch.from_numpy(g.faces).long()].min(-1).values  # faces under the garment
    n_err = (face_normals(g, o) - face_normals(g, o_gt)).abs().sum(-1)
    terms = {"offsets": cfg.offsets * (o - o_gt).abs().sum(-1).mean(),
             "normals": cfg.normals * (n_err * covered).sum() / covered.sum().clamp_min(1),
             "mask": cfg.mask * torch.nn.functional.binary_cross_entropy_with_logits(m_logit, m_gt),
             "collision": cfg.collision * torch.relu(-(o * g.n).sum(-1)).mean(),
             "cvar": cfg.cvar * torch.nn.functional.cross_entropy(type_logits, kind.argmax(-1)),
             "kl": cfg.kl * kl_divergence(mu, logvar)}
    return sum(terms.values()), {k: float(v.detach()) for k, v in terms.items()}


def kl_divergence(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """KL(q(z | x) || N(0, I)), summed over latent dimensions, mean over the batch."""
    return (-0.5 * (1 + logvar - mu ** 2 - logvar.exp()).sum(-1)).mean()


def train(cfg: GCVAETrainConfig, log=print) -> dict:
    torch.manual_seed(cfg.model.seed)
    generate(cfg.data, log)
    data = load(cfg.data, "train")
    rb = RestBody(default_body())
    model = GCVAE(BodyGraph(rb, cfg.model), cfg.model)
    data["onehot"] = one_hot(data["kind"])
    n = len(data["kind"])
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    steps = cfg.epochs * (n // cfg.batch)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps, eta_min=cfg.lr * 0.05)
    t0, curve = time.time(), []
    model.train()
    for epoch in range(cfg.epochs):
        perm, window = torch.randperm(n), []
        for i in range(n // cfg.batch):
            idx = perm[i * cfg.batch:(i + 1) * cfg.batch]
            loss, terms = losses(model, {k: data[k][idx] for k in ("offsets", "mask", "onehot")}, cfg.loss)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            window.append(terms)
        mean = {k: float(np.mean([w[k] for w in window])) for k in window[0]}
        curve.append({"epoch": epoch + 1, **mean})
        log(f"epoch {epoch + 1}/{cfg.epochs}: " + " ".join(f"{k} {v:.4f}" for k, v in mean.items())
            + f" ({time.time() - t0:.0f} s)")
    meta = {"config": asdict(cfg), "train_garments": n, "train_seconds": time.time() - t0, "curve": curve}
    model.eval()
    model.fit_type_prior(data["offsets"], data["mask"], data["kind"])
    model.save(store.gcvae_path(cfg.name), {"meta_json": json.dumps(meta)})
    return meta


def variant_config(name: str) -> GCVAETrainConfig:
    base = GCVAETrainConfig()
    return replace(base, loss=replace(base.loss, **VARIANTS[name]), name="gcvae" if name == "ours" else f"gcvae_{name}")


@torch.no_grad()
def evaluate(model: GCVAE, data: dict) -> dict:
    """The chapter's metrics on ``data`` (encoded at the mean, decoded): surface (mm, on the
    covered vertices), normals (rad, covered faces), mask IoU, KL; and the garment's own distance
    to the decoded surface (mm, both ways), against the registration's."""
    g = model.graph
    rows: dict[str, list[dict]] = {}
    for i in range(len(data["kind"])):
        o_gt, m_gt = data["offsets"][i:i + 1], data["mask"][i:i + 1]
        mu, logvar, _ = model.encode(o_gt, m_gt, one_hot(data["kind"][i:i + 1]))
        o, m_logit = model.decode(mu, one_hot(data["kind"][i:i + 1]))
        m = (m_logit > 0).float()
        cov = m_gt[0] > 0.5
        fcov = m_gt[0, torch.from_numpy(g.faces).long()].min(-1).values > 0.5
        cos = (face_normals(g, o)[0] * face_normals(g, o_gt)[0]).sum(-1).clamp(-1, 1)
        v, f = data["meshes"][i]
        v = np.asarray(v, np.float32)
        rec_v, _ = garment_mesh(g, o[0].numpy(), m[0].numpy())
        reg_v, _ = garment_mesh(g, o_gt[0].numpy(), m_gt[0].numpy())
        r = {"surface_mm": float((o - o_gt)[0][cov].norm(dim=-1).mean() * 1000),
             "normals_rad": float(torch.arccos(cos[fcov]).mean()),
             "mask_iou": float(((m[0] > 0.5) & cov).sum() / ((m[0] > 0.5) | cov).sum().clamp_min(1)),
             "kl": float(-0.5 * (1 + logvar - mu ** 2 - logvar.exp()).sum()),
             "garment_to_decoded_mm": chamfer(v, rec_v), "garment_to_registered_mm": chamfer(v, reg_v)}
        rows.setdefault(data["kind"][i], []).append(r)
    per = {k: {m: float(np.mean([r[m] for r in rs])) for m in rs[0]} | {"n": len(rs)} for k, rs in rows.items()}
    every = [r for rs in rows.values() for r in rs]
    return {"all": {m: float(np.mean([r[m] for r in every])) for m in every[0]} | {"n": len(every)}, "types": per}


def chamfer(a: np.ndarray, b: np.ndarray) -> float | None:
    """Mean distance (mm) from ``a``'s points to ``b``'s and back, averaged."""
    if len(b) == 0:
        return None
    return float((cKDTree(b).query(a)[0].mean() + cKDTree(a).query(b)[0].mean()) / 2 * 1000)


def evaluate_and_report(out_dir: Path = report.RESULTS, log=print) -> Path:
    torch.set_num_threads(1)
    rb = RestBody(default_body())
    data = load(GCVAEDataConfig(), "test")
    out = {"variants": {}}
    for name in VARIANTS:
        path = store.gcvae_path(variant_config(name).name)
        if path.exists():
            model, ck = GCVAE.load(path, rb)
            seconds = json.loads(ck["meta_json"])["train_seconds"]
            out["variants"][name] = evaluate(model, data) | {"train_seconds": seconds}
            log(f"{name}: " + json.dumps(out["variants"][name]["all"]))
    return report.write(Path(out_dir) / "garment-gcvae", out, render(out))


LABELS = {"ours": "GCVAE", "no-normals": "without the normals term", "no-collision": "without the collision term"}
METRICS = ("surface_mm", "normals_rad", "mask_iou", "kl", "garment_to_decoded_mm", "garment_to_registered_mm")


def render(data: dict) -> str:
    heads = ["model", "surface mm", "normals rad", "mask IoU", "KL", "garment<->decoded mm", "garment<->registered mm"]
    fmt = ["", ".1f", ".3f", ".3f", ".1f", ".1f", ".1f"]
    v = data["variants"]
    ours = v["ours"]
    lines = ["# GCVAE garment space (thesis 3.4)", "",
             f"{ours['all']['n']} held-out garments (recon.garment.outfits' held-out parameter bands and family), "
             "encoded (mean of q(z|x)) and decoded. Surface: offset error on the covered body vertices; normals: "
             "angle of the covered faces' normals; garment<->decoded: mean distance between the garment mesh and "
             "the decoded one, both ways (garment<->registered: the same for the registration alone, the "
             "representation's own loss).", "",
             report.table([[LABELS[k]] + [r["all"][m] for m in METRICS] for k, r in v.items()], heads, fmt), "",
             "Per type (GCVAE):", "",
             report.table([[t, r["n"]] + [r[m] for m in METRICS] for t, r in sorted(ours["types"].items())],
                          ["type", "n"] + heads[1:], ["", "d"] + fmt[1:]), "",
             "Sample sheet: demos/previews/gcvae-samples.jpg (`recon garment sample`)."]
    return "\n".join(lines)
