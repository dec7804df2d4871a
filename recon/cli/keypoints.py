"""``recon keypoints``: the MediaPipe -> J+ adapter, collected on synthetic folders and trained."""
from __future__ import annotations

from recon.cli.parsing import COUNT, Parser, actions, known, number


def add_keypoints(p: Parser) -> None:
    models = tuple(known("recon.people.mediapipe:MODELS"))
    action = actions(p)
    a = action("collect", "keypoints:collect", "run MediaPipe over synth folders (resumable per shard)")
    a.add_argument("--data", nargs="+", default=["synth-val"], help="synth folders or benchmark names")
    a.add_argument("--truncate", type=number(float, 0, 1), default=0.0, help="fraction of images cut to half-body")
    a.add_argument("--keypoint-model", choices=models, default=known("recon.people.mediapipe:DEFAULT_MODEL"),
                   help="MediaPipe's landmark model")
    a = action("train", "keypoints:train", "train the adapter on collected folders")
    a.add_argument("--data", nargs="+", required=True, help="collected folders (as given to collect)")
    a.add_argument("--val", default="synth-val", help="collected folder for model selection")
    a.add_argument("--epochs", type=COUNT, default=known("recon.keypoints.train:AdapterTrainConfig.epochs"))
    a.add_argument("--keypoint-model", choices=models, default=known("recon.people.mediapipe:DEFAULT_MODEL"),
                   help="MediaPipe's landmark model the folders were collected with")
    a.add_argument("--out", default=None, help="weights file (default: the shipped adapter of --keypoint-model)")
    a = action("eval", "keypoints:evaluate", "an adapter's J+ error on collected folders (the images MediaPipe found)")
    a.add_argument("--data", nargs="+", default=["synth-val"], help="collected folders (as given to collect)")
    a.add_argument("--keypoint-model", choices=models, default=known("recon.people.mediapipe:DEFAULT_MODEL"),
                   help="MediaPipe's landmark model the folders were collected with")
    a.add_argument("--weights", default=None, help="weights file (default: the shipped adapter of --keypoint-model)")


ADD = {"keypoints": add_keypoints}

