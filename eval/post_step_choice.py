"""The settings of the garment post-step's strain step (``recon.garment.collide``), chosen on DeePSD's val outfits.

    .venv/bin/python eval/post_step_choice.py            (from the repository root)

DeePSD (the shipped weights) on the 10 val outfits x 5 poses of the val performers
(``recon.garment.deepsd.data``; drapes made by ``recon garment train --model deepsd`` or its data
step), then collision resolution alone and the strain step + collision resolution at each
candidate (iterations, anchor, smoothness): error to the drape, edge error, bending, collision %,
per family, and the post-step's time a frame. A tuning set, never a test number (the test rows are
garment-deepsd.md's). Writes eval/results/garment-post-step-val.{json,md}.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from recon import report
from recon.body import default_body
from recon.garment import store
from recon.garment.collide import CollisionResolver
from recon.garment.deepsd.data import DeePSDDataConfig
from recon.garment.deepsd.eval import METRICS, predict, scores
from recon.garment.deepsd.model import DeePSD
from recon.garment.deepsd.train import load_samples

# (strain iterations, anchor, smoothness); 0 iterations: collision resolution alone
CANDIDATES = ((0, 0.01, 0.0), (5, 0.01, 0.0), (5, 0.01, 10.0), (10, 0.01, 0.0), (10, 0.01, 1.0), (10, 0.01, 10.0),
              (10, 0.003, 0.0), (10, 0.003, 1.0), (10, 0.03, 0.0), (10, 0.03, 1.0), (20, 0.01, 0.0), (20, 0.01, 1.0),
              (20, 0.003, 1.0))


def label(c: tuple) -> str:
    return "collision resolution alone" if c[0] == 0 else f"{c[0]} iterations, anchor {c[1]:g}, smooth {c[2]:g}"


@torch.no_grad()
def evaluate(candidates=CANDIDATES, log=print) -> dict:
    torch.set_num_threads(1)
    body = default_body()
    model = DeePSD.load(store.deepsd_path())[0]
    samples = load_samples(body, "val", DeePSDDataConfig())
    if not samples:
        raise FileNotFoundError("no DeePSD val drapes: run `recon garment train --model deepsd` (its data step)")
    per: dict[str, list[dict]] = {}
    ms: dict[str, list[float]] = {}
    for s in samples:
        v = predict("ours", s, {"ours": model}, {})
        rows = {"DeePSD": v, "drape (ground truth)": s.drapes}
        for c in candidates:
            t0 = time.perf_counter()
            res = CollisionResolver(s.graph.faces, s.layer, strain_iters=c[0], strain_anchor=c[1], strain_smooth=c[2])
            rows[label(c)] = res(v, s.body_v, body.faces, rest=s.graph.rest)
            ms.setdefault(label(c), []).append(1000 * (time.perf_counter() - t0) / len(v))
        for k, x in rows.items():
            per.setdefault(k, []).append(scores(x, s) | {"family": s.family})
        log(f"{s.family}: " + ", ".join(f"{k} {per[k][-1]['error_mm']:.1f}" for k in rows))
    fams = sorted({r["family"] for r in per["DeePSD"]})
    out = {"outfits": len(samples), "poses": int(len(samples[0].rotmats)), "rows": {}, "families": {}}
    for k, rs in per.items():
        out["rows"][k] = {m: float(np.mean([r[m] for r in rs])) for m in METRICS} | (
            {"ms": float(np.mean(ms[k]))} if k in ms else {})
        out["families"][k] = {f: {m: float(np.mean([r[m] for r in rs if r["family"] == f])) for m in METRICS}
                              for f in fams}
    return out


def render(data: dict) -> str:
    rows = [[k] + [r[m] for m in METRICS] + [r.get("ms")] for k, r in data["rows"].items()]
    fams = list(next(iter(data["families"].values())))
    fam_rows = [[k] + [f"{data['families'][k][f]['error_mm']:.1f} / {data['families'][k][f]['edge_mm']:.2f} / "
                       f"{data['families'][k][f]['collision_pct']:.2f}" for f in fams] for k in data["rows"]]
    return "\n".join([
        "# Garment post-step: the strain step's settings on DeePSD's val outfits", "",
        f"{data['outfits']} val outfits x {data['poses']} val-performer poses, the shipped DeePSD, then the post-step "
        "(recon.garment.collide) at each candidate; error = mean vertex distance to the drape. A tuning set: the "
        "test rows are in garment-deepsd.md. Time: the post-step a frame on 1 thread, its factorisation included "
        "(once per outfit, here per 5 frames).", "",
        report.table(rows, ["method", "error mm", "edge mm", "bend", "collision %", "ms / frame"],
                     ["", ".2f", ".3f", ".4f", ".3f", ".0f"]), "",
        "Per family (error mm / edge mm / collision %):", "",
        report.table(fam_rows, ["method"] + fams)])


def main() -> None:
    argparse.ArgumentParser(description=__doc__.split("\n")[0]).parse_args()
    data = evaluate()
    print(report.write(Path(report.RESULTS) / "garment-post-step-val", data, render(data)))


if __name__ == "__main__":
    main()
