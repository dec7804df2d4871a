"""Synthetic-sample generation throughput at 256x256, with 1 and 2 worker processes side by side.

    .venv/bin/python benchmarks/bench_synth.py [--n 400]

samples/s for the full pipeline (sample + render + PNG shards on disk), as the marginal rate
between a run of n/4 and a run of n samples (the workers' start-up: imports, body model,
pose/shape pools, is reported apart), and the per-stage cost in one process. Then reading: a
shuffled pass over the stored samples as backbone training reads them (only its CROP_KEYS, a
4-shard cache) against whole shards and a 1-shard cache (the reader before 0.2.0).
-> eval/results/bench-synth.{json,md}
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from recon import report
from recon.backbone.crops import CROP_KEYS
from recon.body import default_body
from recon.synth.dataset import SynthDataset, generate, pack
from recon.synth.scene import SceneSampler

OUT = Path(__file__).resolve().parent.parent / "eval" / "results" / "bench-synth"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=400)
    args = ap.parse_args()
    torch.set_num_threads(1)
    scene = SceneSampler(default_body(), "test", seed=0)
    scene.sample(0)
    t0 = time.perf_counter()
    samples = [scene.sample(i) for i in range(50)]
    t1 = time.perf_counter()
    pack(samples, True)
    t2 = time.perf_counter()
    stages = {"sample + render ms": 1000 * (t1 - t0) / 50, "PNG packing ms": 1000 * (t2 - t1) / 50}
    rows, reading = [], []
    with tempfile.TemporaryDirectory() as keep:
        for workers in (1, 2):
            times = {}
            for n in (args.n // 4, args.n):
                with tempfile.TemporaryDirectory() as d:
                    t = time.perf_counter()
                    generate(Path(d) / "s", "test", 0, n, shard_size=25, workers=workers, progress=False)
                    times[n] = time.perf_counter() - t
                    if workers == 2 and n == args.n:
                        shutil.copytree(Path(d) / "s", Path(keep) / "s")
            a, b = args.n // 4, args.n
            rate = (b - a) / (times[b] - times[a])
            rows.append([workers, rate, times[a] - a / rate, times[b]])
        order = np.random.default_rng(0).permutation(args.n)
        readers = {"whole shards, 1-shard cache": dict(keys=None, cache=1),
                   f"{', '.join(CROP_KEYS)}; 4-shard cache": dict(keys=CROP_KEYS, cache=4)}
        seconds = {}
        for _ in range(2):  # interleaved, best of two
            for name, kw in readers.items():
                ds = SynthDataset(Path(keep) / "s", **kw)
                t = time.perf_counter()
                for i in order:
                    ds[int(i)]
                seconds[name] = min(seconds.get(name, np.inf), time.perf_counter() - t)
        base = seconds["whole shards, 1-shard cache"]
        reading = [[name, args.n / sec, base / sec] for name, sec in seconds.items()]
    data = {"machine": report.machine(), "n": args.n, "one_process": stages, "rows": rows, "reading": reading}
    where = report.describe(data["machine"])
    md = "\n".join(["# Synthetic sample generation (256 x 256, PNG shards on disk)", "",
                    f"`benchmarks/bench_synth.py --n {args.n}`; {where}. One process: "
                    + ", ".join(f"{k} {v:.1f}" for k, v in stages.items()) + " per sample.", "",
                    report.table(rows, ["workers", "samples/s (marginal)", "start-up s", f"{args.n} samples, s"],
                                 ["", ".1f", ".1f", ".1f"]), "",
                    f"Shuffled reading of the {args.n} stored samples (shards of 25, vertices stored), one process:",
                    "", report.table(reading, ["reader", "samples/s", "x whole shards"], ["", ".0f", ".2f"])])
    print(Path(report.write(OUT, data, md)).read_text())


if __name__ == "__main__":
    main()
