"""Body forward speed: recon's anny backend vs anny's own forward, side by side in one run.

    .venv/bin/python benchmarks/bench_body.py [--batch 1 64] [--threads 1]

ms per batch (median, float32, CPU) and the ratio; both compute shaped vertices from phenotypes
and pose the full 13,718-vertex mesh; also forward kinematics level by level (recon.body.lbs)
against the joint-by-joint recursion. -> eval/results/bench-body.{json,md}
"""
from __future__ import annotations

import argparse
from pathlib import Path

import roma
import torch

from recon import report
from recon.body import default_body, lbs
from recon.timing import compare

OUT = Path(__file__).resolve().parent.parent / "eval" / "results" / "bench-body"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 64])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    body = default_body()
    nb = len(body.anny.bone_labels)
    rows = []
    for b in args.batch:
        torch.manual_seed(0)
        pose, shape = 0.3 * torch.randn(b, 24, 3), torch.rand(b, 6)
        rot = body.frame.T @ roma.rotvec_to_rotmat(pose) @ body.frame
        anny_pose = torch.eye(4).repeat(b, nb, 1, 1)
        anny_pose[:, body.bone_ids, :3, :3] = rot
        rest = body.rest_geometry(shape)[1].detach()
        for mode in ("no-grad", "grad"):
            ctx = torch.no_grad if mode == "no-grad" else torch.enable_grad

            def ours(mode=mode, ctx=ctx, pose=pose, shape=shape):
                with ctx():
                    out = body(pose.clone().requires_grad_(mode == "grad"), shape)
                    if mode == "grad":
                        out.vertices.sum().backward()

            def theirs(mode=mode, ctx=ctx, anny_pose=anny_pose, shape=shape):
                with ctx():
                    out = body.anny(pose_parameters=anny_pose.clone().requires_grad_(mode == "grad"),
                                    phenotype_kwargs=shape)
                    if mode == "grad":
                        out["vertices"].sum().backward()

            ms = compare({"recon": ours, "anny": theirs}, rounds=args.rounds)
            rows.append([b, mode, ms["recon"], ms["anny"], ms["anny"] / ms["recon"]])
        rm = roma.rotvec_to_rotmat(pose)
        fk = compare({"levels": lambda rm=rm, rest=rest: lbs.forward_kinematics(rm, rest, body.parents),
                      "joints": lambda rm=rm, rest=rest: lbs.forward_kinematics_sequential(rm, rest, body.parents)},
                     rounds=args.rounds)
        rows.append([b, "FK only: level by level vs joint by joint", fk["levels"], fk["joints"],
                     fk["joints"] / fk["levels"]])
    data = {"machine": report.machine(), "rows": [dict(zip(("batch", "mode", "recon_ms", "other_ms", "ratio"), r))
                                                  for r in rows]}
    where = report.describe(data["machine"])
    md = "\n".join(["# Body forward: recon's anny backend vs anny's own forward",
                    "", f"`benchmarks/bench_body.py --threads {args.threads}`; {where}", "",
                    report.table(rows, ["batch", "mode", "recon ms", "anny ms (FK: joint by joint)", "other / recon"],
                                 ["", "", ".2f", ".2f", ".2f"])])
    print(Path(report.write(OUT, data, md)).read_text())


if __name__ == "__main__":
    main()
