"""NCS (dynamic) against PBNS (quasi-static) inference speed, side by side in one run for every
outfit with NCS weights, given the body's joint transforms:

- batch 1: PBNS on one pose; NCS on one frame streamed with its recurrent state (the motion
  descriptors given); NCS with the descriptors of the frame computed too (the body's forward
  kinematics and the smoothed derivatives over the last 13 frames);
- batch 64: PBNS on 64 poses; NCS on 64 frames of one sequence in one call (the GRU runs over
  them in order).

    .venv/bin/python benchmarks/bench_ncs.py [--threads 1] [--device cuda] [--ncs dress=path/to/ncs_dress.pt ...]

Speed depends on the architecture and the outfit's size, not on how well the weights are trained:
``--ncs`` times NCS files that do not ship (an experiment's).

-> eval/results/bench-ncs-<threads>t.{json,md} on the CPU, bench-ncs-<device>.{json,md} on another
device (the descriptors are computed on the CPU, as the Dresser does).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from recon import report
from recon.body import default_body
from recon.garment import store
from recon.garment.ncs.eval import CHECK_CLIP
from recon.garment.ncs.model import FPS, NCS, SMOOTH, motion_inputs
from recon.garment.ncs.reference_eval import clip_motion
from recon.garment.pbns.model import PBNS
from recon.poses.mocap import MocapPoses
from recon.timing import compare

OUT = Path(__file__).resolve().parent.parent / "eval" / "results"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--ncs", nargs="+", default=[], metavar="OUTFIT=PATH", help="NCS files instead of the shipped")
    ap.add_argument("--device", default="cpu", help="torch device of the garment models (cuda: a GPU)")
    args = ap.parse_args()
    dev = torch.device(args.device)
    given = dict(x.split("=", 1) for x in args.ncs)
    torch.set_num_threads(args.threads)
    body = default_body()
    rot, tr = clip_motion(MocapPoses.load("test"), CHECK_CLIP[0], 0, 64)
    history = 2 * int(np.ceil(3 * SMOOTH * FPS)) + 1  # the frames a descriptor's smoothing reads
    rows = []
    for name in store.trained_outfits():
        path = Path(given.get(name, store.ncs_path(name)))
        if not path.exists():
            continue
        pbns, ck = PBNS.load(store.pbns_path(name))
        ncs, _ = NCS.load(path)
        pbns, ncs, shape = pbns.to(dev), ncs.to(dev), ck["shape"]
        with torch.no_grad():
            static, dynamic, pose, t = (x.to(dev) for x in motion_inputs(body, rot, shape, tr))
            rot_d = rot.to(dev)
            _, h = ncs.animate(static[:8], dynamic[:8], pose[:8], t[:8])
            one = {"PBNS": lambda: pbns.pose(rot_d[8:9], t[8:9]),  # noqa: B023
                   "NCS": lambda: ncs.animate(static[8:9], dynamic[8:9], pose[8:9], t[8:9], h=h),  # noqa: B023
                   "NCS + descriptors": lambda: ncs.animate(  # noqa: B023
                       *[x[-1:].to(dev) for x in motion_inputs(body, rot[:history], shape, tr[:history])],  # noqa: B023
                       h=h)}  # noqa: B023
            ms1 = compare(one, rounds=args.rounds)
            ms64 = compare({"PBNS": lambda: pbns.pose(rot_d, t),  # noqa: B023
                            "NCS": lambda: ncs.animate(static, dynamic, pose, t)}, rounds=args.rounds)  # noqa: B023
        rows.append([name, int(pbns.rest.shape[0]), 1000 / ms1["PBNS"], 1000 / ms1["NCS"],
                     ms1["NCS"] / ms1["PBNS"], 1000 / ms1["NCS + descriptors"],
                     64000 / ms64["PBNS"], 64000 / ms64["NCS"], ms64["NCS"] / ms64["PBNS"]])
    data = {"machine": report.machine(), "device": str(dev), "rows": rows,
            "ncs_files": {k: Path(v).name for k, v in given.items()}}
    where = report.describe(data["machine"])
    if dev.type == "cuda":
        where += f", device {torch.cuda.get_device_name(dev)}"
    on = f"{args.threads} thread(s)" if dev.type == "cpu" else str(dev)
    md = "\n".join([
        f"# NCS vs PBNS inference speed, {on}", "",
        f"`benchmarks/bench_ncs.py --threads {args.threads} --device {dev}`; {where}. Frames per second given the "
        "body's "
        "joint transforms; ratio = NCS time / PBNS time. Batch 1: one frame (NCS streamed with its recurrent "
        "state); batch 64: 64 poses (PBNS) or 64 frames of one sequence (NCS). \"+ descriptors\": NCS with the "
        f"frame's motion descriptors computed (forward kinematics of the last {history} frames)."
        + "".join(f" {o}: `{name}`, not shipped (speed depends on the outfit's size, not on the training)."
                  for o, name in data["ncs_files"].items()), "",
        report.table(rows, ["outfit", "vertices", "PBNS b=1", "NCS b=1", "ratio", "NCS + descriptors b=1",
                            "PBNS b=64", "NCS b=64", "ratio"],
                     ["", "", ".0f", ".0f", ".2f", ".0f", ".0f", ".0f", ".2f"])])
    stem = f"bench-ncs-{args.threads}t" if dev.type == "cpu" else f"bench-ncs-{dev.type}"
    print(Path(report.write(OUT / stem, data, md)).read_text())


if __name__ == "__main__":
    main()
