"""DeePSD's supervision (thesis 4.4: PBS data of many outfits on posed bodies): outfits drawn from
``recon.garment.outfits`` and draped (``recon.garment.drape``, the quasi-static state of the PBNS
energies; our own solver) at poses of the mocap, on the body PBNS's outfits are trained on.

Splits: train and val outfits from the train distribution at poses of the train and val
performers; test outfits held out (``OutfitSampler(held_out=True)``) at poses of the test
performers; and the five presets at the same test poses (the comparison with their per-outfit
PBNS). Each outfit's vertex order is shuffled (within each garment): no model can rely on it.

Each outfit is a task (build, shuffle, drape every pose) written atomically to
``<cache>/deepsd-drapes/<hash>/<split>-<i>.pt``: a rerun drapes only what is missing, and an
interrupted generation leaves whole outfits, usable as they are.
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import roma
import torch
from tqdm import tqdm

from recon import paths
from recon.body import default_body
from recon.body.base import BodyModel
from recon.body.lbs import blend_transforms
from recon.executor import ExecutorConfig, WorkerSpec, map_strict
from recon.garment.data import pose_set, posed_bodies
from recon.garment.deepsd.model import lbs_weights
from recon.garment.drape import DrapeSolver, DrapeSolverConfig
from recon.garment.outfits import OutfitSampler
from recon.garment.pbns.model import BlendShapeGarment
from recon.garment.templates import PRESETS, Garment, Outfit, RestBody, make_outfit
from recon.timing import add_seconds

SPLIT_SEED = {"train": 0, "val": 1, "test": 2, "preset": 3}


@dataclass
class DeePSDDataConfig:
    train_outfits: int = 150
    val_outfits: int = 10
    test_outfits: int = 20
    train_poses: int = 4  # drapes per outfit
    eval_poses: int = 5
    pose_pool: int = 1500  # balanced poses per split the outfits' poses are drawn from
    min_pose_distance: float = 0.25  # rad (data.balanced_poses)
    max_vertices: int = 10000  # outfits larger than this are drawn again (drape time)
    presets: bool = True  # the five presets at the test poses
    seed: int = 0
    workers: int = 2
    drape: DrapeSolverConfig = field(default_factory=DrapeSolverConfig)


def items(cfg: DeePSDDataConfig) -> list[tuple[str, int]]:
    """Every outfit of the dataset, (split, index): test, presets and val first (an interrupted
    generation can still be evaluated), then train."""
    out = [("test", i) for i in range(cfg.test_outfits)]
    out += [("preset", i) for i in range(len(PRESETS) if cfg.presets else 0)]
    out += [("val", i) for i in range(cfg.val_outfits)]
    return out + [("train", i) for i in range(cfg.train_outfits)]


def folder(cfg: DeePSDDataConfig) -> Path:
    """``<cache>/deepsd-drapes/<hash of what the drapes depend on>``."""
    key = json.dumps({k: v for k, v in asdict(cfg).items()
                      if k not in ("workers", "train_outfits", "val_outfits", "test_outfits")}, sort_keys=True)
    return paths.cache_dir() / "deepsd-drapes" / hashlib.sha256(key.encode()).hexdigest()[:12]


def pose_split(split: str) -> str:
    return {"preset": "test"}.get(split, split)


def sample_outfit(body: BodyModel, cfg: DeePSDDataConfig, split: str, index: int) -> tuple[str, Outfit,
                  np.random.Generator]:
    """The outfit ``index`` of ``split`` (deterministic), vertices shuffled within each garment, and
    the generator that goes on to choose its poses."""
    rng = np.random.default_rng([cfg.seed, SPLIT_SEED[split], index])
    if split == "preset":
        name = list(PRESETS)[index]
        return name, make_outfit(body, name), rng
    sampler = OutfitSampler(held_out=split == "test")
    while True:
        family, specs = sampler(rng)
        outfit = make_outfit(body, specs)
        if len(outfit.vertices) <= cfg.max_vertices:
            return family, shuffled(outfit, rng), rng


def shuffled(outfit: Outfit, rng: np.random.Generator) -> Outfit:
    """The same outfit with each garment's vertices (and faces) in a random order."""
    out = []
    for g in outfit.garments:
        perm = rng.permutation(len(g.vertices))
        inv = np.empty_like(perm)
        inv[perm] = np.arange(len(perm))
        out.append(Garment(g.name, g.vertices[perm], inv[g.faces][rng.permutation(len(g.faces))], g.layer,
                           g.pinned[perm]))
    return Outfit(out)


