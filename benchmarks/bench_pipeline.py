"""Latency of the image pipeline, batch 1, per stage (median over repeats on the bundled photos).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_pipeline.py [--repeats 10]

Stages: MediaPipe Pose, adapter, SMPLR (DAE + Omega + Psi + full anny mesh) + placement, and the
optional 2D fit (`recon run` default: 30 steps). Prints ms and each stage's share of the total.
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch

from recon import io
from recon.demo import example_photos
from recon.pipeline import Reconstructor, default_intrinsics


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=10)
    a = ap.parse_args()
    torch.set_num_threads(1)
    rec = Reconstructor(refine_steps=30)
    images = [io.load_image(p) for p in example_photos()]
    times: dict[str, list[float]] = {"mediapipe": [], "adapter": [], "smplr+mesh+place": [], "2D fit (30 steps)": []}
    for _ in range(a.repeats):
        for img in images:
            k = default_intrinsics(*img.shape[:2])
            t0 = time.perf_counter()
            mp = rec.source.mp(img)
            t1 = time.perf_counter()
            rec.source.adapter.predict(mp, k)
            t2 = time.perf_counter()
            rec.refine_steps = 0
            r0 = rec.batch([img], [k])[0]  # includes MediaPipe + adapter again: subtracted below
            t3 = time.perf_counter()
            rec.refine_steps = 30
            r = rec.batch([img], [k])[0]
            times["mediapipe"].append((t1 - t0) * 1000)
            times["adapter"].append((t2 - t1) * 1000)
            times["smplr+mesh+place"].append((t3 - t2) * 1000 - r0.timings_ms["keypoints"])
            times["2D fit (30 steps)"].append(r.timings_ms["refine"])
    med = {k: statistics.median(v) for k, v in times.items()}
    base = med["mediapipe"] + med["adapter"] + med["smplr+mesh+place"]
    print(f"{len(images)} photos x {a.repeats} repeats, 1 thread, batch 1 (median ms)\n")
    print("| stage | ms | share of the pipeline without fit |\n|---|---|---|")
    for k, v in med.items():
        print(f"| {k} | {v:.1f} | {v / base:.2f} |")
    print(f"| **total without fit** | **{base:.1f}** | 1.00 |\n| total with fit | {base + med['2D fit (30 steps)']:.1f} | "
          f"{(base + med['2D fit (30 steps)']) / base:.2f} |")


if __name__ == "__main__":
    main()
