"""How converged is the quasi-static drape the Taylor database and its evaluation stand on?

At held-out poses (the first ``--poses`` of the Taylor test poses) on the outfit's PBNS body, the
drape of the default solver (``DrapeSolverConfig``: 4 contact rounds of at most 40 L-BFGS
iterations) and of longer solves, each against a reference solve of 8 rounds of up to 300
iterations with a 1 um step tolerance; and the default solve started 1 um away (a random move of
every vertex: what another CPU's last bits could do), against the default solve itself.

    .venv/bin/python eval/drape_convergence.py [--outfit tshirt-skirt] [--poses 8] [--workers 2]

-> eval/results/drape-convergence-<outfit>.{json,md}
"""
from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from recon import report
from recon.body import default_body
from recon.executor import Call, ExecutorConfig, WorkerSpec, in_order
from recon.garment import store
from recon.garment.data import posed_bodies
from recon.garment.drape import DrapeSolver, DrapeSolverConfig
from recon.garment.pbns.model import PBNS, trained_outfit
from recon.garment.taylor.eval import test_poses

OUT = Path(__file__).resolve().parent / "results"
DEFAULT = DrapeSolverConfig()
SOLVES = {"default (4 x 40)": DEFAULT, "8 rounds x 40": replace(DEFAULT, rounds=8),
          "4 rounds x 160": replace(DEFAULT, iterations=160),
          "reference (8 x 300, tolerance 1 um)": replace(DEFAULT, rounds=8, iterations=300, step_tol=1e-6)}
NUDGE = 1e-6  # m: the moved start's displacement of every vertex


@torch.no_grad()
def _one(args) -> dict:
    """Every solve at one pose: {name: drape (N, 3)}."""
    outfit, rot = args
    torch.set_num_threads(1)
    body = default_body()
    pbns, _ = PBNS.load(store.pbns_path(outfit))
    o, shape0, _ = trained_outfit(body, store.pbns_path(outfit))
    bv, bn, bt = posed_bodies(body, rot[None], shape0[None])
    start = pbns.skin(pbns.rest, bt)[0]
    out = {}
    for name, cfg in SOLVES.items():
        out[name] = DrapeSolver(o, cfg)(pbns.rest, start, bv[0], bn[0]).numpy()
    g = torch.Generator().manual_seed(0)
    nudge = torch.nn.functional.normalize(torch.randn(start.shape, generator=g), dim=-1) * NUDGE
    out["moved start"] = DrapeSolver(o, DEFAULT)(pbns.rest, start + nudge, bv[0], bn[0], carried=start).numpy()
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--poses", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(1)  # as each worker (the machine record says so)
    rot = test_poses(20)[:args.poses]
    per_pose = in_order(WorkerSpec(Call, (_one,)), [(args.outfit, r) for r in rot],
                        ExecutorConfig(workers=args.workers, threads=1))
    ref = "reference (8 x 300, tolerance 1 um)"

    def dist(a: str, b: str) -> np.ndarray:
        """(poses,) mean and (poses,) largest vertex distance (mm) between two solves."""
        d = np.stack([np.linalg.norm(p[a] - p[b], axis=-1) for p in per_pose]) * 1000
        return d.mean(1), d.max(1)

    rows = []
    for name in [*(n for n in SOLVES if n != ref), "moved start"]:
        mean, big = dist(name, ref if name != "moved start" else "default (4 x 40)")
        against = "reference" if name != "moved start" else "default"
        rows.append([name, against, float(mean.mean()), float(mean.min()), float(mean.max()), float(big.mean())])
    data = {"outfit": args.outfit, "poses": args.poses, "nudge_m": NUDGE, "machine": report.machine(),
            "rows": rows}
    md = "\n".join([
        f"# Convergence of the quasi-static drape: {args.outfit}", "",
        f"`eval/drape_convergence.py --outfit {args.outfit} --poses {args.poses}`; {report.describe(data['machine'])}, "
        f"{args.workers} processes. The first {args.poses} Taylor test poses on the outfit's PBNS body "
        "(recon.garment.drape, from the skinned outfit). Distance: mean over vertices (per pose, then its mean, "
        "least and largest over poses) and the largest vertex's (mean over poses), to the reference solve, or "
        f"(moved start: every vertex of the start moved {NUDGE * 1e6:g} um in a random direction) to the default "
        "solve.", "",
        report.table(rows, ["solve", "against", "mean mm", "least pose", "largest pose", "largest vertex mm"],
                     ["", "", ".2f", ".2f", ".2f", ".1f"])])
    print(Path(report.write(OUT / f"drape-convergence-{args.outfit}", data, md)).read_text())


if __name__ == "__main__":
    main()
