"""PBNS inference speed, side by side in one run for every trained outfit: the shipped inference
(``PBNS.pose``: vertex-major in chunks of vertices for batches >= 12, else batch-major) against
three earlier forms: the batch-major forward (the einsum path), the blend-weight softmax
recomputed every call, and the broadcast-and-sum skinning; then the Dresser's post-step
(recon.garment.collide: collision resolution alone, and with the strain step first), and its body
normals (a sparse incidence matmul) against the index_add of recon.garment.mesh.vertex_normals.

    .venv/bin/python benchmarks/bench_garment.py [--threads 1] [--batch 1 64 256] [--device cuda]

Frames per second of the garment model alone given the body's joint transforms (pose -> MLP ->
PSD -> skinning). -> eval/results/bench-garment-<threads>t.{json,md} on the CPU,
bench-garment-<device>.{json,md} on another device (the collision resolution, a CPU step, is left
out there).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from recon import report
from recon.body import default_body
from recon.garment import store
from recon.garment.collide import CollisionResolver
from recon.garment.data import pose_set
from recon.garment.mesh import vertex_normals
from recon.garment.pbns.model import PBNS
from recon.timing import compare

OUT = Path(__file__).resolve().parent.parent / "eval" / "results"


def blend_uncached(model, transforms):
    """Per-vertex blended (B, N, 3, 4) transforms, softmax of the weights recomputed (no cache)."""
    b = transforms.shape[0]
    return (torch.softmax(model.weight_logits, -1) @ transforms.reshape(b, -1, 12)).view(b, -1, 3, 4)


def skin_broadcast(model, x, transforms):
    """The first PBNS.skin: blended transforms applied by broadcasting to (B, N, 3, 3)."""
    t = blend_uncached(model, transforms)
    return (t[..., :3] * x[..., None, :]).sum(-1) + t[..., 3]


def skin_softmax(model, x, transforms):
    """PBNS.skin with the blend-weight softmax recomputed on every call (before the cache)."""
    b = transforms.shape[0]
    t = blend_uncached(model, transforms)
    return torch.einsum("bnij,bnj->bni", t[..., :3], x.expand(b, -1, -1)) + t[..., 3]


def forms(m, rot, t) -> dict:
    """The shipped inference and the three earlier forms, each a function of nothing."""
    return {"shipped": lambda: m.pose(rot, t), "batch-major": lambda: m(rot, t),
            "softmax per call": lambda: skin_softmax(m, m.rest + m.deformation(rot), t),
            "broadcast": lambda: skin_broadcast(m, m.rest + m.deformation(rot), t)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 64, 256])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu", help="torch device of the garment model (cuda: a GPU)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    dev = torch.device(args.device)
    body = default_body()
    rot_all = pose_set("test", max(args.batch), 0.5, seed=123)
    speed, resolution = [], []
    for name in store.trained_outfits():
        model, ck = PBNS.load(store.pbns_path(name))
        model = model.to(dev)
        shape = ck["shape"][None]
        for b in args.batch:
            rot = rot_all[torch.arange(b) % len(rot_all)]
            with torch.no_grad():
                t = body(rot, shape.expand(b, -1), points_only=True).transforms.to(dev)
                ms = compare(forms(model, rot.to(dev), t), rounds=args.rounds)
            fps = {k: 1000 * b / v for k, v in ms.items()}
            speed.append([name, int(model.rest.shape[0]), b, fps["shipped"]]
                         + [x for k in list(ms)[1:] for x in (fps[k], ms[k] / ms["shipped"])])
        if dev.type != "cpu":
            continue
        res = CollisionResolver(model.faces.numpy(), ck["layer"].numpy())
        rot = rot_all[:1]
        with torch.no_grad():
            out = body(rot, shape)
        bv, bf = out.vertices, body.faces.numpy()
        inc = CollisionResolver.incidence(bf, bv.shape[1])
        bv0 = bv[0].numpy()
        same = vertex_normals(bv, body.faces)[0].numpy()
        assert np.allclose(CollisionResolver.normals(bv0, bf, inc), same, atol=1e-4)
        ms = compare({"pbns": lambda: model.pose(rot, out.transforms),  # noqa: B023
                      "pbns + resolution": lambda: res(model.pose(rot, out.transforms), bv, bf),  # noqa: B023
                      "pbns + post-step": lambda: res(model.pose(rot, out.transforms), bv, bf,  # noqa: B023
                                                      rest=model.rest),  # noqa: B023
                      "normals, incidence": lambda: CollisionResolver.normals(bv0, bf, inc),  # noqa: B023
                      "normals, index_add": lambda: vertex_normals(bv, body.faces)}, rounds=args.rounds)  # noqa: B023
        resolution.append([name, ms["pbns"], ms["pbns + resolution"], ms["pbns + post-step"], ms["normals, incidence"],
                           ms["normals, index_add"], ms["normals, index_add"] / ms["normals, incidence"]])
    data = {"machine": report.machine(), "device": str(dev), "speed": speed, "resolution": resolution}
    where = report.describe(data["machine"])
    if dev.type == "cuda":
        where += f", device {torch.cuda.get_device_name(dev)}"
    on = f"{args.threads} thread(s)" if dev.type == "cpu" else str(dev)
    md = "\n".join([
        f"# PBNS inference speed, {on}", "",
        f"`benchmarks/bench_garment.py --threads {args.threads} --device {dev}`; {where}. Frames per second of the "
        "garment "
        "model given joint transforms, and each form's time relative to the shipped `PBNS.pose` (> 1: slower).", "",
        report.table(speed, ["outfit", "vertices", "batch", "FPS shipped", "FPS batch-major", "ratio",
                             "FPS softmax per call", "ratio", "FPS broadcast", "ratio"],
                     ["", "", "", ".0f", ".0f", ".2f", ".0f", ".2f", ".0f", ".2f"]),
        "", "## Collision resolution (batch 1)", "",
        report.table(resolution, ["outfit", "PBNS ms/frame", "+ collision resolution ms/frame",
                                  "+ strain step and collision resolution (post-step) ms/frame",
                                  "body normals: incidence ms", "index_add ms", "ratio"],
                     ["", ".2f", ".1f", ".1f", ".2f", ".2f", ".2f"])])
    stem = f"bench-garment-{args.threads}t" if dev.type == "cpu" else f"bench-garment-{dev.type}"
    print(Path(report.write(OUT / stem, data, md)).read_text())


if __name__ == "__main__":
    main()
