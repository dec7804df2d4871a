"""The actions of ``recon keypoints``: the MediaPipe -> J+ adapter, collected on synthetic folders and trained."""
from __future__ import annotations

import json
from pathlib import Path

from recon import paths
from recon.keypoints import train as keypoints_train
from recon.keypoints.adapter import KeypointAdapter, weights_for
from recon.synth import dataset


def synth_root(name: str) -> Path:
    """A benchmark name, a folder, or a folder name under <cache>/synth."""
    if name in dataset.BENCHMARKS:
        return dataset.bench_dir(name)
    return Path(name) if Path(name).exists() else paths.cache_dir() / "synth" / name


def _collected(name: str, model: str) -> Path:
    """MediaPipe's outputs on a synth folder; the full model's in <cache>/keypoints/<folder>, another's
    in <cache>/keypoints/<folder>-<model>."""
    folder = synth_root(name).name
    return paths.cache_dir() / "keypoints" / (folder if model == "full" else f"{folder}-{model}")


def collect(args) -> None:
    for name in args.data:
        out = _collected(name, args.keypoint_model)
        keypoints_train.collect(synth_root(name), out, truncate=args.truncate, model=args.keypoint_model)
        print(out)


def train(args) -> None:
    cfg = keypoints_train.AdapterTrainConfig(epochs=args.epochs)
    m = args.keypoint_model
    out = Path(args.out) if args.out else weights_for(m)
    meta = keypoints_train.train([_collected(n, m) for n in args.data], _collected(args.val, m), out=out,
                                 cfg=cfg, keypoint_model=m)
    print(json.dumps({k: v for k, v in meta.items() if k != "curve"}, indent=1))


def evaluate(args) -> None:
    model = KeypointAdapter.load(args.weights, args.keypoint_model)
    for name in args.data:
        print(name, json.dumps(keypoints_train.evaluate(model, _collected(name, args.keypoint_model))))

