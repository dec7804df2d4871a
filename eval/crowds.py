"""Crowds (issue 68): how many people `recon run --max-people 20` finds in street scenes.

other-crowd-val / other-crowd-test (recon.synth.crowd): 4-10 people of the other domain, 60-400 px
tall, on a ground plane in front of a street-like photograph, nearer people hiding farther ones.
Each image goes through `recon run`'s source (`MediaPipeSource.people` with the defaults of
`recon.pipeline.ReconstructorConfig`). A found person counts when its box overlaps a true person's
box (IoU > 0.3, each true person matched once); other finds are extra bodies. Reported: the share
of people at least 100 px tall that are found (all of them, and those with at least half of their
silhouette in view), by height band, and the extra bodies per 20 images. On other-empty-* (no
person) every body found is an extra one. Writes eval/results/crowds-<bench>[-no-detect|-no-multipose].{md,json}
(``--no-detect``: without the people stage's detector, as 0.25 found people; ``--no-multipose``:
NanoDet's boxes alone, as 0.27 found them).

    .venv/bin/python eval/crowds.py --bench other-crowd-test      # ~10 min on 2 cores
"""
from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from recon import report
from recon.keypoints import make_source
from recon.people.boxes import box_iou
from recon.reconstruction import ReconstructorConfig
from recon.synth.dataset import open_bench

BANDS = ((60, 100), (100, 200), (200, 400), (400, 10000))


def match(found: list, truth: np.ndarray) -> tuple[list[int], int]:
    """Indices of the true boxes matched (greedy, IoU > 0.3) and the count of extra finds."""
    free = list(range(len(truth)))
    hit = []
    for box in found:
        best = max(((box_iou(box, truth[t]), t) for t in free), default=(0.0, -1))
        if best[0] > 0.3:
            free.remove(best[1])
            hit.append(best[1])
    return hit, len(found) - len(hit)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bench", default="other-crowd-test")
    ap.add_argument("--max-people", type=int, default=20)
    ap.add_argument("--n", type=int, default=None)
    ap.add_argument("--no-detect", action="store_true", help="without the people stage's detector")
    ap.add_argument("--no-multipose", action="store_true", help="without MultiPose's boxes (0.27's people stage)")
    a = ap.parse_args()
    torch.set_num_threads(1)
    cfg = ReconstructorConfig(detect=not a.no_detect, multipose=not a.no_multipose).as_installed()
    src = make_source("mediapipe", None, "cpu", cfg.flip, cfg.retry, cfg.guard, cfg.keypoint_model, cfg.fallback,
                      cfg.backbone_weight, cfg.search, cfg.detect, cfg.movenet, cfg.multipose)
    ds = open_bench(a.bench)
    rows = []
    for i in tqdm(range(min(a.n or len(ds), len(ds))), desc=a.bench):
        s = ds[i]
        n = int(s.get("n_people", 0))
        people = src.people(s["rgb"], s["K"].astype(np.float64), a.max_people)
        hit, extra = match([kp.box for kp in people], s["boxes"][:n] if n else np.zeros((0, 4)))
        for j in range(n):
            rows.append({"image": i, "height": float(s["heights"][j]), "visible": float(s["visible"][j]),
                         "found": j in hit})
        rows.append({"image": i, "extra": extra})
    people = [r for r in rows if "height" in r]
    extras = sum(r.get("extra", 0) for r in rows)
    images = len({r["image"] for r in rows})

    def share(sel):
        sel = list(sel)
        return (float(np.mean([r["found"] for r in sel])) if sel else None, len(sel))
    tall = [r for r in people if r["height"] >= 100]
    summary = {"images": images, "people": len(people), "found_100px": share(tall),
               "found_100px_half_visible": share(r for r in tall if r["visible"] >= 0.5),
               "extra_per_20_images": 20.0 * extras / max(images, 1),
               "bands": {f"{lo}-{hi}": share(r for r in people if lo <= r["height"] < hi) for lo, hi in BANDS},
               "source": dataclasses.asdict(cfg) | {"max_people": a.max_people}}
    fmt = lambda x: "-" if x[0] is None else f"{100 * x[0]:.1f} % of {x[1]}"  # noqa: E731
    flag = " --no-detect" if a.no_detect else " --no-multipose" if a.no_multipose else ""
    md = [f"# Crowds: people found in {a.bench} (`recon run --max-people {a.max_people}{flag}`)", "",
          "`eval/crowds.py`: " + __doc__.split("\n\n")[1].replace("\n", " "), "",
          report.table([["people >= 100 px tall", fmt(summary["found_100px"])],
                        ["people >= 100 px tall, >= half in view", fmt(summary["found_100px_half_visible"])],
                        *[[f"people {k} px tall", fmt(v)] for k, v in summary["bands"].items()],
                        ["extra bodies per 20 images", f"{summary['extra_per_20_images']:.2f}"]],
                       ["", "found"]), "",
          f"{images} images, {len(people)} people; {report.describe(report.machine())}."]
    out = Path(report.RESULTS) / f"crowds-{a.bench}{flag.replace(' --', '-')}"
    report.write(out, {"summary": summary, "people": people}, "\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
