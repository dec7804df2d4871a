"""``recon keypoints``: the MediaPipe -> J+ adapter, collected on synthetic folders and trained."""
from __future__ import annotations

import json
from pathlib import Path

from recon import paths
from recon.cli.parsing import COUNT, Parser, actions, default, number
from recon.keypoints import train as keypoints_train
from recon.keypoints.adapter import KeypointAdapter, weights_for
from recon.keypoints.mediapipe import DEFAULT_MODEL, MODELS
from recon.synth import dataset


def _synth_root(name: str) -> Path:
    """A benchmark name, a folder, or a folder name under <cache>/synth."""
    if name in dataset.BENCHMARKS:
        return dataset.bench_dir(name)
    return Path(name) if Path(name).exists() else paths.cache_dir() / "synth" / name


def _collected(name: str, model: str) -> Path:
    """MediaPipe's outputs on a synth folder; the full model's in <cache>/keypoints/<folder>, another's
    in <cache>/keypoints/<folder>-<model>."""
    folder = _synth_root(name).name
    return paths.cache_dir() / "keypoints" / (folder if model == "full" else f"{folder}-{model}")


def collect(args) -> None:
    for name in args.data:
        out = _collected(name, args.keypoint_model)
        keypoints_train.collect(_synth_root(name), out, truncate=args.truncate, model=args.keypoint_model)
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


def add_keypoints(p: Parser) -> None:
    action = actions(p)
    a = action("collect", collect, "run MediaPipe over synth folders (resumable per shard)")
    a.add_argument("--data", nargs="+", default=["synth-val"], help="synth folders or benchmark names")
    a.add_argument("--truncate", type=number(float, 0, 1), default=0.0, help="fraction of images cut to half-body")
    a.add_argument("--keypoint-model", choices=tuple(MODELS), default=DEFAULT_MODEL, help="MediaPipe's landmark model")
    a = action("train", train, "train the adapter on collected folders")
    a.add_argument("--data", nargs="+", required=True, help="collected folders (as given to collect)")
    a.add_argument("--val", default="synth-val", help="collected folder for model selection")
    a.add_argument("--epochs", type=COUNT, default=default(keypoints_train.AdapterTrainConfig, "epochs"))
    a.add_argument("--keypoint-model", choices=tuple(MODELS), default=DEFAULT_MODEL,
                   help="MediaPipe's landmark model the folders were collected with")
    a.add_argument("--out", default=None, help="weights file (default: the shipped adapter of --keypoint-model)")
    a = action("eval", evaluate, "an adapter's J+ error on collected folders (the images MediaPipe found)")
    a.add_argument("--data", nargs="+", default=["synth-val"], help="collected folders (as given to collect)")
    a.add_argument("--keypoint-model", choices=tuple(MODELS), default=DEFAULT_MODEL,
                   help="MediaPipe's landmark model the folders were collected with")
    a.add_argument("--weights", default=None, help="weights file (default: the shipped adapter of --keypoint-model)")


ADD = {"keypoints": add_keypoints}
