"""Compare backbone checkpoints on synth-val images outside the selection set (ground-truth crop).

    OMP_NUM_THREADS=2 .venv/bin/python eval/backbone_checkpoints.py recon/backbone/weights/hourglass_base.pt \
        runs/e2e/best.pt [--first 256 --n 512]

Training selects its best checkpoint on the first ``--val-images`` (256 by default) images of
synth-val, so that number is biased for the selected checkpoint; this script renders images
``first .. first + n - 1`` of the same stream and prints, per checkpoint, the pelvis-aligned MPJPE
(mm) of the backbone's joints and of the whole chain (backbone -> DAE -> SMPLR -> body joints).
Used for the end-to-end fine-tuning experiment (eval/results/backbone-e2e-cpu.md).
"""
from __future__ import annotations

import argparse

import torch
from torch.utils.data import DataLoader, Subset

from recon import report
from recon.backbone.crops import RenderedCrops
from recon.backbone.model import Backbone
from recon.backbone.train import EndToEnd, evaluate
from recon.synth.dataset import BENCHMARKS


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("checkpoints", nargs="+")
    ap.add_argument("--first", type=int, default=256)
    ap.add_argument("--n", type=int, default=512)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    b = BENCHMARKS["synth-val"]
    size = None
    nets = []
    for path in a.checkpoints:
        net = Backbone.load(path, jit=False).net  # shipped weights or a run's best.pt
        if size not in (None, net.cfg.input_size):
            raise SystemExit("checkpoints with different input sizes: compare them in separate runs")
        size = net.cfg.input_size
        nets.append((path, net))
    crops = RenderedCrops(b["split"], b["seed"], a.first + a.n, size)
    batches = list(DataLoader(Subset(crops, range(a.first, a.first + a.n)), batch_size=32, num_workers=0))
    chain = EndToEnd()
    rows = [[path, *evaluate(net, batches, "cpu", chain)] for path, net in nets]
    print(f"synth-val images {a.first}-{a.first + a.n - 1}, ground-truth crop, MPJPE-P1 (mm)\n")
    print(report.table(rows, ["checkpoint", "backbone", "backbone -> DAE -> SMPLR"]))


if __name__ == "__main__":
    main()
