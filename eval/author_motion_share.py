"""Train parameter sets on shared motions against each set on its own, chosen on the val windows.

    .venv/bin/python eval/author_motion_share.py [--outfit tshirt-skirt] [--share 4]    (repository root)

The probe (recon/garment/author/curves.py) found the default plan's encoder telling its 32 train
sets apart by their motions: each set is simulated on chunks no other set has, so material and
motion are confounded. Here the same recipe and frame budget with ``AuthorDataConfig.motion_share``
sets on each chunk (``--share``; the model ``author_<outfit>-share-<k>.pt``, trained unless in the
cache) against the default model: on the val windows (2 held-out parameter sets x 2 windows of the
val performers), the propagation from 1-20 % keyframes, the decoder without residuals from one
window's keyframes (same motion) and from the other window's (the material carried), and the
probe. A tuning set, never a test number. Writes eval/results/garment-author-share-val.{json,md}.
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from recon import report
from recon.body import default_body
from recon.garment import store
from recon.garment.author.curves import invariance, probe, vertex_error
from recon.garment.author.data import AuthorDataConfig, sim_folder
from recon.garment.author.eval import RATIOS, keyframes, propagation
from recon.garment.author.model import AuthorModel
from recon.garment.author.train import AuthorTrainConfig, hanging_outfit, load_frames, train
from recon.garment.pbns.model import PBNS

RESULTS = report.RESULTS / "garment-author-share-val"


def no_residual(model: AuthorModel, f, sims, lead: int) -> dict:
    """The decoder alone (no keyframe residuals) from 2 keyframes' z of the same window, and of the
    other window of the same set (the material carried), mm on the hanging part after the lead."""
    same, carried, z_of = [], [], {}
    for k, s in enumerate(sims):
        rows = np.nonzero(f.sim.numpy() == k)[0]
        off, sig = f.offsets[rows].float(), f.sig[rows]
        keys = [i - lead for i in keyframes(len(rows) + lead, lead, RATIOS[0]) if i >= lead]
        z = model.latent(off[keys], sig[keys]).mean(0, keepdim=True)
        z_of[(s.set, s.chunk.clip, s.chunk.start)] = z
        same.append(vertex_error(model.offsets(z.expand(len(rows), -1), sig), off))
    for k, s in enumerate(sims):
        other = [z for (st, c, a), z in z_of.items() if st == s.set and (c, a) != (s.chunk.clip, s.chunk.start)]
        if other:
            rows = np.nonzero(f.sim.numpy() == k)[0]
            off, sig = f.offsets[rows].float(), f.sig[rows]
            carried.append(vertex_error(model.offsets(other[0].expand(len(rows), -1), sig), off))
    return {"same_window_mm": float(np.mean(same)), "carried_mm": float(np.mean(carried)) if carried else None}


def render(rows: dict) -> str:
    names = list(rows)
    ratios = list(rows[names[0]]["propagation"]["ratios"])
    heads = ["model"] + [f"{float(r) * 100:g} %" for r in ratios] + ["mean", "no residual, same window",
                                                                   "no residual, carried", "probe R^2 (val sims)"]
    table = [[n] + [r["propagation"]["ratios"][x]["ours"] for x in ratios]
             + [float(np.mean([r["propagation"]["ratios"][x]["ours"] for x in ratios])),
                r["no_residual"]["same_window_mm"], r["no_residual"]["carried_mm"],
                float(np.mean(r["probe"]["features"]["latent z"]["test_sims_r2"]))] for n, r in rows.items()]
    lines = ["# Keyframe authoring: train sets on shared motions (val windows)", "", __doc__.split("\n\n")[2].replace(
        "\n", " "), "", report.table(table, heads, ["s"] + [".1f"] * (len(heads) - 2) + [".2f"]), ""]
    for n, r in rows.items():
        s = r["probe"]["spread"]
        lines += [f"{n}: latents' spread within a set against between sets {s['test']['ratio']:.2f} on val "
                  f"({s['train']['ratio']:.3g} on its train sets); same motion {r['invariance']['same_motion_mm']:.1f} "
                  f"mm, cross-motion {r['invariance']['cross_motion_mm']:.1f} mm.", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--share", type=int, default=4)
    a = ap.parse_args()
    body = default_body()
    hanging = hanging_outfit(body, a.outfit)
    pbns, _ = PBNS.load(store.trained_pbns(a.outfit))
    rows = {}
    for share in (1, a.share):
        data = replace(AuthorDataConfig(outfit=a.outfit), motion_share=share)
        path = store.author_path(a.outfit)
        if share != 1:
            path = path.with_name(f"author_{a.outfit}-share-{share}.pt")
            if not path.exists():
                train(AuthorTrainConfig(data=data), path=path)
        model, _ = AuthorModel.load(path)
        folder = sim_folder(data)
        train_f, _, lead = load_frames(data, "train", model.cfg, body)
        val_f, val_sims, _ = load_frames(data, "val", model.cfg, body)
        name = "each set its own motions (default)" if share == 1 else f"{share} sets on each motion"
        rows[name] = {"share": share, "propagation": propagation(model, val_sims, folder, lead, body, pbns,
                                                                  hanging.shape, baselines=False),
                      "no_residual": no_residual(model, val_f, val_sims, lead),
                      "invariance": invariance(model, val_f, lead),
                      "probe": probe(model, train_f, val_f, val_sims)}
        print(name, {k: v for k, v in rows[name].items() if k != "probe"})
    print(report.write(RESULTS, {"outfit": a.outfit, "rows": rows}, render(rows)))


if __name__ == "__main__":
    main()
