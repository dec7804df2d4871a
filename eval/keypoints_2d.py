"""The 2D signal (issue 88): the keypoint source's 2D error per joint group on the other domain.

Each image of the benchmark goes through `recon run`'s keypoint source (one person,
``MediaPipeSource`` with ``recon.pipeline.ReconstructorConfig``'s defaults) with the people stage's
detector (``--detect``, 0.26) and without it (0.25: MediaPipe's face-anchored detector, its retries
and the faceless search). Reported per variant: people found, and the 2D error of the J+ as % of the
true person's box height (the error budget's unit), per joint group, on the images every variant
found (so that the rows compare the same people). Writes eval/results/keypoints-2d-<bench>.{md,json}.

    OMP_NUM_THREADS=1 .venv/bin/python eval/keypoints_2d.py --bench other-val     # ~12 min
"""
from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from recon import report
from recon.body import skeleton
from recon.keypoints import make_source
from recon.reconstruction import ReconstructorConfig
from recon.smplr.lifter_train import box_height
from recon.synth.dataset import open_bench

GROUPS = {a: [skeleton.JOINT_NAMES.index(n) for n in names]
          for a, names in zip(("Hd", "Ts", "Sr", "Ew", "Wt", "Hp", "Kn", "Ft"), skeleton.JOINT_GROUPS.values(),
                              strict=True)}
GROUPS["Lm"] = list(range(24, 42))
VARIANTS = {"0.25 (no detector)": ({"detect": False}, 0.0), "detector": ({"detect": True}, 0.0),
            "detector + MoveNet x0.5": ({"detect": True}, 0.5), "detector + MoveNet x1": ({"detect": True}, 1.0)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bench", default="other-val")
    ap.add_argument("--n", type=int, default=None)
    a = ap.parse_args()
    torch.set_num_threads(1)
    ds = open_bench(a.bench, ("rgb", "K", "points2d"))
    n = min(a.n or len(ds), len(ds))
    found = {}
    for name, (change, movenet) in VARIANTS.items():
        cfg = dataclasses.replace(ReconstructorConfig(), **change).as_installed()
        src = make_source("mediapipe", None, "cpu", cfg.flip, cfg.retry, cfg.guard, cfg.keypoint_model, cfg.fallback,
                          cfg.backbone_weight, cfg.search, cfg.detect, movenet)
        pts = np.full((n, 42, 2), np.nan)
        for i in tqdm(range(n), desc=name):
            s = ds[i]
            kp = src(s["rgb"], s["K"].astype(np.float64))
            if kp is not None:
                pts[i] = kp.points2d
        found[name] = pts
    gt = np.stack([ds[i]["points2d"] for i in range(n)]).astype(np.float64)
    both = np.all([~np.isnan(p[:, 0, 0]) for p in found.values()], 0)
    rows, out = [], {}
    for name, pts in found.items():
        err = 100 * np.linalg.norm(pts[both] - gt[both], axis=-1) / box_height(gt[both])[:, None]
        groups = {g: float(np.mean(err[:, idx])) for g, idx in GROUPS.items()}
        out[name] = {"found": float(np.mean(~np.isnan(pts[:, 0, 0]))), "all": float(err.mean()),
                     "median": float(np.median(err)), "groups": groups}
        rows.append([name, f"{100 * out[name]['found']:.1f}", f"{err.mean():.2f}", f"{np.median(err):.2f}",
                     *(f"{v:.2f}" for v in groups.values())])
    md = [f"# The 2D signal on {a.bench}: error of the J+ as % of the person's box height", "",
          "`eval/keypoints_2d.py`: " + __doc__.split("\n\n")[1].replace("\n", " "), "",
          report.table(rows, ["source", "found %", "mean %", "median %", *GROUPS]), "",
          f"{n} images, {int(both.sum())} found by every variant; {report.describe(report.machine())}."]
    report.write(Path(report.RESULTS) / f"keypoints-2d-{a.bench}", {"bench": a.bench, "images": n,
                                                                     "compared": int(both.sum()), "variants": out},
                 "\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
