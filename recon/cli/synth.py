"""``recon synth`` (rendered benchmarks and training data) and ``recon eval`` (methods on a benchmark)."""
from __future__ import annotations

from recon.cli.parsing import COUNT, SEED, Parser, actions, add_executor, known, number, run_by


def add_synth(p: Parser) -> None:
    action = actions(p)
    workers = known("recon.synth.dataset:generate.workers")
    a = action("bench", "synth:bench", "render (or finish) a fixed benchmark into the cache")
    a.add_argument("name", choices=list(known("recon.synth.dataset:BENCHMARKS")))
    a.add_argument("--n", type=COUNT, default=None, help="only the first N images")
    add_executor(a, workers, "render processes")
    a.add_argument("--verify", action="store_true", help="re-hash the shards; compare with the committed hashes")
    a = action("generate", "synth:generate", "render samples of a split into a folder")
    a.add_argument("--out", required=True)
    a.add_argument("--split", default="train", choices=["train", "val", "test"])
    a.add_argument("--seed", type=SEED, default=0)
    a.add_argument("--n", type=COUNT, default=1000)
    add_executor(a, workers, "render processes")
    a.add_argument("--no-vertices", action="store_true", help="do not store vertices (smaller shards)")
    a.add_argument("--framing", default="standard", choices=["standard", "wide"],
                   help="wide: framed as the synth-wide benchmarks (512 px, people 30-90 %% of the height, off-centre)")
    a.add_argument("--dressed", type=number(float, 0.0, 1.0), default=0.0,
                   help="share of people dressed in CLOTH3D outfits of the training distribution (DeePSD)")
    a.add_argument("--any-shape", action="store_true",
                   help="bodies of any anny shape (gender anywhere in [0, 1], ages 18-80) instead of the shape prior")
    a.add_argument("--verify", action="store_true", help="re-hash the shards against the manifest")


def add_eval(p: Parser) -> None:
    p.set_defaults(func=run_by("synth:evaluate"))
    p.add_argument("--bench", default="synth-test", help=", ".join(known("recon.synth.dataset:BENCHMARKS")))
    p.add_argument("--method", nargs="+", default=["mean", "mediapipe"],
                   help=", ".join(known("recon.bench.methods:METHODS")))
    p.add_argument("--n", type=COUNT, default=None, help="only the first N images")
    p.add_argument("--out", default=str(known("recon.report:RESULTS")))
    add_executor(p, 1, "processes scoring the images")


ADD = {"synth": add_synth, "eval": add_eval}

