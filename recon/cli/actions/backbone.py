"""The actions of ``recon backbone``: the volumetric hourglass, its GPU recipe, training, export and calibration."""
from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

from recon.backbone import calibrate as backbone_calibrate
from recon.backbone import train as backbone_train
from recon.backbone.recipe import RecipeConfig, device_default, run_recipe
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
    print(backbone_calibrate.calibrate(Path(args.weights)))

