"""``recon keypoints``: the MediaPipe -> J+ adapter, collected on synthetic folders and trained."""
from __future__ import annotations

import json
from pathlib import Path

from recon import paths
from recon.cli.parsing import COUNT, Parser, actions, default, number
from recon.keypoints import train as keypoints_train
from recon.synth import dataset


def _synth_root(name: str) -> Path:
    """A benchmark name, a folder, or a folder name under <cache>/synth."""
    if name in dataset.BENCHMARKS:
        return dataset.bench_dir(name)
    return Path(name) if Path(name).exists() else paths.cache_dir() / "synth" / name


def _collected(name: str) -> Path:
    return paths.cache_dir() / "keypoints" / _synth_root(name).name


def collect(args) -> None:
    for name in args.data:
        keypoints_train.collect(_synth_root(name), _collected(name), truncate=args.truncate)
        print(_collected(name))


def train(args) -> None:
    cfg = keypoints_train.AdapterTrainConfig(epochs=args.epochs)
    meta = keypoints_train.train([_collected(n) for n in args.data], _collected(args.val), cfg=cfg)
    print(json.dumps({k: v for k, v in meta.items() if k != "curve"}, indent=1))


def add_keypoints(p: Parser) -> None:
    action = actions(p)
    a = action("collect", collect, "run MediaPipe over synth folders (resumable per shard)")
    a.add_argument("--data", nargs="+", default=["synth-val"], help="synth folders or benchmark names")
    a.add_argument("--truncate", type=number(float, 0, 1), default=0.0, help="fraction of images cut to half-body")
    a = action("train", train, "train the adapter on collected folders")
    a.add_argument("--data", nargs="+", required=True, help="collected folders (as given to collect)")
    a.add_argument("--val", default="synth-val", help="collected folder for model selection")
    a.add_argument("--epochs", type=COUNT, default=default(keypoints_train.AdapterTrainConfig, "epochs"))


ADD = {"keypoints": add_keypoints}
