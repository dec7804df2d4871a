"""``recon backbone``: the volumetric hourglass, its GPU recipe, training, export and calibration."""
from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

from recon.backbone import search as backbone_search
from recon.backbone import train as backbone_train
from recon.backbone.hourglass import SIZES, STEMS
from recon.backbone.model import WEIGHTS
from recon.backbone.recipe import RecipeConfig, device_default, run_recipe
from recon.cli.parsing import COUNT, NON_NEGATIVE, POSITIVE, SEED, STEPS, Parser, actions, default, device
from recon.errors import ReconError
from recon.synth import dataset


def train(args) -> None:
    if args.online == bool(args.train):
        raise ReconError("give --train FOLDERS (stored shards) or --online (rendered on the fly), not both")
    if args.render_executor == "ray" and not args.online:
        raise ReconError("--render-executor ray renders --online training data")
    cls = backbone_train.BackboneTrainConfig
    cfg = cls(**{f.name: getattr(args, f.name) for f in dataclasses.fields(cls)
                 if f.name not in ("model", "init") and hasattr(args, f.name)},
              model={"stem": args.stem} if args.stem != "hourglass" else {}, init=args.init or "")
    if args.online:  # a benchmark name is rendered on the fly, like the training data
        val = args.val
    else:
        val = dataset.bench_dir(args.val) if args.val in dataset.BENCHMARKS else Path(args.val)
    log = backbone_train.train(None if args.online else [Path(p) for p in args.train], val, Path(args.out), cfg,
                               device=args.device)
    print(json.dumps({k: v for k, v in log.items() if k != "history"}))


def export(args) -> None:
    print(backbone_train.export(Path(args.run), Path(args.weights)))


def recipe(args) -> int:
    fields = {f.name for f in dataclasses.fields(RecipeConfig)}
    cfg = RecipeConfig(**{k: v for k, v in vars(args).items() if k in fields and v is not None})
    out = run_recipe(Path(args.out), cfg, device=args.device or device_default())
    print(json.dumps({k: v for k, v in out.items() if k not in ("recipe", "machine")}, indent=1))
    if out["phase"] == "training":
        print(f"training: {out['minutes_left']} min of the budget left - run the same command again to resume",
              file=sys.stderr)
    return 0


def calibrate(args) -> None:
    print(backbone_search.calibrate(Path(args.weights)))


# flag -> (type, help) of the training settings, read from BackboneTrainConfig / RecipeConfig
TRAIN_FLAGS = {
    "steps": (COUNT, "optimiser steps (the schedule's length unless --minutes is further)"),
    "minutes": (NON_NEGATIVE, "total wall-clock budget; the lr schedule follows it (0: none)"),
    "run_minutes": (NON_NEGATIVE, "stop this invocation after N minutes (resumable; 0: no limit)"),
    "batch": (COUNT, None), "lr": (POSITIVE, None), "eval_every": (COUNT, None), "val_images": (COUNT, None),
    "repeats": (COUNT, "--online: crops per rendered sample"),
    "workers": (STEPS, "data-loader processes (--render-executor ray: rendering actors)"),
    "seed": (SEED, "data/initialisation seed (use a new one when fine-tuning)"),
    "smplr_weight": (NON_NEGATIVE, "> 0: end-to-end fine-tuning through the frozen DAE + SMPLR "
                                   "(thesis 2.4.5; with --init, --lr 1e-4)"),
}


def add_backbone(p: Parser) -> None:
    action = actions(p)
    cls = backbone_train.BackboneTrainConfig
    a = action("train", train, "train on rendered (--online) or stored synthetic data; resumable")
    a.add_argument("--out", required=True, help="checkpoint folder (resumes if it holds a run)")
    a.add_argument("--online", action="store_true", help="render training data on the fly in the loader workers")
    a.add_argument("--render-executor", choices=("local", "ray"), default=default(cls, "render_executor"),
                   help="--online: render in local loader processes, or in --workers Ray actors on any node of a "
                        "cluster (pip install 'recon[cluster]'), streamed to the trainer")
    a.add_argument("--ray-address", default=None, help="the Ray cluster to join (default: $RAY_ADDRESS, else a local "
                                                      "Ray with this machine's cores)")
    a.add_argument("--train", nargs="+", help="synth folders with training shards")
    a.add_argument("--val", default="synth-val", help="benchmark name (rendered when --online) or folder")
    a.add_argument("--device", type=device, default="cpu")
    a.add_argument("--size", choices=list(SIZES), default=default(cls, "size"))
    a.add_argument("--stem", choices=STEMS, default="hourglass",
                   help="first layers: the hourglass' own, or EfficientNet-Lite0 (+ FPN to stride 4)")
    a.add_argument("--imagenet", action="store_true",
                   help="start the efficientnet-lite0 stem from ImageNet weights (extra recon[imagenet])")
    a.add_argument("--init", default=None,
                   help="start from these weights, e.g. recon/backbone/weights/hourglass_base.pt")
    for name, (kind, help) in TRAIN_FLAGS.items():
        a.add_argument("--" + name.replace("_", "-"), type=kind, default=default(cls, name), help=help)
    a = action("export", export, "best checkpoint of a run -> shipped weights (+ crop calibration)")
    a.add_argument("--run", required=True, help="the training run's folder")
    a.add_argument("--weights", default=str(WEIGHTS), help="the weights file to write")
    a = action("recipe", recipe, "the GPU recipe in one command: train for a minute budget (re-run to resume), then "
               "export, score on synth-val against the shipped weights, ship if better (weights, results, model card)")
    a.add_argument("--out", default="runs/gpu-recipe", help="run folder (resumes if it holds a run)")
    a.add_argument("--device", type=device, default=None, help="default: cuda when available, else cpu")
    for name in ("minutes", "run_minutes", "lr", "batch", "workers", "seed"):
        a.add_argument("--" + name.replace("_", "-"), type=TRAIN_FLAGS[name][0], default=None,
                       help=f"default: {default(RecipeConfig, name)!r}")
    a.add_argument("--init", default=None, help=f"default: {default(RecipeConfig, 'init')!r}")
    a.add_argument("--size", choices=list(SIZES), default=None, help=f"default: {default(RecipeConfig, 'size')!r}")
    a = action("calibrate", calibrate, "recalibrate the crop-search depth factors of a weights file")
    a.add_argument("--weights", default=str(WEIGHTS))


ADD = {"backbone": add_backbone}
