"""NCS training variants on tshirt-skirt side by side: how much dynamics each learns and, with
``--simulation``, how close each comes to the dynamic newton reference.

    OMP_NUM_THREADS=1 .venv/bin/python eval/ncs_variants.py [--steps 400] [--only recipe,no-smoothing]
    OMP_NUM_THREADS=1 .venv/bin/python eval/ncs_variants.py --full --simulation --only "recipe,static part frozen"

Each variant is the recipe (``NCSTrainConfig``) with one change. Short runs (default): ``--steps``
steps on 1,600 train / 120 val windows -> eval/results/garment-ncs-variants.{json,md}. ``--full``:
the recipe's own windows and length (2,400 steps, what ``recon garment train --model ncs`` runs)
-> garment-ncs-variants-full.{json,md}; a variant's file already in the cache is scored, not
retrained (``--retrain`` to redo it). A row is the variant's validation at the end:
``dynamic_mm``, how far the dynamic code moves the cloth (mean over vertices: NCS against its own
motion control 0), with inertia, collisions and strain; ``--simulation`` adds the mean per-vertex
error against the dynamic simulations of the test clips (recon.garment.evaluate_ncs), of NCS and
of NCS at motion control 0 (its static part), beside PBNS's.
"""
from __future__ import annotations

import argparse
import json
from dataclasses import replace

import numpy as np
import torch

from recon import paths, report
from recon.body import default_body
from recon.garment import evaluate_ncs, ncs_train
from recon.garment.ncs import NCS, InertiaConfig, NCSConfig

BASE = dict(samples=1600, val_samples=120, distil_steps=800)
RECIPE = ncs_train.NCSTrainConfig()
_SWING_ONLY = NCSConfig(swing_modes=16, dynamic_in_static_rows=False)
# rows scored against the dynamic simulations say which: before 2026-11-25 (session 8) the cloth
# started at rest and was damped against the world; since, it starts and is damped with the skinned
# outfit and each clip is scored after a lead-in (recon.garment.reference.simulate, evaluate_ncs)
SIMULATION = "carried, lead-in"
VARIANTS = {
    "recipe": {},
    "no motion smoothing": {"smooth_motion": 0.0},
    "dynamic branch starts small (x0.01)": {"dynamic_init": 0.01},
    "no motion augmentation": {"motion_augmentation": 0.0},
    "inertia x10": {"inertia": InertiaConfig(weight=10 * RECIPE.inertia.weight)},
    "15 fps": {"fps": 15.0},
    "soft edges first (continuation 0.1)": {"edge_warmup": 0.1},
    "static part frozen (PBNS)": {"freeze_static": True},
    "static part frozen; its residual force removed": {"freeze_static": True, "remove_static_force": True},
    "static part frozen; residual force removed; 32 dynamic modes": {
        "freeze_static": True, "remove_static_force": True, "model": NCSConfig(dynamic_modes=32)},
    "static part frozen; 16 swing modes": {"freeze_static": True, "model": NCSConfig(swing_modes=16)},
    "static part frozen; 16 swing modes; the dynamic code on them only; whole outfit": {
        "freeze_static": True, "hanging_only": False, "model": _SWING_ONLY},
    "static part frozen; 16 swing modes; the dynamic code on them only": {"freeze_static": True, "model": _SWING_ONLY},
    "static part frozen; 16 fixed swing modes; the dynamic code on them only; whole outfit": {
        "freeze_static": True, "train_dynamic_rows": False, "hanging_only": False, "model": _SWING_ONLY},
    "static part frozen; 16 fixed swing modes; the dynamic code on them only": {
        "freeze_static": True, "train_dynamic_rows": False, "model": _SWING_ONLY},
    "static part frozen; 16 fixed swing modes; the dynamic code on them only; 7200 steps": {
        "freeze_static": True, "train_dynamic_rows": False, "model": _SWING_ONLY, "epochs": 24},
    "static part frozen; 16 fixed swing modes; the dynamic code on them only; seed 1": {
        "freeze_static": True, "train_dynamic_rows": False, "model": _SWING_ONLY, "seed": 1},
    "static part frozen; 16 fixed swing modes; the dynamic code on them only; 2 s windows": {
        "freeze_static": True, "train_dynamic_rows": False, "model": _SWING_ONLY, "window": 2.0},
    "static part frozen; 16 fixed swing modes; the dynamic code on them only; dynamic lr 0.01": {
        "freeze_static": True, "train_dynamic_rows": False, "model": _SWING_ONLY, "lr_dynamic": 0.01},
}
KEYS = ("val_dynamic_mm", "val_inertia", "val_collision_pct", "val_edge_mm")
HEADERS = ["variant", "steps", "dynamic mm", "inertia", "collision %", "edge mm", "train s", "sim_error_mm",
           "sim_error_mm at motion 0", "hem_error_mm", "simulation", "PBNS sim_error_mm", "PBNS hem_error_mm"]


def against_simulation(body, outfit: str, path) -> dict:
    """Means over DYNAMIC_CLIPS of sim_error_mm and hem_error_mm for PBNS, NCS and NCS at motion
    control 0: {model: {metric: mm}}."""
    pbns, ncs, _, shape = evaluate_ncs._load(outfit, path)
    rows = [evaluate_ncs.dynamic_rows(body, outfit, pbns, ncs, shape, c)["rows"] for c in evaluate_ncs.DYNAMIC_CLIPS]
    models = (evaluate_ncs.MODELS[1], evaluate_ncs.MODELS[2], evaluate_ncs.STATIC_PART)
    return {m: {k: float(np.mean([r[m][k] for r in rows])) for k in ("sim_error_mm", "hem_error_mm")} for m in models}


