"""The backbone's GPU recipe as one resumable command: ``recon backbone recipe``.

A lent GPU machine runs a command for at most 10 minutes, so each invocation trains for at most
``run_minutes`` and stops, checkpointed; running the same command again resumes. Once the
training budget (``minutes``) is spent, the same command exports the best checkpoint to a
candidate file (crop search calibrated on synth-val images 0 .. calibrate_on-1), scores the
candidate and the shipped weights side by side on the next ``score_images`` synth-val images
(the crop search without ground truth, as ``recon run --source backbone`` uses it, and the
ground-truth crop of the thesis protocol), and ships the candidate only when its crop-search
MPJPE is lower: the weights file, eval/results/backbone-gpu-recipe.{json,md}, and the model
card's "Latest GPU recipe" section. Training data are rendered on the fly by one loader process
per core but one (EGL, on the GPU when the machine has one).
"""
from __future__ import annotations

import os
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from recon import paths, report
from recon.backbone.crop import Crop
from recon.backbone.model import WEIGHTS
from recon.backbone.search import CropSearch
from recon.backbone.train import BackboneTrainConfig, export, train
from recon.body import default_body
from recon.errors import MissingFile
from recon.synth.dataset import SynthDataset, bench_dir, build_benchmark

CARD = WEIGHTS.parent / "MODEL_CARD.md"
CARD_BEGIN, CARD_END = "<!-- gpu-recipe:begin -->", "<!-- gpu-recipe:end -->"


@dataclass
class RecipeConfig:
    minutes: float = 45.0  # training budget, wall clock, over all invocations
    run_minutes: float = 8.0  # per invocation (the lent machine's limit is 10 minutes a command)
    init: str = str(WEIGHTS)  # continue from these weights ("": from scratch)
    lr: float = 5e-4  # warm restart of the cosine schedule (from scratch: 1e-3)
    size: str = "base"
    batch: int = 64
    repeats: int = 2
    workers: int = 0  # loader (render) processes; 0: one per core but one
    eval_every: int = 400
    val_images: int = 512
    seed: int = 3  # a new data stream for a continued run
    calibrate_on: int = 300
    score_images: int = 500
    model: dict = field(default_factory=dict)  # HourglassConfig overrides (tests: a tiny network)


def train_config(cfg: RecipeConfig) -> BackboneTrainConfig:
    return BackboneTrainConfig(size=cfg.size, batch=cfg.batch, lr=cfg.lr, steps=10 ** 9, minutes=cfg.minutes,
                               run_minutes=cfg.run_minutes, eval_every=cfg.eval_every, val_images=cfg.val_images,
                               workers=cfg.workers or max(1, (os.cpu_count() or 2) - 1), repeats=cfg.repeats,
                               seed=cfg.seed, model=dict(cfg.model), init=cfg.init)


def score(weights: Path, samples: list[dict], device: str) -> dict:
    """Pelvis-aligned joint MPJPE (mm) of a weights file on samples: the crop search without ground
    truth, and the ground-truth metric crop."""
    search = CropSearch.load(default_body(), weights, device, jit=False)
    own, gt_crop = [], []
    for s in samples:
        k, gt = s["K"].astype(np.float64), s["points3d"].astype(np.float64)
        pts, _, _, _ = search.locate(s["rgb"], k)
        own.append(np.linalg.norm((pts[:24] - pts[:1]) - (gt[:24] - gt[:1]), axis=1).mean() * 1000)
        crop = Crop.around(gt[:24].mean(0), k)
        p = search.net.predict([s["rgb"]], [crop])[0][0]
        gt_crop.append(np.linalg.norm((p[:24] - p[:1]) - (gt[:24] - gt[:1]), axis=1).mean() * 1000)
    return {"crop_search_mpjpe_mm": float(np.mean(own)), "gt_crop_mpjpe_mm": float(np.mean(gt_crop))}


