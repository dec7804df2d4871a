"""The Taylor database's drape solver against newton's VBD drape (``recon garment reference``'s
protocol) at held-out poses on PBNS's body: is it closer to newton's than PBNS is? A section of
garment-taylor.md (``recon garment eval --model taylor``; needs the ``sim`` extra, minutes a pose).
"""
from __future__ import annotations

import time

import torch

from recon.body import default_body
from recon.executor import Call, ExecutorConfig, WorkerSpec, in_order
from recon.garment import reference, store
from recon.garment.data import posed_bodies
from recon.garment.drape import DrapeSolver
from recon.garment.pbns.model import PBNS, trained_outfit
from recon.garment.taylor.config import TaylorBuildConfig


@torch.no_grad()
def _newton_one(args) -> dict:
    """One held-out pose on PBNS's body: newton's drape (reference.drape, its protocol) and ours, from
    the same skinned start; the distance of ours, PBNS's and the skinned start to newton's."""
    outfit, pose, rot = args
    body = default_body()
    pbns, ck = PBNS.load(store.pbns_path(outfit))
    o, shape0, _ = trained_outfit(body, store.pbns_path(outfit))
    rot = rot[None]
    bv, bn, bt = posed_bodies(body, rot, shape0[None])
    sk = pbns.skin(pbns.rest, bt)[0]
    t = time.time()
    ours = DrapeSolver(o, TaylorBuildConfig().drape)(pbns.rest, sk, bv[0], bn[0])
    ours_s = time.time() - t
    sim = reference.drape(bv[0].numpy(), body.faces.numpy(), pbns.rest.numpy(), sk.numpy(), pbns.faces.numpy(),
                          o.pinned, reference.DrapeConfig())
    newton = torch.from_numpy(sim["vertices"]).float()
    err = lambda v: float((v - newton).norm(dim=-1).mean()) * 1000  # noqa: E731
    return {"pose": pose, "ours_mm": err(ours), "pbns_mm": err(pbns.pose(rot, bt)[0]), "skinning_mm": err(sk),
            "ours_s": ours_s, "newton_s": sim["seconds"], "newton_settled": sim["settled"]}


def newton_comparison(outfit: str, poses: dict[int, torch.Tensor], workers: int = 2) -> list[dict]:
    """Our drape solver against newton's VBD drape at ``poses`` ({index in the test poses: (24, 3,
    3)}) on PBNS's body, in ``workers`` processes (needs the ``sim`` extra)."""
    return in_order(WorkerSpec(Call, (_newton_one,)), [(outfit, i, r) for i, r in poses.items()],
                    ExecutorConfig(workers=workers, threads=1))
