"""What the .glb's default of 4 skinning influences a vertex costs: how far each vertex lands from
where every influence puts it (anny's skinning exactly, what ``--all-influences`` writes).

The body (anny, its mean shape) and every shipped outfit's cloth (its PBNS weights, and its NCS
weights where they differ; the rest mesh resized to the body, its blend shapes left out: they add
to the rest mesh and are skinned by the same weights) are skinned over balanced poses of the mocap's
test split, once with their weights as written by ``recon.export.glb.influence_sets`` (4, float32,
renormalised) and once with every weight.

    .venv/bin/python eval/glb_influences.py [--poses 300]
-> eval/results/glb-influences.{json,md}
"""
from __future__ import annotations

import argparse

import numpy as np
import torch

from recon import report
from recon.body import default_body, lbs
from recon.export.glb import INFLUENCES, written_weights
from recon.garment import store
from recon.garment.data import pose_set
from recon.garment.dress import Dresser
from recon.garment.templates import PRESETS

OUT = report.RESULTS / "glb-influences"


def errors(rest: torch.Tensor, weights: np.ndarray, transforms: torch.Tensor) -> dict:
    """Per posed vertex, the distance (mm) between skinning with the written 4 and with every weight."""
    with torch.no_grad():
        full = lbs.skin(rest, torch.from_numpy(weights.astype(np.float32)), transforms)
        four = lbs.skin(rest, written_weights(weights), transforms)
    d = (four - full).norm(dim=-1).numpy().ravel() * 1000
    many = int(((weights > 1e-6).sum(1) > INFLUENCES).sum())
    return {"vertices": len(weights), "over_4": many, "most": int((weights > 1e-6).sum(1).max()),
            "mean_mm": float(d.mean()), "p99_mm": float(np.percentile(d, 99)), "max_mm": float(d.max())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--poses", type=int, default=300)
    a = ap.parse_args()
    torch.set_num_threads(1)
    body = default_body()
    poses = pose_set("test", a.poses, 0.5, seed=123)
    rows = {}
    with torch.no_grad():
        out = body(poses, body.mean_shape[None])
    transforms = out.transforms
    rows["body"] = errors(out.rest_vertices[0], body.weights.numpy(), transforms)
    for outfit in PRESETS:
        if not store.pbns_path(outfit).exists():
            continue
        dresser = Dresser(outfit)
        rest = dresser.rest_for(body, body.mean_shape)
        rows[f"{outfit}, PBNS"] = errors(rest, dresser.model.weights.detach().numpy(), transforms)
        if store.ncs_path(outfit).exists():  # NCS's weights, where they are not PBNS's
            ncs = Dresser(outfit, dynamics=True).garment.ncs.weights.detach()
            if not torch.equal(ncs, dresser.model.weights.detach()):
                rows[f"{outfit}, NCS"] = errors(rest, ncs.numpy(), transforms)
    head = ["mesh", "vertices", "over 4 influences", "most influences", "mean (mm)", "99th pct (mm)", "max (mm)"]
    body_rows = [[k, r["vertices"], r["over_4"], r["most"], r["mean_mm"], r["p99_mm"], r["max_mm"]]
                 for k, r in rows.items()]
    md = "\n".join([
        "# The .glb's 4 skinning influences a vertex", "",
        f"How far a vertex lands from where every influence puts it, over {a.poses} balanced poses of the mocap's "
        "test split (eval/glb_influences.py): the .glb files keep each vertex's 4 strongest joints, renormalised "
        "(what three.js, Unity and most engines read); `--all-influences` keeps every one.", "",
        report.table(body_rows, head, ["", "", "", "", ".2f", ".2f", ".1f"]), "",
        f"Machine: {report.describe(report.machine())}.", ""])
    report.write(OUT, {"poses": a.poses, "rows": rows, "machine": report.machine()}, md)
    print(md)


if __name__ == "__main__":
    main()
