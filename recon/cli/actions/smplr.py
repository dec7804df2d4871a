"""The actions of ``recon smplr``: SMPLR's networks and the camera-aware lifter, trained on generated data."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from recon.body import default_body
from recon.errors import ReconError
from recon.smplr import evaluate as smplr_eval
from recon.smplr import lifter_train
from recon.smplr import train as smplr_train
from recon.smplr.data import load_or_generate
from recon.smplr.lifter import LifterConfig
from recon.smplr.model import WEIGHTS as SMPLR_WEIGHTS


def train(args) -> None:
    cfg = smplr_train.TrainConfig()
    if args.stages is None and args.jobs > 1:
        # The DAE chain and the Psi -> Omega -> finetune chain are independent: one process
        # (1 thread) each, sharing the generated data, then one export of the best networks.
        load_or_generate(default_body(), "train", cfg.train_size, cfg.seed, cfg.pose_noise_deg)
        load_or_generate(default_body(), "val", cfg.val_size, cfg.seed + 100, 0.0)
        procs = [subprocess.Popen([sys.executable, "-m", "recon.cli", "smplr", "train", "--no-export", "--stages", *c])
                 for c in (["dae3d", "dae2d"], ["psi", "omega", "finetune"])]
        codes = [p.wait() for p in procs]
        if any(codes):
            raise ReconError(f"a training process failed (exit codes {codes}); re-run to resume")
    else:
        smplr_train.run(args.stages or list(smplr_train.STAGES), cfg)
    if not args.no_export:
        print(smplr_train.export(cfg, default_body(), SMPLR_WEIGHTS))


def train_lifter(args) -> None:
    cfg = lifter_train.LifterTrainConfig(steps=args.steps, lr=args.lr, seed=args.seed, init=args.init)
    residuals = Path(args.residuals) if args.residuals else None
    if residuals is not None and not residuals.exists():
        raise ReconError(f"{residuals} not found: make it with eval/collect_sources.py (docs/smplr.md)")
    meta = lifter_train.train(Path(args.out), cfg, LifterConfig(width=args.width, blocks=args.blocks), residuals)
    print(f"{args.out}: best synthetic validation J+ error {meta['best_val_mpjpe_mm']:.1f} mm "
          f"after {meta['train_seconds'] / 60:.1f} min")


def evaluate(args) -> None:
    print(Path(smplr_eval.evaluate_and_report(n=args.n, out_dir=Path(args.out))).read_text())

