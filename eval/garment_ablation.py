"""PBNS ablation: train one outfit with one config change, evaluate on the held-out test poses.

    OMP_NUM_THREADS=1 .venv/bin/python eval/garment_ablation.py NAME THREADS '{"edge.weight": 3e4}' \
        [--outfit top-shorts]

Overrides are GarmentTrainConfig fields ("epochs", "lr_psd") or "<term>.<field>" for a nested
config ("edge.weight", "collision.weight", "gravity.weight", "model.embedding"). Weights go to
/tmp/pbns-ablation/NAME.pt (never over the shipped ones); prints one JSON line "RESULT ...",
with the error to the newton drapes when `recon garment reference` has cached them.
Results: eval/results/garment-ablation-top-shorts.md.
"""
from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import torch

from recon.body import default_body
from recon.garment.pbns import train as T
from recon.garment.pbns.eval import evaluate
from recon.garment.pbns.model import PBNS
from recon.garment.pbns.reference_eval import error_to_drapes


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("name")
    ap.add_argument("threads", type=int)
    ap.add_argument("overrides", nargs="?", default="{}")
    ap.add_argument("--outfit", default="top-shorts")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    cfg = T.GarmentTrainConfig(outfit=a.outfit)
    for key, value in json.loads(a.overrides).items():
        if "." in key:
            part, fld = key.split(".")
            setattr(cfg, part, replace(getattr(cfg, part), **{fld: value}))
        else:
            setattr(cfg, key, value)
    body = default_body()
    out = Path("/tmp/pbns-ablation") / f"{a.name}.pt"
    out.parent.mkdir(parents=True, exist_ok=True)
    T.train(body, cfg, out=out)
    r = evaluate(body, cfg.outfit, n_poses=500, weights=out)
    model, ck = PBNS.load(out)
    # None without cached drapes
    r["error_to_drapes"] = error_to_drapes(model, cfg.outfit, ck["shape"], body, ck["layer"].numpy())
    print("RESULT", a.name, json.dumps(r))


if __name__ == "__main__":
    main()
