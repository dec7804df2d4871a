"""Paired comparison of two methods on one benchmark (issue 68: a change ships only if other-val
does not get worse).

Reads the per-image numbers ``recon eval`` keeps (eval/results/scores/<bench>/<method>.json) and
prints, for B against A: people found by each (and the difference with a 95 % bootstrap interval),
and on the images both found the mean paired difference of MPJPE-P1 and PA-MPJPE with its 95 %
bootstrap interval (10,000 resamples of the images). ``--json`` writes the same as a record.

    .venv/bin/python eval/compare.py other-val recon-run "recon-run[backbone_weight=0.0]"
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from recon import report
from recon.bench.runner import scores_path


def interval(x: np.ndarray, rng: np.random.Generator, n: int = 10000) -> tuple[float, float, float]:
    """(mean, 2.5 %, 97.5 %) of the mean of ``x`` by the bootstrap."""
    if len(x) == 0:
        return float("nan"), float("nan"), float("nan")
    means = x[rng.integers(0, len(x), (n, len(x)))].mean(1)
    return float(x.mean()), float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def compare(bench: str, a: str, b: str, results: Path = report.RESULTS, seed: int = 0, bench_b: str | None = None
            ) -> dict:
    """B against A on ``bench`` (B's numbers on ``bench_b`` when given: e.g. other-test-gray against
    other-test, the same images in grayscale)."""
    sa = json.loads(scores_path(results, bench, a).read_text())
    sb = json.loads(scores_path(results, bench_b or bench, b).read_text())
    n = min(len(sa["p1"]), len(sb["p1"]))
    rng = np.random.default_rng(seed)
    fa = np.array([v is not None for v in sa["p1"][:n]], float)
    fb = np.array([v is not None for v in sb["p1"][:n]], float)
    both = (fa > 0) & (fb > 0)
    out = {"bench": bench, "a": a, "b": b, "images": n, "found_a": float(fa.mean()), "found_b": float(fb.mean()),
           "found_diff": interval(fb - fa, rng), "both": int(both.sum()),
           "found_b_where_a": float(both.sum() / max(fa.sum(), 1))}
    for key in ("p1", "p2"):
        xa = np.array([v for v, m in zip(sa[key][:n], both, strict=True) if m], float)
        xb = np.array([v for v, m in zip(sb[key][:n], both, strict=True) if m], float)
        out[key] = {"a": float(xa.mean()) if len(xa) else None, "b": float(xb.mean()) if len(xb) else None,
                    "diff": interval(xb - xa, rng)}
    return out


def describe(c: dict) -> str:
    f = c["found_diff"]
    lines = [f"{c['bench']}: B = {c['b']} against A = {c['a']} ({c['images']} images)",
             f"  found: A {c['found_a']:.1%}, B {c['found_b']:.1%}; B - A {f[0]:+.1%} [{f[1]:+.1%}, {f[2]:+.1%}]; "
             f"B where A found: {c['found_b_where_a']:.1%}",
             f"  on the {c['both']} images both found:"]
    for key, label in (("p1", "MPJPE-P1"), ("p2", "PA-MPJPE")):
        d = c[key]["diff"]
        lines.append(f"    {label}: A {c[key]['a']:.1f}, B {c[key]['b']:.1f} mm; B - A {d[0]:+.1f} "
                     f"[{d[1]:+.1f}, {d[2]:+.1f}]")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bench")
    ap.add_argument("a")
    ap.add_argument("b", nargs="+")
    ap.add_argument("--results", default=str(report.RESULTS))
    ap.add_argument("--bench-b", default=None, help="B's benchmark, when another view of the same images")
    ap.add_argument("--json", help="also write the comparisons to this JSON file")
    args = ap.parse_args()
    out = [compare(args.bench, args.a, b, Path(args.results), bench_b=args.bench_b) for b in args.b]
    for c in out:
        print(describe(c))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
