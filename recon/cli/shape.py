"""``recon shape``: the shape head (body shape from the person's mask): crops, train, eval."""
from __future__ import annotations

import json
from pathlib import Path

from recon import paths
from recon.cli.keypoints import _synth_root
from recon.cli.parsing import COUNT, Parser, actions, default, number
from recon.shape import ShapeHead
from recon.shape import train as shape_train


def _crops(kind: str, name: str, n: int | None) -> Path:
    """<cache>/shape/<folder>-<kind>[-n].npz"""
    folder = _synth_root(name).name
    return paths.cache_dir() / "shape" / f"{folder}-{kind}{'' if n is None else f'-{n}'}.npz"


def crops(args) -> None:
    for name in args.render:
        print(shape_train.render_crops(_synth_root(name), _crops("render", name, args.n), args.n,
                                       seed=sum(map(ord, name))))
    for name in args.mediapipe:
        n = args.mediapipe_n
        print(shape_train.mediapipe_crops(_synth_root(name), _crops("mediapipe", name, n), n=n))


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


def add_shape(p: Parser) -> None:
    action = actions(p)
    a = action("crops", crops, "mask crops of synth folders: the renderer's, and MediaPipe's (slow)")
    a.add_argument("--render", nargs="*", default=[], help="synth folders: rendered masks (augmented in training)")
    a.add_argument("--mediapipe", nargs="*", default=[], help="synth folders or benchmarks: MediaPipe's masks")
    a.add_argument("--n", type=COUNT, default=None, help="render crops of the first N images (default: all)")
    a.add_argument("--mediapipe-n", type=COUNT, default=None, help="MediaPipe crops of the first N images")
    a = action("train", train, "train the shape head on crops (made by `recon shape crops`)")
    a.add_argument("--render", nargs="+", required=True, help="folders whose render crops to train on")
    a.add_argument("--mediapipe", nargs="*", default=[], help="folders whose MediaPipe crops to train on")
    a.add_argument("--n", type=COUNT, default=None, help="as given to crops")
    a.add_argument("--mediapipe-n", type=COUNT, default=None, help="as given to crops")
    a.add_argument("--val", default="synth-val", help="MediaPipe crops for model selection")
    a.add_argument("--val-n", type=COUNT, default=None, help="as given to crops for --val")
    a.add_argument("--minutes", type=number(float, 0.1, 1e4), default=default(shape_train.ShapeTrainConfig, "minutes"))
    a.add_argument("--steps", type=COUNT, default=default(shape_train.ShapeTrainConfig, "steps"),
                   help="the schedule's length, unless --minutes runs out first")
    a.add_argument("--out", default=None, help="weights file (default: the shipped one)")
    a = action("eval", evaluate, "gender accuracy and phenotype errors on MediaPipe crops")
    a.add_argument("--data", nargs="+", default=["synth-val"], help="folders with MediaPipe crops")
    a.add_argument("--n", type=COUNT, default=None, help="as given to crops")
    a.add_argument("--weights", default=None, help="weights file (default: the shipped one)")


ADD = {"shape": add_shape}
