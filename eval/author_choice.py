"""The authoring model's base cloth and the network's share between keyframes, chosen on the val windows.

    .venv/bin/python eval/author_choice.py [--outfit tshirt-skirt]      (from the repository root)

Two models of the default recipe and data, their offsets taken from PBNS's drape (the models
before 0.20.0) and from NCS's cloth, each trained unless in the cache as
``author_<outfit>-base-<base>.pt``; the propagation of each from 1-20 % keyframes on the val
windows (2 held-out parameter sets x 2 windows of the val performers) with the decoded cloth's
share between keyframes at 0, 0.25, 0.5, 0.75 and 1 (0: the keyframes' offsets interpolated).
The choice: the lowest mean over the keyframe ratios. A tuning set, never a test number (those
are garment-author.md's). Writes eval/results/garment-author-choice-val.{json,md}.
"""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from recon import report
from recon.body import default_body
from recon.garment import store
from recon.garment.author.data import AuthorDataConfig, plan, sim_folder
from recon.garment.author.eval import RATIOS, propagation
from recon.garment.author.model import AuthorConfig, AuthorModel
from recon.garment.author.train import AuthorTrainConfig, hanging_outfit, train
from recon.garment.pbns.model import PBNS

BASES = ("pbns", "ncs")
SHARES = (0.0, 0.25, 0.5, 0.75, 1.0)


def base_model(outfit: str, base: str) -> Path:
    """The default recipe's model with offsets from ``base``, trained into the cache unless there."""
    path = store.author_path(f"{outfit}-base-{base}")
    if not path.exists():
        cfg = AuthorTrainConfig(data=AuthorDataConfig(outfit=outfit), model=AuthorConfig(base=base))
        train(cfg, simulate=False, path=path)
    return path


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--out", default=str(report.RESULTS))
    a = ap.parse_args()
    body = default_body()
    data = AuthorDataConfig(outfit=a.outfit)
    sims = [s for s in plan(data) if s.split == "val"]
    pbns, _ = PBNS.load(store.trained_pbns(a.outfit))
    shape = hanging_outfit(body, a.outfit).shape
    rows = []
    for base in BASES:
        model = AuthorModel.load(base_model(a.outfit, base))[0]
        for share in SHARES:
            model.cfg = replace(model.cfg, base=base, network_share=share)
            p = propagation(model, sims, sim_folder(data), data.lead, body, pbns, shape, log=lambda *x: None,
                            baselines=False)
            errors = {r: v["ours"] for r, v in p["ratios"].items()}
            rows.append({"base": base, "network_share": share, "mm": errors,
                         "mean_mm": float(np.mean(list(errors.values())))})
            print(rows[-1], flush=True)
    best = min(rows, key=lambda r: r["mean_mm"])
    result = {"outfit": a.outfit, "split": "val", "windows": len(sims), "rows": rows,
              "choice": {"base": best["base"], "network_share": best["network_share"]}}
    print(report.write(Path(a.out) / "garment-author-choice-val", result, render(result)))


def render(r: dict) -> str:
    ratios = [f"{x:g}" for x in RATIOS]
    heads = ["offsets from", "network share"] + [f"{float(x) * 100:g} %" for x in ratios] + ["mean"]
    table = report.table([[row["base"], f"{row['network_share']:g}"] + [row["mm"][x] for x in ratios] + [row["mean_mm"]]
                          for row in r["rows"]], heads)
    c = r["choice"]
    return "\n".join([
        f"# Authoring: base cloth and network share on the val windows ({r['outfit']})", "",
        "`python eval/author_choice.py` (a tuning set: the test rows are garment-author.md's). Mean vertex error "
        f"(mm) of the hanging part over the frames after the lead, {r['windows']} val simulations (held-out "
        "parameter sets on the val performers), keyframes on 1-20 % of the frames.", "",
        table, "",
        f"Chosen (lowest mean): offsets from {c['base']}, network share {c['network_share']:g}."])


if __name__ == "__main__":
    main()
