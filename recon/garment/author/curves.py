"""What the intrinsic latent knows (issue: find the term that keeps the space from holding the
material), beside the authoring table:

- a linear probe from a frame's latent z to the true intrinsic parameters (in [0, 1], the ranges'
  scale), ridge-fitted on the train frames, its strength chosen by holding out train parameter
  sets; R^2 on held-out sets (cross-validated over the train sets, and on the test sets), for z
  and, as the data's own ceiling, for the shape descriptor S (the cloth without its motion);
- the spread of one set's latents across motions against the spread across sets;
- the signal: how far the simulations of different parameter sets lie apart on the same motion,
  against how far the decoder's cloth of their latents lies apart on it.

Also the motion-invariant encoding's check (``invariance``: same-motion and cross-motion errors).
"""
from __future__ import annotations

import numpy as np
import torch

from recon import report
from recon.garment.author.data import NAMES, Sim
from recon.garment.author.train import Frames

LAMBDAS = (1e-2, 1e-1, 1.0, 10.0, 100.0, 1e3, 1e4)
FOLDS = 8  # train parameter sets held out together when choosing the ridge strength
CHUNK = 512


def vertex_error(a: torch.Tensor, b: torch.Tensor) -> float:
    """Mean per-vertex distance (mm)."""
    return float((a - b).norm(dim=-1).mean()) * 1000


