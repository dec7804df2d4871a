"""``recon shape``: the shape head (body shape from the person's mask): crops, train, eval."""
from __future__ import annotations

from recon.cli.parsing import COUNT, Parser, actions, known, number


def add_shape(p: Parser) -> None:
    action = actions(p)
    a = action("crops", "shape:crops", "mask crops of synth folders: the renderer's, and MediaPipe's (slow)")
    a.add_argument("--render", nargs="*", default=[], help="synth folders: rendered masks (augmented in training)")
    a.add_argument("--mediapipe", nargs="*", default=[], help="synth folders or benchmarks: MediaPipe's masks")
    a.add_argument("--n", type=COUNT, default=None, help="render crops of the first N images (default: all)")
    a.add_argument("--mediapipe-n", type=COUNT, default=None, help="MediaPipe crops of the first N images")
    a = action("train", "shape:train", "train the shape head on crops (made by `recon shape crops`)")
    a.add_argument("--render", nargs="+", required=True, help="folders whose render crops to train on")
    a.add_argument("--mediapipe", nargs="*", default=[], help="folders whose MediaPipe crops to train on")
    a.add_argument("--n", type=COUNT, default=None, help="as given to crops")
    a.add_argument("--mediapipe-n", type=COUNT, default=None, help="as given to crops")
    a.add_argument("--val", default="synth-val", help="MediaPipe crops for model selection")
    a.add_argument("--val-n", type=COUNT, default=None, help="as given to crops for --val")
    a.add_argument("--minutes", type=number(float, 0.1, 1e4),
                   default=known("recon.shape.train:ShapeTrainConfig", "minutes"))
    a.add_argument("--steps", type=COUNT, default=known("recon.shape.train:ShapeTrainConfig.steps"),
                   help="the schedule's length, unless --minutes runs out first")
    a.add_argument("--out", default=None, help="weights file (default: the shipped one)")
    a = action("eval", "shape:evaluate", "gender accuracy and phenotype errors on MediaPipe crops")
    a.add_argument("--data", nargs="+", default=["synth-val"], help="folders with MediaPipe crops")
    a.add_argument("--n", type=COUNT, default=None, help="as given to crops")
    a.add_argument("--weights", default=None, help="weights file (default: the shipped one)")


ADD = {"shape": add_shape}

