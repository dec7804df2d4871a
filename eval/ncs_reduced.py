"""What NCS's training energies imply in its swing space: the implicit integration that NCS's
loss stands for, solved frame by frame over the dynamic test clips, beside PBNS, a trained NCS and
the newton simulation. It bounds what the dynamic branch can learn there: a gap to the trained
NCS is the training's, a gap to the simulation the energies' (the fabric) and the space's.

    OMP_NUM_THREADS=1 .venv/bin/python eval/ncs_reduced.py [--ncs path/to/ncs.pt] [--iters 20]

Per clip (``evaluate_ncs.DYNAMIC_CLIPS``, from its lead-in): x_t = PBNS's drape + the 16 fixed
swing modes (``ncs.swing_basis``, x and z, NCSConfig(swing_modes=16)) with coefficients c_t,
skinned like PBNS's blend shapes; c_t minimises NCS's training loss on the hanging part (the PBNS
energies of ``NCSTrainConfig`` + the inertia term against x_{t-1}, x_{t-2}, the previous solved
frames), L-BFGS, ``--iters`` iterations a frame. Scored like garment-ncs.md on the frames after
the lead-in: per-vertex error and hem swing error against the simulation, and the hem's peak
swing. The simulations come from the cache of ``recon garment eval --model ncs``.
-> eval/results/ncs-reduced-<outfit>.{json,md}
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from recon import report
from recon.body import default_body
from recon.garment import evaluate_ncs as E
from recon.garment import losses as L
from recon.garment import store
from recon.garment.data import posed_bodies, trained_outfit
from recon.garment.ncs import NCS, InertiaLoss, NCSConfig, hanging_part, vertex_masses
from recon.garment.ncs_train import NCSTrainConfig, part_outfit
from recon.garment.pbns import PBNS

SWING_MODES = 16
REDUCED = "PBNS + swing modes, integrated"


def solve_frame(coef: torch.Tensor, static: torch.Tensor, blend: torch.Tensor, basis: torch.Tensor, loss,
                iters: int) -> torch.Tensor:
    """Coefficients minimising ``loss(x, du)`` for x = ``static`` + ``blend`` (n, 3, 3) applied to
    du = coef . ``basis``, from ``coef``; L-BFGS, ``iters`` iterations."""
    c = coef.clone().requires_grad_(True)
    opt = torch.optim.LBFGS([c], lr=1, max_iter=iters, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        x, du = posed(c, static, blend, basis)
        e = loss(x, du)
        e.backward()
        return e

    opt.step(closure)
    return c.detach()


def posed(coef, static, blend, basis):
    du = torch.einsum("k,knj->nj", coef, basis)
    return static + torch.einsum("nij,nj->ni", blend, du), du


def integrate(basis: torch.Tensor, weights: torch.Tensor, crit: L.Criterion, inertia: InertiaLoss,
              static: torch.Tensor, transforms: torch.Tensor, bv: torch.Tensor, bn: torch.Tensor,
              iters: int) -> torch.Tensor:
    """(T, n, 3) frames of the hanging part: PBNS's ``static`` (T, n, 3) plus ``basis`` (K, n, 3)
    rest-pose fields skinned with ``weights`` (n, 24), their coefficients solved per frame."""
    out, prev = [], [static[0], static[0]]  # the cloth moving with PBNS before the clip
    coef = torch.zeros(len(basis))
    for t in range(len(static)):
        with torch.no_grad():
            blend = (weights @ transforms[t].reshape(-1, 12)).view(-1, 3, 4)[:, :, :3]
        body_t, past = (bv[t:t + 1], bn[t:t + 1]), (prev[1][None], prev[0][None])

        def loss(x, du, body_t=body_t, past=past):
            return (crit(x[None], du[None], *body_t) + inertia(x[None], *past)).sum()

        coef = solve_frame(coef, static[t], blend, basis, loss, iters)
        with torch.no_grad():
            x = posed(coef, static[t], blend, basis)[0]
        out.append(x)
        prev = [prev[1], x]
    return torch.stack(out)


def hem_swing(v_hem: torch.Tensor, skinned_hem: torch.Tensor, lead: int) -> torch.Tensor:
    """(T', 2): the hem centroid's horizontal offset from the skinned one's, after the lead-in."""
    return (v_hem.mean(1) - skinned_hem.mean(1))[lead:, [0, 2]]


def run(outfit_name: str, ncs_path: Path | None, iters: int) -> dict:
    body = default_body()
    pbns, ck = PBNS.load(store.pbns_path(outfit_name))
    shape = ck["shape"][None]
    outfit, _, _ = trained_outfit(body, store.pbns_path(outfit_name))
    swing = NCS.from_pbns(pbns, NCSConfig(swing_modes=SWING_MODES, dynamic_in_static_rows=False), outfit)
    hanging, _ = hanging_part(outfit)
    part = np.nonzero(hanging)[0]
    idx = torch.from_numpy(part)
    basis = swing.D[pbns.D.shape[0]:].detach().view(2 * SWING_MODES, -1, 3)[:, idx]
    cloth = part_outfit(outfit, part) if not hanging.all() else outfit
    cfg = NCSTrainConfig()
    crit = L.Criterion(cloth, pbns.rest[idx], cfg)
    inertia = InertiaLoss(torch.from_numpy(vertex_masses(cloth.vertices, cloth.faces)), cfg.fps, cfg.inertia)
    ncs = NCS.load(ncs_path)[0] if ncs_path else None
    hem = E.hem_vertices(pbns.rest.numpy(), pbns.faces.numpy())
    hem_sub = np.cumsum(hanging)[hem] - 1
    clips = []
    for clip in E.DYNAMIC_CLIPS:
        t0 = time.time()
        rot, tr = E._lead_in(clip)
        bv, bn, transforms = posed_bodies(body, rot, shape, transl=tr)
        models = E.run_models(pbns, ncs, body, shape, rot, tr)
        solved = integrate(basis, pbns.weights.detach()[idx], crit, inertia, models[E.MODELS[1]][:, idx],
                           transforms, bv, bn, iters)
        seconds = time.time() - t0
        ref = torch.from_numpy(E.dynamic_reference(body, outfit_name, pbns, shape, clip)["vertices"]).float()
        skinned_hem = models[E.MODELS[0]][:, hem]
        sim_swing = hem_swing(ref[:, hem_sub], skinned_hem, clip.lead)
        rows = {}
        for m, v in {**{m: x[:, idx] for m, x in models.items()}, REDUCED: solved}.items():
            s = hem_swing(v[:, hem_sub], skinned_hem, clip.lead)
            rows[m] = {"sim_error_mm": float((v - ref).norm(dim=-1)[clip.lead:].mean() * 1000),
                       "hem_error_mm": float((s - sim_swing).norm(dim=-1).mean() * 1000),
                       "hem_peak_mm": float(s.norm(dim=-1).max() * 1000)}
        clips.append({"clip": clip.name, "motion": clip.motion, "rows": rows, "seconds": seconds,
                      "sim_hem_peak_mm": float(sim_swing.norm(dim=-1).max() * 1000)})
        print(clip.name, {m: round(r["sim_error_mm"], 1) for m, r in rows.items()}, flush=True)
    return {"outfit": outfit_name, "iters": iters, "swing_modes": SWING_MODES,
            "ncs": None if ncs_path is None else Path(ncs_path).name, "clips": clips}


def render(data: dict) -> str:
    models = list(data["clips"][0]["rows"])
    lines = [f"# What NCS's energies imply in its swing space ({data['outfit']})", "",
             f"`eval/ncs_reduced.py`; {report.describe(data['machine'])}. PBNS's drape plus {data['swing_modes']} "
             f"fixed swing modes (x, z), their coefficients solved frame by frame on NCS's training loss (the PBNS "
             f"energies + inertia against the two previous solved frames; L-BFGS, {data['iters']} iterations a "
             "frame): the implicit integration NCS's loss stands for, in the space its dynamic code reaches. Scored "
             "against the dynamic simulation after each clip's lead-in, on the hanging part (garment-ncs.md's "
             "protocol); hem peak: the hem's largest swing from where skinning puts it."
             + (f" NCS: {data['ncs']} (not shipped)." if data["ncs"] else ""), ""]
    rows = []
    for c in data["clips"]:
        for m in models:
            r = c["rows"][m]
            rows.append([c["clip"], c["motion"], m, r["sim_error_mm"], r["hem_error_mm"], r["hem_peak_mm"],
                         c["sim_hem_peak_mm"]])
    for m in models:
        rows.append(["mean", "", m] + [float(np.mean([c["rows"][m][k] for c in data["clips"]]))
                                       for k in ("sim_error_mm", "hem_error_mm", "hem_peak_mm")]
                    + [float(np.mean([c["sim_hem_peak_mm"] for c in data["clips"]]))])
    lines.append(report.table(rows, ["clip", "motion", "model", "sim_error_mm", "hem_error_mm", "hem peak mm",
                                     "sim hem peak mm"], ["", "", "", ".1f", ".1f", ".0f", ".0f"]))
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--ncs", type=Path, default=None, help="a trained NCS to score beside (an experiment's file)")
    ap.add_argument("--iters", type=int, default=20)
    a = ap.parse_args()
    torch.set_num_threads(1)
    data = {**run(a.outfit, a.ncs, a.iters), "machine": report.machine()}
    print(report.write(report.RESULTS / f"ncs-reduced-{a.outfit}", data, render(data)).read_text())


if __name__ == "__main__":
    main()
