"""The actions of ``recon shape``: the shape head (body shape from the person's mask): crops, train, eval."""
from __future__ import annotations

import json
from pathlib import Path

from recon import paths
from recon.cli.actions.keypoints import synth_root
from recon.shape import ShapeHead
from recon.shape import train as shape_train


def _crops(kind: str, name: str, n: int | None) -> Path:
    """<cache>/shape/<folder>-<kind>[-n].npz"""
    folder = synth_root(name).name
    return paths.cache_dir() / "shape" / f"{folder}-{kind}{'' if n is None else f'-{n}'}.npz"


def crops(args) -> None:
    for name in args.render:
        print(shape_train.render_crops(synth_root(name), _crops("render", name, args.n), args.n,
                                       seed=sum(map(ord, name))))
    for name in args.mediapipe:
        n = args.mediapipe_n
        print(shape_train.mediapipe_crops(synth_root(name), _crops("mediapipe", name, n), n=n))


def train(args) -> None:
    cfg = shape_train.ShapeTrainConfig(minutes=args.minutes, steps=args.steps)
    meta = shape_train.train([_crops("render", n, args.n) for n in args.render],
                             [_crops("mediapipe", n, args.mediapipe_n) for n in args.mediapipe],
                             _crops("mediapipe", args.val, args.val_n), out=Path(args.out) if args.out else
                             shape_train.WEIGHTS, cfg=cfg)
    print(json.dumps({k: v for k, v in meta.items() if k != "curve"}, indent=1))


def evaluate(args) -> None:
    model = ShapeHead.load(args.weights)
    for name in args.data:
        print(name, json.dumps(shape_train.evaluate(model, _crops("mediapipe", name, args.n))))

