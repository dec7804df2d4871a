"""The person guard's thresholds for one landmark model: the whole ``MediaPipeSource`` (retries,
grayscale views, crop confirmation) run with each setting of a grid, every MediaPipe call
memoised, so a setting costs only the guard's own work.

Counts bodies on the person-free sets of eval/phantoms.py (30 images of the error budget, 600
generator images), the bundled photos kept, and people found on the first 1,000 synth-val images
(tuning set). The score's weights are the model's guard's (``recon.people.guard.for_model``).
Writes eval/results/guard-thresholds-<model>.{json,md}.

    .venv/bin/python eval/guard_thresholds.py --keypoint-model heavy   # ~25 min the first time, 6 after
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import itertools
import pickle

import numpy as np
import torch
from phantoms import bodies, person_free_sets  # eval/ sibling
from tqdm import tqdm

from recon import paths, report
from recon.keypoints.sources import RETRIES, MediaPipeSource
from recon.people import guard
from recon.people.mediapipe import MODELS, MediaPipePose
from recon.synth.dataset import SynthDataset, bench_dir

GRID = {"image": (-1.0, -0.5), "retry": (2.0, 2.5, 3.0), "confirmed": (-1.0, 0.0, 1.0)}
LOOSE = ({"image": 99.0, "retry": 99.0, "confirmed": -99.0},  # every retry view and confirmation
         {"image": -99.0, "retry": 99.0, "confirmed": -99.0})  # every first answer and its mirror


class Memo:
    """A MediaPipe detector whose answers are kept by image content."""

    def __init__(self, detector: MediaPipePose, answers: dict):
        self.detector, self.answers = detector, answers

    def __call__(self, rgb: np.ndarray):
        key = hashlib.blake2b(np.ascontiguousarray(rgb).tobytes(), digest_size=16).digest() + str(rgb.shape).encode()
        if key not in self.answers:
            self.answers[key] = self.detector(rgb)
        return self.answers[key]


def memoised_source(model: str, answers: dict) -> MediaPipeSource:
    src = MediaPipeSource(guard=True, model=model)
    src._by_threshold = {t: Memo(src.mp if t == 0.5 else MediaPipePose(model, min_confidence=t),
                                 answers.setdefault(t, {})) for t in sorted({t for *_, t in RETRIES} | {0.5})}
    src.mp = src._by_threshold[0.5]
    return src


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--keypoint-model", default="heavy", choices=tuple(MODELS))
    ap.add_argument("--val-images", type=int, default=1000)
    a = ap.parse_args()
    torch.set_num_threads(1)
    m = a.keypoint_model
    memo = paths.cache_dir() / "phantoms" / f"memo-{m}-{a.val_images}.pkl"
    answers = pickle.loads(memo.read_bytes()) if memo.exists() else {}
    src = memoised_source(m, answers)
    sets = person_free_sets(600)
    ds = SynthDataset(bench_dir("synth-val"))
    sets["synth-val"] = [(str(i), ds[i]["rgb"]) for i in range(a.val_images)]
    shipped = guard.for_model(m)
    if not memo.exists():
        for th in LOOSE:
            src.person_guard = dataclasses.replace(shipped, threshold=th)
            for name, images in sets.items():
                bodies(tqdm(images, desc=name), src)
        paths.atomic_write(memo, lambda t: t.write_bytes(pickle.dumps(answers)))
    rows = []
    for ti, tr, tc in itertools.product(*GRID.values()):
        if tc > tr:
            continue
        src.person_guard = dataclasses.replace(shipped, threshold={"image": ti, "retry": tr, "confirmed": tc})
        counts = [len(bodies(images, src)) for images in sets.values()]
        rows.append([ti, tr, tc, *counts, "shipped" if src.person_guard.threshold == shipped.threshold else ""])
    names = list(sets)
    short = ["person-free (error budget)", "person-free (generator)", "bundled photos", "synth-val people"]
    header = ["image", "retry", "confirmed", *[f"{s} ({len(sets[n])})" for s, n in zip(short, names, strict=True)], ""]
    res = {"keypoint_model": m, "guard": dataclasses.asdict(shipped), "sets": names, "rows": rows}
    out = report.RESULTS / f"guard-thresholds-{m}"
    md = [f"# The person guard's thresholds on MediaPipe's {m} landmark model", "",
          f"`eval/guard_thresholds.py --keypoint-model {m}`: the whole `MediaPipeSource` with each setting "
          "(bodies on person-free images: fewer is better; bundled photos and synth-val people found: more is "
          f"better). The score: {shipped.describe()} (the shipped setting marked). synth-val is a tuning set. "
          "The rule of the choice: no body on the 30 images, none more than the full model's guard gives on the "
          "600 (5, [phantoms.md](phantoms.md)), then the most people.", "",
          report.table(rows, header), ""]
    report.write(out, res, "\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
