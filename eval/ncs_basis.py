"""Can NCS's blend shapes hold the cloth's response to inertia? One implicit step from PBNS's
quasi-static past, solved per window in three spaces.

    OMP_NUM_THREADS=1 .venv/bin/python eval/ncs_basis.py [--outfit tshirt-skirt] [--n 6]

Windows: the ``--n`` train-split windows (3 frames, smoothed as NCS trains) whose skinned outfit
accelerates most, spread over the top 100. PBNS dresses the three frames. For the last one the
displacement is optimised (Adam, ``ITERS`` steps) on NCS's training energies (recon.garment.losses
with NCS's recipe weights) once without and once with its inertia term against the two PBNS
frames before (as NCS trains: the past held constant); the response to inertia is the distance
between the two solutions, mean over vertices and over the hem. Spaces: the vertices themselves
(pins held by the pin term), PBNS's blend shapes (the code over D's rows), and those plus the
swing modes (``NCSConfig.swing_modes``: the hanging part's lowest membrane modes). The gap
between the first two is what a dynamic code over PBNS's D alone cannot express.
-> eval/results/ncs-basis-<outfit>.{json,md}
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from recon import report
from recon.body import default_body
from recon.garment import losses as L
from recon.garment import store
from recon.garment.data import trained_outfit
from recon.garment.evaluate_ncs import hem_vertices
from recon.garment.ncs import InertiaLoss, hanging_part, swing_basis, vertex_masses
from recon.garment.ncs_train import MotionWindows, NCSTrainConfig
from recon.garment.pbns import PBNS, pose_features

ITERS = 300
SPACES = ("vertices", "PBNS's blend shapes", "blend shapes + swing modes")


def responses(outfit_name: str, n: int, swing_modes: int, seed: int = 0) -> dict:
    body = default_body()
    cfg = NCSTrainConfig(outfit=outfit_name)
    outfit, shape, _ = trained_outfit(body, store.pbns_path(outfit_name))
    pbns, _ = PBNS.load(store.pbns_path(outfit_name))
    pbns.requires_grad_(False)
    masses = vertex_masses(outfit.vertices, outfit.faces)
    w = MotionWindows(body, "train", shape[None], 3, 2000, seed, smooth=cfg.smooth_motion, fps=cfg.fps)
    crit = L.Criterion(outfit, pbns.rest, cfg)
    inertia = InertiaLoss(torch.from_numpy(masses), cfg.fps, cfg.inertia)
    rot = w.rot[w.ends[:, None] + torch.arange(-2, 1)]
    with torch.no_grad():
        skinned = torch.cat([pbns.skin(pbns.rest, w.transforms[a:a + 64].flatten(0, 1)).view(-1, 3, len(pbns.rest), 3)
                             for a in range(0, len(rot), 64)])
    accel = (skinned[:, 2] - 2 * skinned[:, 1] + skinned[:, 0]).norm(dim=-1).mean(1) * cfg.fps ** 2
    sel = accel.argsort(descending=True)[np.linspace(0, 99, n).round().astype(int)]
    tr, bv, bn = w.transforms[sel], w.body_v[sel], w.body_n[sel]
    with torch.no_grad():
        x = pbns.pose(rot[sel].flatten(0, 1), tr.flatten(0, 1)).view(n, 3, -1, 3)
        z = pbns.mlp(pose_features(rot[sel][:, 2]))
    swing = torch.from_numpy(swing_basis(outfit.vertices, outfit.faces, masses, *hanging_part(outfit), swing_modes))
    pinned = torch.from_numpy(outfit.pinned)
    hem = torch.from_numpy(hem_vertices(outfit.vertices, outfit.faces))

    def solve(space: str, with_inertia: bool) -> torch.Tensor:
        d = pbns.D if space == SPACES[1] else torch.cat([pbns.D, swing])
        p = torch.zeros((n, len(pbns.rest), 3) if space == SPACES[0] else (n, len(d)), requires_grad=True)
        opt = torch.optim.Adam([p], lr=1e-3 if space == SPACES[0] else 3e-2)
        for _ in range(ITERS):
            if space == SPACES[0]:  # free vertices: the pins hold by the pin term on the move itself
                v = x[:, 2] + p
                e = crit(v, torch.zeros_like(v), bv, bn) + cfg.pin.weight * (p[:, pinned] ** 2).sum(-1).mean(1)
            else:
                dt = ((torch.nn.functional.pad(z, (0, len(d) - z.shape[1])) + p) @ d).view(n, -1, 3)
                v = pbns.skin(pbns.rest + dt, tr[:, 2])
                e = crit(v, dt, bv, bn)
            if with_inertia:
                e = e + inertia(v, x[:, 1], x[:, 0])
            opt.zero_grad()
            e.sum().backward()
            opt.step()
        return v.detach()

    rows = []
    for space in SPACES:
        t0 = time.time()
        d = (solve(space, True) - solve(space, False)).norm(dim=-1) * 1000
        rows.append({"space": space, "response_mm": d.mean(1).tolist(), "hem_mm": d[:, hem].mean(1).tolist(),
                     "seconds": time.time() - t0})
    return {"outfit": outfit_name, "n": n, "swing_modes": swing_modes, "iters": ITERS,
            "accel": accel[sel].tolist(), "rows": rows}


def render(data: dict) -> str:
    acc = ", ".join(f"{a:.0f}" for a in data["accel"])
    rows = [[r["space"], np.mean(r["response_mm"]), np.mean(r["hem_mm"]), np.min(r["hem_mm"]), np.max(r["hem_mm"])]
            for r in data["rows"]]
    return "\n".join([
        f"# The cloth's response to inertia, by the space it may move in ({data['outfit']})", "",
        f"`eval/ncs_basis.py`; {report.describe(data['machine'])}. {data['n']} train windows among the 100 whose "
        f"skinned outfit accelerates most (mean over vertices: {acc} m/s^2); PBNS dresses three frames; the last "
        f"one's displacement is optimised ({data['iters']} Adam steps) on NCS's training energies without and with "
        "its inertia term (the past held constant, as NCS trains). Response: the distance between the two "
        "solutions (mm), mean over vertices and over the hem. Swing modes: the hanging part's "
        f"{data['swing_modes']} lowest membrane modes along x and z (`NCSConfig.swing_modes`).", "",
        report.table(rows, ["space", "response mm (mean)", "hem mm (mean)", "hem mm (min)", "hem mm (max)"],
                     ["", ".1f", ".1f", ".1f", ".1f"])])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--outfit", default="tshirt-skirt")
    ap.add_argument("--n", type=int, default=6)
    ap.add_argument("--swing-modes", type=int, default=16)
    a = ap.parse_args()
    torch.set_num_threads(1)
    data = {**responses(a.outfit, a.n, a.swing_modes), "machine": report.machine()}
    print(report.write(report.RESULTS / f"ncs-basis-{a.outfit}", data, render(data)).read_text())


if __name__ == "__main__":
    main()