def run_recipe(out_dir: Path, cfg: RecipeConfig | None = None, device: str = "cuda", weights: Path = WEIGHTS,
               card: Path | None = CARD, results: Path | None = report.RESULTS, progress: bool = True) -> dict:
    """One invocation (see the module doc). Returns {"phase": "training" | "shipped" | "kept", ...}."""
    cfg = cfg or RecipeConfig()
    out_dir, weights = Path(out_dir), Path(weights)
    n_val = cfg.calibrate_on + cfg.score_images
    tcfg = train_config(cfg)
    build_benchmark("synth-val", workers=tcfg.workers, n=max(n_val, _stored("synth-val")))
    log = train(None, "synth-val", out_dir / "run", tcfg, device=device, progress=progress)
    if log["seconds"] < 60 * cfg.minutes:
        left = cfg.minutes - log["seconds"] / 60
        return {"phase": "training", "steps": log["steps"], "minutes_left": round(left, 1),
                "best_val_mpjpe_mm": log["best_val_mpjpe_mm"]}
    candidate = export(out_dir / "run", out_dir / "candidate.pt", calibrate_on=cfg.calibrate_on)
    ds = SynthDataset(bench_dir("synth-val"))
    samples = [ds[i] for i in range(cfg.calibrate_on, min(n_val, len(ds)))]
    scores = {"candidate": score(candidate, samples, device)}
    if weights.exists():
        scores["shipped"] = score(weights, samples, device)
    better = "shipped" not in scores or (scores["candidate"]["crop_search_mpjpe_mm"]
                                          < scores["shipped"]["crop_search_mpjpe_mm"])
    gpu = torch.cuda.get_device_name() if device.startswith("cuda") and torch.cuda.is_available() else None
    record = {"recipe": {**asdict(cfg), "init": _relative(cfg.init)}, "device": gpu or device,
              "machine": report.machine(), "training_minutes": round(log["seconds"] / 60, 1), "steps": log["steps"],
              "best_val_mpjpe_mm": log["best_val_mpjpe_mm"],
              "synth_val_images": [cfg.calibrate_on, len(samples) + cfg.calibrate_on], "scores": scores,
              "shipped": better}
    if better:
        paths.atomic_write(weights, lambda t: shutil.copyfile(candidate, t))
        if card is not None and Path(card).exists():
            update_card(Path(card), record)
    if results is not None:
        report.write(Path(results) / "backbone-gpu-recipe", record, render(record))
    return {"phase": "shipped" if better else "kept", **record}


def _relative(path: str) -> str:
    """A path inside the repository as written in records: relative to its root (machine-independent)."""
    if path and Path(path).resolve().is_relative_to(paths.REPO_ROOT.resolve()):
        return str(Path(path).resolve().relative_to(paths.REPO_ROOT.resolve()))
    return path


def _stored(name: str) -> int:
    try:
        return len(SynthDataset(bench_dir(name)))
    except MissingFile:  # nothing stored yet
        return 0


def render(r: dict) -> str:
    rows = [[k, v["crop_search_mpjpe_mm"], v["gt_crop_mpjpe_mm"]] for k, v in r["scores"].items()]
    a, b = r["synth_val_images"]
    return "\n".join([
        "# Backbone GPU recipe (`recon backbone recipe`)", "",
        f"{r['training_minutes']} min of training on {r['device']} ({report.describe(r['machine'])}), "
        f"{r['steps']} steps, "
        f"from `{r['recipe']['init'] or 'scratch'}`; scored on synth-val images {a}-{b - 1} (joint MPJPE, mm, "
        "pelvis-aligned).", "",
        report.table(rows, ["weights", "crop search (no GT)", "GT crop"], ["", ".1f", ".1f"]), "",
        f"Shipped: {'yes' if r['shipped'] else 'no (the shipped weights stay)'}."])


def update_card(card: Path, record: dict) -> None:
    """Replace the model card's "Latest GPU recipe" section (between its markers) with this run."""
    text = card.read_text()
    section = "\n".join([CARD_BEGIN, "## Latest GPU recipe run", "",
                         render(record).split("\n", 2)[2].strip(), "",
                         "Record: [eval/results/backbone-gpu-recipe.md](../../../eval/results/backbone-gpu-recipe.md).",
                         CARD_END])
    if CARD_BEGIN in text and CARD_END in text:
        head, rest = text.split(CARD_BEGIN, 1)
        text = head + section + rest.split(CARD_END, 1)[1]
    else:
        text = text.rstrip("\n") + "\n\n" + section + "\n"
    paths.write_text(card, text)


def device_default() -> str:
    return "cuda" if torch.cuda.is_available() else "cpu"
