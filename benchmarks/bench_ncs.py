"""NCS (dynamic) against PBNS (quasi-static) inference speed, side by side in one run for every
outfit with NCS weights, given the body's joint transforms:

- batch 1: PBNS on one pose; NCS on one frame streamed with its recurrent state (the motion
  descriptors given); NCS with the descriptors of the frame computed too (the body's forward
  kinematics and the smoothed derivatives over the last 13 frames);
- batch 64: PBNS on 64 poses; NCS on 64 frames of one sequence in one call (the GRU runs over
  them in order).

    .venv/bin/python benchmarks/bench_ncs.py [--threads 1] [--ncs dress=path/to/ncs_dress.pt ...]

Speed depends on the architecture and the outfit's size, not on how well the weights are trained:
``--ncs`` times NCS files that do not ship (an experiment's).

-> eval/results/bench-ncs-<threads>t.{json,md}
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from recon import report
from recon.body import default_body
from recon.garment import store
from recon.garment.evaluate_ncs import CHECK_CLIP, _clip
from recon.garment.ncs import FPS, NCS, SMOOTH, motion_inputs
from recon.garment.pbns import PBNS
from recon.poses.mocap import MocapPoses
from recon.timing import compare

OUT = Path(__file__).resolve().parent.parent / "eval" / "results"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--ncs", nargs="+", default=[], metavar="OUTFIT=PATH", help="NCS files instead of the shipped")
    args = ap.parse_args()
    given = dict(x.split("=", 1) for x in args.ncs)
    torch.set_num_threads(args.threads)
    body = default_body()
    rot, tr = _clip(MocapPoses.load("test"), CHECK_CLIP[0], 0, 64)
    history = 2 * int(np.ceil(3 * SMOOTH * FPS)) + 1  # the frames a descriptor's smoothing reads
    rows = []
    for name in store.trained_outfits():
        path = Path(given.get(name, store.ncs_path(name)))
        if not path.exists():
            continue
        pbns, ck = PBNS.load(store.pbns_path(name))
        ncs, _ = NCS.load(path)
        shape = ck["shape"]
        with torch.no_grad():
            static, dynamic, pose, t = motion_inputs(body, rot, shape, tr)
            _, h = ncs.animate(static[:8], dynamic[:8], pose[:8], t[:8])
            one = {"PBNS": lambda: pbns.pose(rot[8:9], t[8:9]),  # noqa: B023
                   "NCS": lambda: ncs.animate(static[8:9], dynamic[8:9], pose[8:9], t[8:9], h=h),  # noqa: B023
                   "NCS + descriptors": lambda: ncs.animate(  # noqa: B023
                       *[x[-1:] for x in motion_inputs(body, rot[:history], shape, tr[:history])], h=h)}  # noqa: B023
            ms1 = compare(one, rounds=args.rounds)
            ms64 = compare({"PBNS": lambda: pbns.pose(rot, t),  # noqa: B023
                            "NCS": lambda: ncs.animate(static, dynamic, pose, t)}, rounds=args.rounds)  # noqa: B023
        rows.append([name, int(pbns.rest.shape[0]), 1000 / ms1["PBNS"], 1000 / ms1["NCS"],
                     ms1["NCS"] / ms1["PBNS"], 1000 / ms1["NCS + descriptors"],
                     64000 / ms64["PBNS"], 64000 / ms64["NCS"], ms64["NCS"] / ms64["PBNS"]])
    data = {"machine": report.machine(), "rows": rows, "ncs_files": {k: Path(v).name for k, v in given.items()}}
    where = report.describe(data["machine"])
    md = "\n".join([
        f"# NCS vs PBNS inference speed, {args.threads} thread(s)", "",
        f"`benchmarks/bench_ncs.py --threads {args.threads}`; {where}. Frames per second given the body's "
        "joint transforms; ratio = NCS time / PBNS time. Batch 1: one frame (NCS streamed with its recurrent "
        "state); batch 64: 64 poses (PBNS) or 64 frames of one sequence (NCS). \"+ descriptors\": NCS with the "
        f"frame's motion descriptors computed (forward kinematics of the last {history} frames)."
        + "".join(f" {o}: `{name}`, not shipped (speed depends on the outfit's size, not on the training)."
                  for o, name in data["ncs_files"].items()), "",
        report.table(rows, ["outfit", "vertices", "PBNS b=1", "NCS b=1", "ratio", "NCS + descriptors b=1",
                            "PBNS b=64", "NCS b=64", "ratio"],
                     ["", "", ".0f", ".0f", ".2f", ".0f", ".0f", ".0f", ".2f"])])
    print(Path(report.write(OUT / f"bench-ncs-{args.threads}t", data, md)).read_text())


if __name__ == "__main__":
    main()
