"""Synthetic-sample generation throughput at 256x256, measured side by side in one run.

    .venv/bin/python benchmarks/bench_synth.py [--n 400]

Prints samples/s for the full pipeline (sample + render + PNG shards on disk) with 1 and 2
worker processes, and the per-stage cost in one process. Throughput is the marginal rate
(extra samples / extra seconds between a run of n/4 and a run of n samples), so the workers'
start-up (imports, body model, pose/shape pools: a few seconds) is reported apart.
Target (issue 3): >= 40 samples/s on the 2-core machine.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=400)
    args = ap.parse_args()
    import torch

    torch.set_num_threads(1)
    from recon.body import default_body
    from recon.synth.dataset import _pack, generate
    from recon.synth.scene import SceneSampler

    scene = SceneSampler(default_body(), "test", seed=0)
    scene.sample(0)
    t0 = time.perf_counter()
    samples = [scene.sample(i) for i in range(50)]
    t1 = time.perf_counter()
    _pack(samples, True)
    t2 = time.perf_counter()
    print(f"one process: sample+render {1000 * (t1 - t0) / 50:.1f} ms, PNG packing {1000 * (t2 - t1) / 50:.1f} ms per sample")
    for workers in (1, 2):
        times = {}
        for n in (args.n // 4, args.n):
            with tempfile.TemporaryDirectory() as d:
                t = time.perf_counter()
                generate(Path(d) / "s", "test", 0, n, shard_size=25, workers=workers, progress=False)
                times[n] = time.perf_counter() - t
        a, b = args.n // 4, args.n
        rate = (b - a) / (times[b] - times[a])
        startup = times[a] - a / rate
        print(f"workers={workers}: {rate:.1f} samples/s marginal; start-up {startup:.1f} s; "
              f"{b} samples in {times[b]:.1f} s all included")


if __name__ == "__main__":
    main()
