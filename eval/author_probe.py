"""What the authoring model's latent knows, added to eval/results/garment-author.{json,md} for an
outfit without re-running the rest of its report (``recon garment eval --model author`` computes it
too):

    .venv/bin/python eval/author_probe.py [--outfit tshirt-skirt]      (from the repository root)

Needs the outfit's trained model and its simulations (``recon garment train --model author``). The
probe, the latents' spread and the signal: recon/garment/author/curves.py. Also recorded: the
model's same-motion and cross-motion errors on the test windows (``invariance``), so that a model
trained again from the same recipe can be told apart from the one the table's other rows measured.
"""
from __future__ import annotations

import argparse
import json
import time

from recon import report
from recon.body import default_body
from recon.garment import store
from recon.garment.author.curves import invariance, probe
from recon.garment.author.data import AuthorDataConfig
from recon.garment.author.eval import render
from recon.garment.author.model import AuthorModel
from recon.garment.author.train import load_frames

RESULTS = report.RESULTS / "garment-author"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--outfit", default="tshirt-skirt")
    a = ap.parse_args()
    t0 = time.time()
    body = default_body()
    model, meta = AuthorModel.load(store.author_path(a.outfit))
    dcfg = AuthorDataConfig(**meta["config"]["data"])
    train_f, _, lead = load_frames(dcfg, "train", model.cfg, body)
    test_f, test_sims, _ = load_frames(dcfg, "test", model.cfg, body)
    p = probe(model, train_f, test_f, test_sims)
    p["model_check"] = invariance(model, test_f, lead)
    p["seconds"] = round(time.time() - t0, 1)
    print(json.dumps(p, indent=1))
    data = report.read(RESULTS)
    (entry,) = [r for r in data["outfits"] if r["outfit"] == a.outfit]
    entry["probe"] = p
    print(report.write(RESULTS, data, render(data["outfits"])))


if __name__ == "__main__":
    main()
