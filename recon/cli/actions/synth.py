"""The actions of ``recon synth`` (rendered benchmarks, training data) and ``recon eval`` (benchmarks)."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from recon.bench import runner
from recon.cli.parsing import default, executor_args
from recon.errors import ReconError
from recon.executor import ExecutorConfig
from recon.synth import dataset

RENDER_WORKERS = default(dataset.generate, "workers")


def _verify(out: Path, bench: str | None) -> None:
    bad = dataset.SynthDataset(out).verify()
    if bad:
        raise ReconError(f"shards {bad} differ from the manifest")
    print("all shards match the manifest")
    if bench and dataset.reference_hashes_path(bench).exists():
        diff = dataset.compare_with_reference(bench)
        if diff:
            raise ReconError(f"shards {diff} differ from the committed reference hashes")
        print(f"bit-identical to the reference ({dataset.reference_hashes_path(bench)})")


def bench(args) -> None:
    out = dataset.build_benchmark(args.name, n=args.n, executor=ExecutorConfig(**executor_args(args, RENDER_WORKERS)))
    if args.verify:
        _verify(out, args.name)
    print(f"{out}: {len(dataset.SynthDataset(out))} samples")


def generate(args) -> None:
    cfg = dataset.bench_config("synth-wide-test") if args.framing == "wide" else dataset.SynthConfig()
    cfg = replace(cfg, dressed_prob=args.dressed, any_shape=args.any_shape)
    out = dataset.generate(Path(args.out), args.split, args.seed, args.n, store_vertices=not args.no_vertices,
                           cfg=cfg, executor=ExecutorConfig(**executor_args(args, RENDER_WORKERS)))
    if args.verify:
        _verify(out, None)
    print(f"{out}: {len(dataset.SynthDataset(out))} samples")


def evaluate(args) -> None:
    print(Path(runner.evaluate(args.bench, args.method, n=args.n, out_dir=Path(args.out),
                               executor=ExecutorConfig(**executor_args(args)))).read_text())

