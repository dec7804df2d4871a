"""One backbone pass (size `base`, 128 px, batch 1, 1 thread) with the hourglass' own stem and
with the EfficientNet-Lite0 stem, both BN-folded + traced as at inference, timed side by side.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_backbone_stem.py [--repeats 7]

Untrained weights: speed does not depend on them.
"""
from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace

import torch

from recon.backbone.hourglass import SIZES, StackedHourglass
from recon.backbone.model import inference_copy, traced


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--size", default="base", choices=list(SIZES))
    a = ap.parse_args()
    torch.set_num_threads(1)
    cfg = SIZES[a.size]
    nets = {stem: traced(inference_copy(StackedHourglass(replace(cfg, stem=stem)).eval()), cfg.input_size)
            for stem in ("hourglass", "efficientnet-lite0")}
    x = torch.rand(1, cfg.input_size, cfg.input_size, 3).permute(0, 3, 1, 2)  # channels-last, as in Backbone.grids
    ms = {k: [] for k in nets}
    with torch.no_grad():
        for net in nets.values():
            for _ in range(5):
                net(x)
        for _ in range(a.repeats):  # interleaved, so drift on this machine hits both alike
            for k, net in nets.items():
                t = time.perf_counter()
                for _ in range(10):
                    net(x)
                ms[k].append((time.perf_counter() - t) * 100)
    base = statistics.median(ms["hourglass"])
    for k, v in ms.items():
        print(f"{k:20s} {statistics.median(v):6.1f} ms per pass  (x{statistics.median(v) / base:.2f})")


if __name__ == "__main__":
    main()
