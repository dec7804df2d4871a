"""``recon synth`` (rendered benchmarks and training data) and ``recon eval`` (methods on a benchmark)."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from recon import report
from recon.bench import runner
from recon.bench.methods import METHODS
from recon.cli.parsing import COUNT, SEED, Parser, actions, add_executor, default, executor_args, number
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


def add_synth(p: Parser) -> None:
    action = actions(p)
    a = action("bench", bench, "render (or finish) a fixed benchmark into the cache")
    a.add_argument("name", choices=list(dataset.BENCHMARKS))
    a.add_argument("--n", type=COUNT, default=None, help="only the first N images")
    add_executor(a, RENDER_WORKERS, "render processes")
    a.add_argument("--verify", action="store_true", help="re-hash the shards; compare with the committed hashes")
    a = action("generate", generate, "render samples of a split into a folder")
    a.add_argument("--out", required=True)
    a.add_argument("--split", default="train", choices=["train", "val", "test"])
    a.add_argument("--seed", type=SEED, default=0)
    a.add_argument("--n", type=COUNT, default=1000)
    add_executor(a, RENDER_WORKERS, "render processes")
    a.add_argument("--no-vertices", action="store_true", help="do not store vertices (smaller shards)")
    a.add_argument("--framing", default="standard", choices=["standard", "wide"],
                   help="wide: framed as the synth-wide benchmarks (512 px, people 30-90 %% of the height, off-centre)")
    a.add_argument("--dressed", type=number(float, 0.0, 1.0), default=0.0,
                   help="share of people dressed in CLOTH3D outfits of the training distribution (DeePSD)")
    a.add_argument("--any-shape", action="store_true",
                   help="bodies of any anny shape (gender anywhere in [0, 1], ages 18-80) instead of the shape prior")
    a.add_argument("--verify", action="store_true", help="re-hash the shards against the manifest")


def add_eval(p: Parser) -> None:
    p.set_defaults(func=evaluate)
    p.add_argument("--bench", default="synth-test", help=", ".join(dataset.BENCHMARKS))
    p.add_argument("--method", nargs="+", default=["mean", "mediapipe"], help=", ".join(METHODS))
    p.add_argument("--n", type=COUNT, default=None, help="only the first N images")
    p.add_argument("--out", default=str(report.RESULTS))
    add_executor(p, 1, "processes scoring the images")


ADD = {"synth": add_synth, "eval": add_eval}
