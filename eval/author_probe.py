"""What the authoring model's latent knows, added to eval/results/garment-author.{json,md} for an
outfit without re-running the rest of its report (``recon garment eval --model author`` computes it
too):

    .venv/bin/python eval/author_probe.py [--outfit tshirt-skirt] [--train-sets N]   (repository root)

Needs the outfit's trained model and its simulations (``recon garment train --model author``). The
probe, the latents' spread and the signal: recon/garment/author/curves.py. Also recorded: the
model's same-motion and cross-motion errors on the test windows (``invariance``), so that a model
trained again from the same recipe can be told apart from the one the table's other rows measured.
``--train-sets N``: the learning curve's model trained on N sets instead (its probe is added as a
row of the probe's curve: does the latent learn the parameters from more sets?).
"""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace

from recon import report
from recon.body import default_body
from recon.garment import store
from recon.garment.author.curves import invariance, probe
from recon.garment.author.data import AuthorDataConfig
from recon.garment.author.eval import render
from recon.garment.author.model import AuthorModel
from recon.garment.author.train import AuthorTrainConfig, load_frames, model_path

RESULTS = report.RESULTS / "garment-author"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--train-sets", type=int, default=None)
    a = ap.parse_args()
    t0 = time.time()
    body = default_body()
    path = store.author_path(a.outfit) if a.train_sets is None else model_path(
        AuthorTrainConfig(data=replace(AuthorDataConfig(outfit=a.outfit), train_sets=a.train_sets)))
    model, meta = AuthorModel.load(path)
    dcfg = AuthorDataConfig(**meta["config"]["data"])
    train_f, _, lead = load_frames(dcfg, "train", model.cfg, body)
    test_f, test_sims, _ = load_frames(dcfg, "test", model.cfg, body)
    p = probe(model, train_f, test_f, test_sims)
    p["model_check"] = invariance(model, test_f, lead)
    p["seconds"] = round(time.time() - t0, 1)
    print(json.dumps(p, indent=1))
    data = report.read(RESULTS)
    (entry,) = [r for r in data["outfits"] if r["outfit"] == a.outfit]
    if a.train_sets is None:
        entry["probe"] = p
    else:
        entry.setdefault("probe_curve", {})[str(dcfg.train_sets)] = p
    print(report.write(RESULTS, data, render(data["outfits"])))


if __name__ == "__main__":
    main()