def invariance(model, f: Frames, lead: int) -> dict:
    """Same-motion reconstruction error and cross-motion error (z of the middle frame of each window
    decoded on the other windows of its parameter set), mm."""
    with torch.no_grad():
        floor = model.descriptor.decode(model.descriptor.encode(f.offsets))
        z = model.latent(f.offsets, f.sig)
        same = model.offsets(z, f.sig)
    cross = []
    for s in torch.unique(f.set_id):
        sims = torch.unique(f.sim[f.set_id == s])
        for a in sims:
            mine = torch.nonzero(f.sim == a)[:, 0]
            ref = mine[len(mine) // 2]
            for b in sims:
                if b == a:
                    continue
                other = torch.nonzero(f.sim == b)[:, 0]
                dec = model.offsets(z[ref].expand(len(other), -1), f.sig[other])
                cross.append(vertex_error(dec, f.offsets[other]))
    return {"descriptor_mm": vertex_error(floor, f.offsets), "same_motion_mm": vertex_error(same, f.offsets),
            "cross_motion_mm": float(np.mean(cross))}


def ridge(x: np.ndarray, y: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ridge regression on standardised features: (feature mean, scale, weights (D, P), bias (P,))."""
    mu, sd = x.mean(0), x.std(0) + 1e-8
    xs = (x - mu) / sd
    w = np.linalg.solve(xs.T @ xs + lam * len(x) * np.eye(x.shape[1]), xs.T @ (y - y.mean(0)))
    return mu, sd, w, y.mean(0)


def predict(fit: tuple, x: np.ndarray) -> np.ndarray:
    mu, sd, w, b = fit
    return (x - mu) / sd @ w + b


def r2(pred: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Coefficient of determination per column (1: exact; 0: no better than the mean; < 0: worse)."""
    return 1.0 - ((pred - y) ** 2).sum(0) / np.maximum(((y - y.mean(0)) ** 2).sum(0), 1e-12)


def set_folds(groups: np.ndarray, folds: int) -> list[np.ndarray]:
    """The frames of each of ``folds`` groups of parameter sets (sets dealt in turn)."""
    sets = np.unique(groups)
    return [np.isin(groups, sets[k::folds]) for k in range(min(folds, len(sets)))]


def held_out_r2(x: np.ndarray, y: np.ndarray, groups: np.ndarray, lam: float) -> np.ndarray:
    """R^2 per parameter of predictions for each fold of sets by a probe fitted on the others."""
    pred = np.zeros_like(y)
    for held in set_folds(groups, FOLDS):
        pred[held] = predict(ridge(x[~held], y[~held], lam), x[held])
    return r2(pred, y)


def fit_probe(x: np.ndarray, y: np.ndarray, groups: np.ndarray) -> tuple[tuple, float, np.ndarray]:
    """The probe with the ridge strength whose cross-validated R^2 (held-out sets) is highest: (fit,
    strength, that R^2 per parameter)."""
    scores = {lam: held_out_r2(x, y, groups, lam) for lam in LAMBDAS}
    lam = max(scores, key=lambda k: scores[k].mean())
    return ridge(x, y, lam), lam, scores[lam]


def per_sim(values: np.ndarray, sims: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each simulation's mean of ``values`` and the simulations' ids."""
    ids = np.unique(sims)
    return np.stack([values[sims == s].mean(0) for s in ids]), ids


@torch.no_grad()
def features(model, f: Frames) -> dict[str, np.ndarray]:
    """Per frame: the latent z and the shape descriptor S (the cloth alone, no motion)."""
    z, s = [], []
    for a in range(0, len(f.offsets), CHUNK):
        off, sig = f.offsets[a:a + CHUNK].float(), f.sig[a:a + CHUNK]
        z.append(model.latent(off, sig))
        s.append(model.descriptor.encode(off))
    return {"latent z": torch.cat(z).double().numpy(), "descriptor S": torch.cat(s).double().numpy()}


def spread(z: np.ndarray, f: Frames) -> dict:
    """Across the simulations of ``f``: the variance of each simulation's mean z about its set's mean
    (motion) and of the sets' means about theirs (material), summed over z's dimensions."""
    means, ids = per_sim(z, f.sim.numpy())
    sets = np.array([int(f.set_id[f.sim == i][0]) for i in ids])
    set_means = {s: means[sets == s].mean(0) for s in np.unique(sets)}
    within = float(np.mean([((m - set_means[s]) ** 2).sum() for m, s in zip(means, sets)]))
    centre = np.mean(list(set_means.values()), 0)
    between = float(np.mean([((m - centre) ** 2).sum() for m in set_means.values()]))
    return {"within_set": within, "between_sets": between, "ratio": within / max(between, 1e-12)}


@torch.no_grad()
def signal(model, f: Frames, plan: list[Sim]) -> dict:
    """On each window simulated with several parameter sets (``plan``: the simulations ``f.sim``
    indexes): the mean vertex distance (mm) between two sets' simulations, between the decoder's
    cloth from their mean latents (each set's z averaged over the window's frames), and of a
    simulation from the base cloth (its offsets' size)."""
    sims = f.sim.numpy()
    windows: dict[tuple, list[int]] = {}
    for i in np.unique(sims):
        c = plan[int(i)].chunk
        windows.setdefault((c.clip, c.start, c.frames), []).append(int(i))
    true, decoded = [], []
    for ids in windows.values():
        if len(ids) < 2:
            continue
        rows = [np.nonzero(sims == i)[0] for i in ids]
        off = [f.offsets[r].float() for r in rows]
        sig = f.sig[rows[0]]
        dec = [model.offsets(model.latent(o, sig).mean(0, keepdim=True).expand(len(o), -1), sig) for o in off]
        for a in range(len(ids)):
            for b in range(a + 1, len(ids)):
                true.append(float((off[a] - off[b]).norm(dim=-1).mean()) * 1000)
                decoded.append(float((dec[a] - dec[b]).norm(dim=-1).mean()) * 1000)
    size = float(f.offsets.float().norm(dim=-1).mean()) * 1000
    return {"pairs": len(true), "between_sets_mm": float(np.mean(true)) if true else None,
            "decoded_between_sets_mm": float(np.mean(decoded)) if decoded else None, "from_base_mm": size}


def probe(model, train_f: Frames, test_f: Frames, test_plan: list[Sim]) -> dict:
    """The tables of the module doc for a trained authoring ``model`` (its train and held-out frames;
    ``test_plan``: the held-out simulations ``test_f.sim`` indexes)."""
    out = {"parameters": list(NAMES), "features": {}}
    tr, te = features(model, train_f), features(model, test_f)
    y_tr, y_te = train_f.theta.numpy().astype(np.float64), test_f.theta.numpy().astype(np.float64)
    for name in tr:
        fit, lam, cv = fit_probe(tr[name], y_tr, train_f.set_id.numpy())
        pred = predict(fit, te[name])
        sim_pred, ids = per_sim(pred, test_f.sim.numpy())
        sim_true, _ = per_sim(y_te, test_f.sim.numpy())
        out["features"][name] = {"lambda": lam, "train_sets_held_out_r2": cv.round(3).tolist(),
                                 "test_frames_r2": r2(pred, y_te).round(3).tolist(),
                                 "test_sims_r2": r2(sim_pred, sim_true).round(3).tolist()}
    out["spread"] = {"train": spread(tr["latent z"], train_f), "test": spread(te["latent z"], test_f)}
    out["signal"] = signal(model, test_f, test_plan)
    return out


def render_probe(p: dict, table: dict | None = None, curve: dict | None = None) -> list[str]:
    """The probe's Markdown section; ``table``: the report's own invariance row of the model, to
    compare with the probed model's (``p["model_check"]``, where the probe ran on its own);
    ``curve``: {train sets: probe} of the learning curve's models."""
    names = p["parameters"]
    rows = []
    for feat, r in p["features"].items():
        for key, label in (("train_sets_held_out_r2", "train sets held out (CV)"),
                           ("test_sims_r2", "test sets, per simulation"), ("test_frames_r2", "test sets, per frame")):
            vals = r[key]
            rows.append([feat, label] + vals + [float(np.mean(vals))])
    s, g = p["spread"], p["signal"]
    lines = ["### What the latent knows", "",
             "A linear probe (ridge, its strength chosen by holding out train parameter sets) from a frame's "
             "latent z, and from its shape descriptor S (the cloth alone: what the data holds), to the true "
             "intrinsic parameters scaled to [0, 1] (`recon/garment/author/curves.py`). R^2: 1 exact, 0 no better "
             "than the mean.", "",
             report.table(rows, ["features", "held out"] + names + ["mean"], ["s", "s"] + [".2f"] * (len(names) + 1)),
             "",
             f"Spread of the latents (sum of variances over z's dimensions): one set's simulations about their "
             f"set's mean (the motion) {s['test']['within_set']:.3g} against the sets' means about theirs (the "
             f"material) {s['test']['between_sets']:.3g} on the test sets (ratio {s['test']['ratio']:.2f}; train "
             f"{s['train']['ratio']:.2f}).", "",
             f"The signal: on the same window, two parameter sets' simulations lie {g['between_sets_mm']:.1f} mm "
             f"apart ({g['pairs']} pairs), a simulation {g['from_base_mm']:.1f} mm from the base cloth; the "
             f"decoder's cloth from the two sets' latents lies {g['decoded_between_sets_mm']:.1f} mm apart.", ""]
    if curve:
        rows = []
        for n, q in sorted(curve.items(), key=lambda kv: int(kv[0])):
            z, s_, sp = q["features"]["latent z"], q["features"]["descriptor S"], q["spread"]
            rows.append([int(n), float(np.mean(z["train_sets_held_out_r2"])), float(np.mean(z["test_sims_r2"])),
                         float(np.mean(s_["test_sims_r2"])), sp["train"]["ratio"], sp["test"]["ratio"]])
        lines += ["The probe of the learning curve's models (mean R^2 over the parameters; spread: within a set "
                  "against between sets):", "",
                  report.table(rows, ["train sets", "z: train sets held out", "z: test sets", "S: test sets",
                                      "spread, train", "spread, test"], ["d", ".2f", ".2f", ".2f", ".2g", ".2f"]), ""]
    c = p.get("model_check")
    if c and table:
        lines += [f"The probed model (same recipe and simulations, trained again): same motion "
                  f"{c['same_motion_mm']:.1f} mm, cross-motion {c['cross_motion_mm']:.1f} mm; the one the tables "
                  f"above measured: "
                  f"{table['same_motion_mm']:.1f} / {table['cross_motion_mm']:.1f} mm.", ""]
    return lines


