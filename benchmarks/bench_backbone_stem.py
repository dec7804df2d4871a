"""One backbone pass (size `base`, 128 px, batch 1) with the hourglass' own stem and with the
EfficientNet-Lite0 stem, both BN-folded + traced as at inference, timed side by side.

    .venv/bin/python benchmarks/bench_backbone_stem.py [--threads 1] [--rounds 5]

Untrained weights: speed does not depend on them. -> eval/results/bench-backbone-stem.{json,md}
"""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import torch

from recon import report
from recon.backbone.hourglass import SIZES, StackedHourglass
from recon.backbone.model import inference_copy, traced
from recon.timing import compare

OUT = Path(__file__).resolve().parent.parent / "eval" / "results" / "bench-backbone-stem"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--size", default="base", choices=list(SIZES))
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    cfg = SIZES[a.size]
    nets = {stem: traced(inference_copy(StackedHourglass(replace(cfg, stem=stem)).eval()), cfg.input_size)
            for stem in ("hourglass", "efficientnet-lite0")}
    x = torch.rand(1, cfg.input_size, cfg.input_size, 3).permute(0, 3, 1, 2)  # channels-last, as in Backbone.grids
    with torch.no_grad():
        ms = compare({k: (lambda n=n: n(x)) for k, n in nets.items()}, rounds=a.rounds)
    rows = [[k, v, v / ms["hourglass"]] for k, v in ms.items()]
    data = {"machine": report.machine(), "size": a.size, "ms_per_pass": ms}
    where = report.describe(data["machine"])
    md = "\n".join([f"# One backbone pass: the two stems (size `{a.size}`, batch 1, traced)", "",
                    f"`benchmarks/bench_backbone_stem.py --threads {a.threads}`; {where}", "",
                    report.table(rows, ["stem", "ms per pass", "x hourglass stem"], ["", ".1f", ".2f"])])
    print(Path(report.write(OUT, data, md)).read_text())


if __name__ == "__main__":
    main()