def render(data: dict) -> str:
    full = data.get("full", False)
    how = ("the recipe's windows and length" if full else
           f"{data['steps']} steps on {data['base']['samples']:,} train / {data['base']['val_samples']} val windows")
    length = "the full recipe" if full else f"{data['steps']} steps"
    lines = [f"# NCS training variants ({data['outfit']}, {length})",
             "", f"`eval/ncs_variants.py{' --full' if full else ''}`; {report.describe(data['machine'])}. The recipe "
             f"(`NCSTrainConfig`) with one change each ({how}), validated on the val performers' windows. "
             "dynamic mm: how far the dynamic code moves the cloth (mean over vertices). For scale, the newton "
             "simulation's skirt hem swings up to 21 cm from where skinning puts it in the test turn "
             "([garment-ncs.md](garment-ncs.md)). sim_error_mm: mean per-vertex error against the dynamic "
             "simulations of garment-ncs.md's three test clips; at motion 0: the variant's static part alone. "
             "Rows marked (ReLU) were trained before the dynamic branch's activations became leaky: with ReLUs "
             "and no biases every hidden unit of that branch switched off for good within a few hundred steps "
             "(docs/garments.md), which bounded what any of those variants could learn. hem_error_mm: the hem's "
             "swing against the simulation's (garment-ncs.md). simulation: which references a row was scored "
             "against, with PBNS's errors on them: \"at rest, still air\" (until 2026-11-25) started the cloth at "
             "rest around a moving body and damped its velocity in the world; \"carried, lead-in\" starts it at "
             "the skinned outfit's velocity, damps its velocity relative to it and scores each clip after a "
             "lead-in (recon/garment/reference.py). Variants without \"whole outfit\" whose dynamic code moves "
             "the hanging part alone train on it alone (`NCSTrainConfig.hanging_only`); a whole-outfit row was "
             "trained on every garment. The validation windows depend on the seed and the window length."]
    rows = [r + [None] * (len(HEADERS) - len(r)) for r in data["rows"]]
    lines += ["", report.table(rows, HEADERS, ["", "", ".2f", ".4f", ".2f", ".2f", "", ".1f", ".1f", ".1f", "",
                                               ".1f", ".1f"])]
    return "\n".join(lines)


def merge_rows(old: list[list], new: list[list]) -> list[list]:
    """``old`` rows with those of the same variant replaced by ``new``'s, the rest of ``new`` after."""
    fresh = {r[0]: r for r in new}
    return [fresh.pop(r[0], r) for r in old] + list(fresh.values())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--only", default=None, help="comma-separated variant names")
    ap.add_argument("--full", action="store_true", help="the recipe's windows and length (2,400 steps)")
    ap.add_argument("--simulation", action="store_true", help="also score against the dynamic simulations")
    ap.add_argument("--retrain", action="store_true", help="--full: retrain variants already in the cache")
    a = ap.parse_args()
    torch.set_num_threads(1)
    body = default_body()
    names = a.only.split(",") if a.only else list(VARIANTS)
    base = {} if a.full else BASE
    epochs = RECIPE.epochs if a.full else max(1, round(a.steps / (BASE["samples"] // RECIPE.batch)))
    folder = paths.cache_dir() / ("ncs-variants-full" if a.full else "ncs-variants")
    rows = []
    for name in names:
        cfg = replace(RECIPE, **{"outfit": a.outfit, "epochs": epochs, **base, **VARIANTS[name]})
        out = folder / f"{a.outfit}-{name.replace(' ', '_').replace(',', '')}.pt"
        if a.full and out.exists() and not a.retrain:
            meta = json.loads(NCS.load(out)[1]["meta_json"])
        else:
            meta = ncs_train.train(body, cfg, out=out, progress=False)
        last = meta["curve"][-1]
        row = [name, last["step"]] + [last[k] for k in KEYS] + [round(meta["train_seconds"])]
        if a.simulation:
            sim = against_simulation(body, a.outfit, out)
            row += [sim[evaluate_ncs.MODELS[2]]["sim_error_mm"], sim[evaluate_ncs.STATIC_PART]["sim_error_mm"],
                    sim[evaluate_ncs.MODELS[2]]["hem_error_mm"], SIMULATION,
                    sim[evaluate_ncs.MODELS[1]]["sim_error_mm"], sim[evaluate_ncs.MODELS[1]]["hem_error_mm"]]
        rows.append(row)
        print(rows[-1], flush=True)
    stem = report.RESULTS / ("garment-ncs-variants-full" if a.full else "garment-ncs-variants")
    if a.only and stem.with_suffix(".json").exists():  # the other variants' rows stay
        rows = merge_rows(json.loads(stem.with_suffix(".json").read_text())["rows"], rows)
    data = {"outfit": a.outfit, "steps": a.steps, "full": a.full, "base": base or {"samples": RECIPE.samples,
            "val_samples": RECIPE.val_samples}, "rows": rows, "machine": report.machine()}
    print(report.write(stem, data, render(data)).read_text())


if __name__ == "__main__":
    main()
