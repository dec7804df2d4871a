"""Body forward speed: recon's anny backend vs anny's own forward, side by side in one run.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_body.py [--batch 64] [--repeats 20]

Prints ms per batch (median of repeats, float32, CPU) and the ratio. Both compute shaped
vertices from phenotypes and pose the full 13,718-vertex mesh.
"""
from __future__ import annotations

import argparse

import torch

from recon.bench.timing import median_ms as bench


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 64])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    from recon.body import default_body

    body = default_body()
    nb = len(body.anny.bone_labels)
    print(f"threads={args.threads}  vertices={body.num_vertices}  dtype=float32")
    print(f"{'batch':>5} {'mode':>8} {'recon ms':>9} {'anny ms':>8} {'anny/recon':>10}")
    for b in args.batch:
        torch.manual_seed(0)
        pose = 0.3 * torch.randn(b, 24, 3)
        shape = torch.rand(b, 6)
        rot = body.frame.T @ __import__("roma").rotvec_to_rotmat(pose) @ body.frame
        anny_pose = torch.eye(4).repeat(b, nb, 1, 1)
        anny_pose[:, body.bone_ids, :3, :3] = rot
        for mode in ("no-grad", "grad"):
            ctx = torch.no_grad if mode == "no-grad" else torch.enable_grad
            p = pose.clone().requires_grad_(mode == "grad")

            def ours():
                with ctx():
                    out = body(p, shape)
                    if mode == "grad":
                        out.vertices.sum().backward()

            def theirs():
                with ctx():
                    ap_ = anny_pose.clone().requires_grad_(mode == "grad")
                    out = body.anny(pose_parameters=ap_, phenotype_kwargs=shape)
                    if mode == "grad":
                        out["vertices"].sum().backward()

            a, t = bench(ours, args.repeats), bench(theirs, args.repeats)
            print(f"{b:>5} {mode:>8} {a:>9.1f} {t:>8.1f} {t / a:>10.2f}")


if __name__ == "__main__":
    main()
