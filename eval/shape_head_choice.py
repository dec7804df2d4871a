"""Which phenotypes ``recon run`` reads from the person's mask (``recon.shape.FROM_MASK``), chosen on synth-val.

    .venv/bin/python eval/shape_head_choice.py --n 500            (from the repository root)

Runs ``recon run``'s keypoint source once on each of the first ``n`` synth-val images (memoised in
the cache: a re-run or another candidate costs no MediaPipe call), then the rest of the pipeline
once per candidate set of phenotypes taken from the shape head instead of SMPLR, and scores each
as ``recon eval`` does (P1 / PA / PVE / IoU, gender right, height correlation, per-phenotype
errors). A tuning set, never a test number. Writes eval/results/shape-head-choice.{json,md}.
"""
from __future__ import annotations

import argparse
import hashlib
import pickle
from pathlib import Path

import torch

from recon import paths, report
from recon.bench import runner
from recon.bench.methods import METHODS, MediaPipeSMPLR
from recon.body import default_body
from recon.keypoints import make_source
from recon.people.mediapipe import DEFAULT_MODEL, resolve_model
from recon.pipeline import Reconstructor
from recon.synth.dataset import SynthDataset, bench_dir

CANDIDATES = {
    "smplr": (),
    "gender-build-proportions": ("gender", "muscle", "weight", "proportions"),
    "all-six": ("gender", "age", "muscle", "weight", "height", "proportions"),
}


class MemoSource:
    """``recon run``'s keypoint source, its answers memoised per image (keyed by the pixels)."""

    name = "mediapipe"

    def __init__(self, path: Path):
        self.path = path
        self.memo = pickle.loads(path.read_bytes()) if path.exists() else {}
        self.source, self.model = None, resolve_model(DEFAULT_MODEL)

    def __call__(self, rgb, k):
        key = hashlib.sha1(rgb.tobytes()).hexdigest()
        if key not in self.memo:
            if self.source is None:
                self.source = make_source("mediapipe", default_body())
            self.memo[key] = self.source(rgb, k)
        return self.memo[key]

    def save(self) -> None:
        paths.atomic_write(self.path, lambda t: Path(t).write_bytes(pickle.dumps(self.memo)))


def candidate(name: str, phenotypes: tuple[str, ...], source: MemoSource) -> type:
    """A benchmark method: ``recon run`` with ``phenotypes`` read from the mask, on memoised keypoints."""

    def init(self, body):
        self.rec = Reconstructor(body=body, source=source, shape_head=bool(phenotypes))
        self.rec.phenotypes_from_mask = phenotypes

    return type(name, (MediaPipeSMPLR,), {"name": name, "__init__": init,
                                          "description": f"from the mask: {', '.join(phenotypes) or 'none'}"})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--only", nargs="*", default=None, help="candidates to run (default: all)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (two runs side by side: 1 each)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    source = MemoSource(paths.cache_dir() / "shape" / f"memo-synth-val-{args.n}.pkl")
    ds = SynthDataset(bench_dir("synth-val"))
    body = default_body()
    rows = []
    for name, phenotypes in CANDIDATES.items():
        if args.only is not None and name not in args.only:
            continue
        METHODS[name] = candidate(name, phenotypes, source)
        rows.append(runner.run_method(name, ds, body, args.n))
        source.save()
    stem = report.RESULTS / "shape-head-choice"
    old = report.read(stem)["rows"] if stem.with_suffix(".json").exists() else []
    fresh = {r["method"]: r for r in rows}
    rows = [fresh.pop(r["method"], r) for r in old] + list(fresh.values())
    data = {"benchmark": "synth-val", "images": args.n, "rows": rows}
    intro = (f"Which phenotypes `recon run` takes from the shape head (`recon.shape.FROM_MASK`): the first "
             f"{args.n} synth-val images, `recon run`'s keypoints memoised, the rest of the pipeline per "
             "candidate (`eval/shape_head_choice.py`). A tuning set, not a test result.\n\n")
    print(report.write(stem, data, intro + runner.render(data).split("\n", 2)[2]))


if __name__ == "__main__":
    main()
