"""PBNS inference speed, side by side in one run for every trained outfit: the shipped inference
(``PBNS.pose``: vertex-major in chunks of vertices for batches >= 12, else batch-major) against
three earlier forms: the batch-major forward (the einsum path, the inference before ``pose``),
the blend-weight softmax recomputed every call, and the broadcast-and-sum skinning.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_garment.py [--threads 1] [--repeats 10]

Prints frames per second (median over repeats, float32, CPU) of the garment model alone given
the body's joint transforms (pose -> MLP -> PSD -> skinning), and the ratios shipped / earlier;
then the cost of the collision resolution the Dresser applies (recon.garment.collide) per
frame, and its body normals (sparse incidence matmul) against the index_add of
recon.garment.mesh.vertex_normals, side by side.
"""
from __future__ import annotations

import argparse

import torch

from recon.bench.timing import median_ms


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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 64, 256])
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    from recon.body import default_body
    from recon.garment.pbns import PBNS
    from recon.garment.train import WEIGHTS_DIR, pose_set

    body = default_body()
    rot_all = pose_set("test", max(args.batch), 0.5, seed=123)
    print(f"threads={args.threads}; FPS = frames per second, garment model given joint transforms\n")
    print("| outfit | vertices | batch | FPS shipped | FPS batch-major | ratio | FPS softmax per call | ratio | "
          "FPS broadcast | ratio |\n|---|---|---|---|---|---|---|---|---|---|")
    for path in sorted(WEIGHTS_DIR.glob("pbns_*.pt")):
        model, ck = PBNS.load(path)
        shape = ck["shape"][None]
        for b in args.batch:
            rot = rot_all[torch.arange(b) % len(rot_all)]
            with torch.no_grad():
                t = body(rot, shape.expand(b, -1), points_only=True).transforms
                reps = args.repeats if b > 1 else 20 * args.repeats
                new = median_ms(lambda: model.pose(rot, t), reps)  # noqa: B023
                major = median_ms(lambda: model(rot, t), reps)  # noqa: B023
                soft = median_ms(lambda: skin_softmax(model, model.rest + model.deformation(rot), t), reps)  # noqa: B023
                old = median_ms(lambda: skin_broadcast(model, model.rest + model.deformation(rot), t), reps)  # noqa: B023
            print(f"| {path.stem[5:]} | {model.rest.shape[0]} | {b} | {1000 * b / new:.0f} | "
                  f"{1000 * b / major:.0f} | {major / new:.2f} | {1000 * b / soft:.0f} | {soft / new:.2f} | "
                  f"{1000 * b / old:.0f} | {old / new:.2f} |")
    bench_resolution(body, rot_all, args.repeats)


def bench_resolution(body, rot_all, repeats: int) -> None:
    import numpy as np

    from recon.garment.collide import CollisionResolver
    from recon.garment.mesh import vertex_normals
    from recon.garment.pbns import PBNS
    from recon.garment.train import WEIGHTS_DIR

    print("\n| outfit | PBNS ms/frame | + collision resolution ms/frame | body normals: incidence ms | "
          "index_add ms | ratio |\n|---|---|---|---|---|---|")
    bf = body.faces.numpy()
    for path in sorted(WEIGHTS_DIR.glob("pbns_*.pt")):
        model, ck = PBNS.load(path)
        res = CollisionResolver(model.faces.numpy(), ck["layer"].numpy())
        rot = rot_all[:1]
        with torch.no_grad():
            out = body(rot, ck["shape"][None])
            t = out.transforms
            pbns = median_ms(lambda: model.pose(rot, t), 20 * repeats)  # noqa: B023
        bv = out.vertices
        both = median_ms(lambda: res(model.pose(rot, t), bv, bf), 2 * repeats)  # noqa: B023
        inc = CollisionResolver.incidence(bf, bv.shape[1])
        bv0 = bv[0].numpy()
        n_inc = median_ms(lambda: CollisionResolver.normals(bv0, bf, inc), 5 * repeats)  # noqa: B023
        n_add = median_ms(lambda: vertex_normals(bv, body.faces), 5 * repeats)  # noqa: B023
        assert np.allclose(CollisionResolver.normals(bv0, bf, inc), vertex_normals(bv, body.faces)[0].numpy(), atol=1e-4)
        print(f"| {path.stem[5:]} | {pbns:.2f} | {both:.1f} | {n_inc:.2f} | {n_add:.2f} | {n_add / n_inc:.2f} |")


if __name__ == "__main__":
    main()
