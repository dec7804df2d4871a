"""Why NCS learns so little motion: the forces on PBNS's cloth, per energy term, against the
inertial force that NCS's dynamics are trained on.

    OMP_NUM_THREADS=1 .venv/bin/python eval/ncs_forces.py [--outfit tshirt-skirt] [--n 64]

On ``--n`` windows of the val performers' mocap (smoothed as NCS trains), PBNS (the outfit's
shipped weights, NCS's static part when frozen) dresses the last three frames; per vertex, the
force of each training energy at the last frame (minus its gradient, recon.garment.losses with
NCS's recipe weights) and the inertial force m (x_t - 2 x_{t-1} + x_{t-2}) / dt^2 (NCS's inertia
term's), in units of the gravity term's force on a vertex. At an equilibrium the static sum would
be ~0; a network trained on the sum sees the inertial force only where the static part's residual
does not bury it. -> eval/results/ncs-forces-<outfit>.{json,md}
"""
from __future__ import annotations

import argparse

import torch

from recon import report
from recon.body import default_body
from recon.garment import losses as L
from recon.garment import store
from recon.garment.data import trained_outfit
from recon.garment.ncs import InertiaLoss, vertex_masses
from recon.garment.ncs_train import MotionWindows, NCSTrainConfig
from recon.garment.pbns import PBNS


def forces(outfit_name: str, n: int, seed: int = 1) -> dict:
    body = default_body()
    cfg = NCSTrainConfig(outfit=outfit_name)
    outfit, shape, _ = trained_outfit(body, store.pbns_path(outfit_name))
    pbns, _ = PBNS.load(store.pbns_path(outfit_name))
    w = MotionWindows(body, "val", shape[None], 3, n, seed, smooth=cfg.smooth_motion, fps=cfg.fps)
    crit = L.Criterion(outfit, pbns.rest, cfg)
    masses = torch.from_numpy(vertex_masses(outfit.vertices, outfit.faces))
    inertia = InertiaLoss(masses, cfg.fps, cfg.inertia)
    rot = w.rot[w.ends[:, None] + torch.arange(-2, 1)]  # (n, 3, 24, 3, 3)
    with torch.no_grad():
        x, dt = (y.view(n, 3, -1, 3) for y in pbns(rot.flatten(0, 1), w.transforms.flatten(0, 1)))
    xt = x[:, 2].clone().requires_grad_(True)
    crit(xt, dt[:, 2], w.body_v, w.body_n)
    terms = {k: e for k, e in crit.terms.items() if e.requires_grad}  # the pins act on dT, not on x
    unit = cfg.gravity.weight / xt.shape[1]  # the gravity term's force on each vertex
    out = {}
    for name, e in [*terms.items(), ("static sum", sum(terms.values()))]:
        f = -torch.autograd.grad(e.sum(), xt, retain_graph=True)[0] / unit
        out[name] = f.norm(dim=-1)
    xi = xt.detach().requires_grad_(True)
    g = torch.autograd.grad(inertia(xi, x[:, 1], x[:, 0]).sum(), xi)[0]
    out["inertia"] = (-g / unit).norm(dim=-1)
    return {k: {"mean": float(v.mean()), "median": float(v.median()), "p90": float(v.quantile(0.9))}
            for k, v in out.items()}


def render(data: dict) -> str:
    rows = [[k, v["mean"], v["median"], v["p90"]] for k, v in data["forces"].items()]
    return "\n".join([
        f"# Forces on PBNS's cloth against the inertial force ({data['outfit']})", "",
        f"`eval/ncs_forces.py`; {report.describe(data['machine'])}. {data['n']} windows of the val performers' "
        "mocap; PBNS dresses the last three frames; per vertex, the force of each training energy at the last "
        "frame (NCS's recipe weights) and the inertial force m (x_t - 2 x_{t-1} + x_{t-2}) / dt^2, in units of "
        "the gravity term's force on a vertex. NCS's dynamic branch is trained on the sum: where the static "
        "terms do not balance (a network's drape is not an equilibrium), their residual outweighs the "
        "inertia it should learn from.", "",
        report.table(rows, ["force (x gravity)", "mean", "median", "90th percentile"], ["", ".3f", ".3f", ".3f"])])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--n", type=int, default=64)
    a = ap.parse_args()
    torch.set_num_threads(1)
    data = {"outfit": a.outfit, "n": a.n, "forces": forces(a.outfit, a.n), "machine": report.machine()}
    print(report.write(report.RESULTS / f"ncs-forces-{a.outfit}", data, render(data)).read_text())


if __name__ == "__main__":
    main()