class OutfitDraper:
    """A worker (``recon.executor``) draping generated outfits: the body and the pose pools made
    once per process; ``draper((split, index))`` is ``drape_outfit``."""

    def __init__(self, cfg: DeePSDDataConfig):
        self.body, self.cfg = default_body(), cfg
        self.rb = RestBody(self.body)
        self.pools = {s: pose_set(s, cfg.pose_pool, cfg.min_pose_distance, cfg.seed) for s in ("train", "val", "test")}

    def __call__(self, task: tuple[str, int]) -> dict:
        return self.drape_outfit(*task)

    def drape_outfit(self, split: str, index: int) -> dict:
        """Build outfit ``index`` of ``split`` and drape it at its poses: the record saved for it."""
        body, cfg, rb = self.body, self.cfg, self.rb
        t0 = time.time()
        family, outfit, rng = sample_outfit(body, cfg, split, index)
        pool = self.pools[pose_split(split)]
        n_poses = cfg.train_poses if split == "train" else cfg.eval_poses
        if split in ("test", "preset"):  # every test outfit at the same held-out poses
            rng = np.random.default_rng([cfg.seed, SPLIT_SEED["test"], 10 ** 6])
        pick = rng.choice(len(pool), n_poses, replace=False)
        rotmats = pool[pick]
        weights = torch.from_numpy(lbs_weights(rb, outfit))
        bv, bn, bt = posed_bodies(body, rotmats, body.mean_shape[None])
        rest = torch.from_numpy(outfit.vertices).float()
        skinned = BlendShapeGarment.apply_blend(rest, blend_transforms(weights, bt))
        solver = DrapeSolver(outfit, cfg.drape)
        drapes = torch.stack([solver(rest, skinned[k], bv[k], bn[k]) for k in range(len(rotmats))])
        return {"split": split, "index": index, "family": family, "rest": rest, "faces": torch.from_numpy(outfit.faces),
                "layer": torch.from_numpy(outfit.layer.astype(np.int8)),
                "garment_id": torch.from_numpy(outfit.garment_id.astype(np.int8)),
                "pinned": torch.from_numpy(outfit.pinned), "names": json.dumps([g.name for g in outfit.garments]),
                "rotvec": roma.rotmat_to_rotvec(rotmats).float(), "drapes": drapes.float(),
                "lbs_weights": weights, "seconds": time.time() - t0}


def generate(cfg: DeePSDDataConfig, log=print) -> Path:
    """Drape every outfit of ``items(cfg)`` not yet in ``folder(cfg)``; returns the folder."""
    out = folder(cfg)
    out.mkdir(parents=True, exist_ok=True)
    paths.atomic_write(out / "config.json", lambda t: Path(t).write_text(json.dumps(asdict(cfg), indent=1)))
    todo = [it for it in items(cfg) if not (out / record_name(*it)).exists()]
    t0 = time.time()
    if todo:
        log(f"draping {len(todo)} of {len(items(cfg))} outfits in {cfg.workers} processes -> {out}")
        jobs = map_strict(WorkerSpec(OutfitDraper, (cfg,)), todo, ExecutorConfig(workers=cfg.workers, threads=1))
        for _, rec in tqdm(jobs, total=len(todo), desc="outfits", unit="outfit"):
            paths.atomic_write(out / record_name(rec["split"], rec["index"]), lambda t, rec=rec: torch.save(rec, t))
    add_seconds(out / "timing.json", time.time() - t0, cfg.workers)
    return out


def record_name(split: str, index: int) -> str:
    return f"{split}-{index:04d}.pt"


def load_split(out: Path, split: str) -> list[dict]:
    """The records of a split that exist (in index order)."""
    return [torch.load(p, weights_only=True) for p in sorted(Path(out).glob(f"{split}-*.pt"))]


if __name__ == "__main__":
    generate(DeePSDDataConfig())
