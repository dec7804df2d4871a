"""NCS's training loss solved frame by frame (recon.garment.integrate: the trajectories the network
learns) against the dynamic simulations of the val clips, per solver setting, beside PBNS.

    OMP_NUM_THREADS=1 .venv/bin/python eval/ncs_teacher.py [--outfit tshirt-skirt]

Rows: the recipe (the preconditioned quasi-Newton solver, ``IntegrateConfig``, damping
``InertiaConfig.keep_velocity``); the same with the preconditioner of the edges' projected Newton
step factorised each frame (``across`` 0.5) instead of the constant one; the thesis' undamped
inertia (keep_velocity 1); and plain L-BFGS (torch's, strong Wolfe line search) stopped after 30,
100 and 400 iterations a frame (``--quick``: the first two only). Each clip
(``evaluate_ncs.VAL_CLIPS``) starts on PBNS's drape from its lead-in and is scored after it, as
garment-ncs-val.md scores the models: the hanging part's mean per-vertex error, the hem's swing
error and its peak swing, and seconds per frame (one thread).
-> eval/results/ncs-teacher-<outfit>.{json,md}
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import torch

from recon import report
from recon.body import default_body
from recon.garment.integrate import IntegrateConfig, Preconditioner, integrate
from recon.garment.losses import InertiaLoss
from recon.garment.ncs import eval as E
from recon.garment.ncs import reference_eval as R
from recon.garment.ncs.config import NCSTrainConfig
from recon.garment.ncs.data import Teacher


def plain_lbfgs(iterations: int):
    """A frame minimiser for ``integrate``: torch's L-BFGS (no preconditioner, strong Wolfe line
    search) stopped after ``iterations``."""
    def solve(energy, u0: torch.Tensor) -> torch.Tensor:
        u = u0.clone().requires_grad_(True)
        opt = torch.optim.LBFGS([u], lr=1, max_iter=iterations, history_size=20, line_search_fn="strong_wolfe",
                                tolerance_change=1e-12)

        def closure():
            opt.zero_grad()
            e = energy(u)
            e.backward()
            return e

        opt.step(closure)
        return u.detach()
    return solve


def settings(cfg: NCSTrainConfig, quick: bool = False) -> dict:
    """Setting name -> (solver: "recipe", or plain L-BFGS's iterations; keep_velocity; the
    preconditioner's ``across``). ``quick``: the recipe and the per-frame preconditioner only."""
    keep, it, across = cfg.inertia.keep_velocity, cfg.integrate.iterations, cfg.integrate.across
    recipe = f"recipe: preconditioned (across {across:g}), {it} iterations, keep_velocity {keep}"
    out = {recipe: ("recipe", keep, across)}
    if across >= 1:
        out[f"preconditioner factorised each frame (across 0.5), {it} iterations"] = ("recipe", keep, 0.5)
    if not quick:
        out[f"thesis' inertia (keep_velocity 1), preconditioned, {it} iterations"] = ("recipe", 1.0, across)
        out.update({f"plain L-BFGS, {n} iterations": (n, keep, across) for n in (30, 100, 400)})
    return out


def run(outfit: str, quick: bool = False) -> dict:
    body = default_body()
    cfg = NCSTrainConfig(outfit=outfit)
    teacher = Teacher(body, outfit, cfg)
    idx, pbns, shape = teacher.idx, teacher.pbns, teacher.shape
    hem = R.hem_vertices(pbns.rest.numpy(), pbns.faces.numpy())
    hanging = np.zeros(len(pbns.rest), bool)
    hanging[idx.numpy()] = True
    hem_sub = np.cumsum(hanging)[hem] - 1
    rows = []
    for clip in R.VAL_CLIPS:
        rot, tr = R.lead_in(clip)
        static, carried, bv, bn, _, _ = teacher.drapes(rot, tr)
        sim = R.dynamic_reference(body, outfit, pbns, shape, clip)
        mine = np.cumsum(sim["subset"])[idx.numpy()] - 1  # the teacher's part of the simulated one
        ref = torch.from_numpy(sim["vertices"][:, mine]).float()
        skin_hem = E.run_models(pbns, None, body, shape, rot, tr)[E.MODELS[0]][:, hem].mean(1)

        def score(v: torch.Tensor, ref=ref, skin_hem=skin_hem, lead=clip.lead) -> dict:
            s = (v[:, hem_sub].mean(1) - skin_hem)[lead:, [0, 2]]
            sim = (ref[:, hem_sub].mean(1) - skin_hem)[lead:, [0, 2]]
            return {"sim_error_mm": float((v - ref).norm(dim=-1)[lead:].mean() * 1000),
                    "hem_error_mm": float((s - sim).norm(dim=-1).mean() * 1000),
                    "hem_peak_mm": float(s.norm(dim=-1).max() * 1000),
                    "sim_hem_peak_mm": float(sim.norm(dim=-1).max() * 1000)}

        rows.append({"clip": clip.name, "motion": clip.motion, "setting": "PBNS", **score(static),
                     "seconds_per_frame": None})
        for name, (solver, keep, across) in settings(cfg, quick).items():
            inertia = InertiaLoss(teacher.inertia.m, teacher.inertia.fps, replace(cfg.inertia, keep_velocity=keep))
            t0 = time.time()
            precond = Preconditioner(teacher.crit, inertia, teacher.held.numpy(), across)
            x = integrate(teacher.crit, inertia, teacher.held, static, carried, bv, bn, cfg.integrate,
                          precond, solve=None if solver == "recipe" else plain_lbfgs(solver))
            rows.append({"clip": clip.name, "motion": clip.motion, "setting": name, **score(x),
                         "seconds_per_frame": (time.time() - t0) / len(x)})
            print(rows[-1], flush=True)
    return {"outfit": outfit, "integrate": vars(IntegrateConfig()) | vars(cfg.integrate), "rows": rows}


def render(data: dict) -> str:
    lines = [f"# NCS's training loss solved frame by frame ({data['outfit']}), against the val simulations", "",
             f"`eval/ncs_teacher.py`; {report.describe(data['machine'])}. The trajectories NCS's dynamic branch "
             "learns (recon.garment.integrate): per frame, the hanging part's state minimising the PBNS energies "
             "plus the inertia term against the two previous states, from PBNS's drape at the start of each "
             "val clip's lead-in, scored after it as garment-ncs-val.md scores the models (mean per-vertex "
             "error, the hem's swing error and peak swing; in brackets the simulation's). Seconds per frame "
             "are of runs sharing the machine's 2 cores with other jobs: compare them within this table only.",
             ""]
    settings_ = list(dict.fromkeys(r["setting"] for r in data["rows"]))
    table = []
    for r in data["rows"]:
        table.append([r["clip"], r["motion"], r["setting"], r["sim_error_mm"], r["hem_error_mm"],
                      f"{r['hem_peak_mm']:.0f} ({r['sim_hem_peak_mm']:.0f})",
                      "-" if r["seconds_per_frame"] is None else f"{r['seconds_per_frame']:.2f}"])
    for s in settings_:
        mine = [r for r in data["rows"] if r["setting"] == s]
        sec = [r["seconds_per_frame"] for r in mine if r["seconds_per_frame"] is not None]
        table.append(["mean", "", s, float(np.mean([r["sim_error_mm"] for r in mine])),
                      float(np.mean([r["hem_error_mm"] for r in mine])), "", f"{np.mean(sec):.2f}" if sec else "-"])
    lines.append(report.table(table, ["clip", "motion", "setting", "sim_error_mm", "hem_error_mm", "hem peak mm",
                                      "s / frame"], ["", "", "", ".1f", ".1f", "", ""]))
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--quick", action="store_true", help="the recipe beside the per-frame preconditioner only")
    a = ap.parse_args()
    torch.set_num_threads(1)
    data = {**run(a.outfit, a.quick), "machine": report.machine()}
    print(report.write(report.RESULTS / f"ncs-teacher-{a.outfit}", data, render(data)).read_text())


if __name__ == "__main__":
    main()
