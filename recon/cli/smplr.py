"""``recon smplr``: SMPLR's networks and the camera-aware lifter, trained on generated data."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from recon import report
from recon.body import default_body
from recon.cli.parsing import COUNT, POSITIVE, SEED, Parser, actions, default
from recon.errors import ReconError
from recon.smplr import evaluate as smplr_eval
from recon.smplr import lifter_train
from recon.smplr import train as smplr_train
from recon.smplr.data import load_or_generate
from recon.smplr.lifter import WEIGHTS as LIFTER_WEIGHTS
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


def add_smplr(p: Parser) -> None:
    action = actions(p)
    a = action("train", train, "train all stages (resumable) and export recon/smplr/weights")
    a.add_argument("--stages", nargs="+", choices=smplr_train.STAGES, default=None)
    a.add_argument("--jobs", type=COUNT, default=2, help="train the two independent chains in parallel")
    a.add_argument("--no-export", action="store_true", help="train only; do not write the weights file")
    a = action("train-lifter", train_lifter, "train the camera-aware 2D -> 3D lifter on generated cameras (resumable)")
    a.add_argument("--steps", type=COUNT, default=default(lifter_train.LifterTrainConfig, "steps"))
    a.add_argument("--width", type=COUNT, default=default(LifterConfig, "width"))
    a.add_argument("--blocks", type=COUNT, default=default(LifterConfig, "blocks"))
    a.add_argument("--lr", type=POSITIVE, default=default(lifter_train.LifterTrainConfig, "lr"))
    a.add_argument("--seed", type=SEED, default=default(lifter_train.LifterTrainConfig, "seed"))
    a.add_argument("--init", default="", help="continue from these lifter weights (warm restart)")
    a.add_argument("--residuals", default=None, help="2D residual bank (eval/collect_sources.py output); "
                   "default: Gaussian 2D noise")
    a.add_argument("--out", default=str(LIFTER_WEIGHTS), help="weights file")
    a = action("eval", evaluate, "the ablation table on held-out samples -> smplr_anny.{json,md}")
    a.add_argument("--n", type=COUNT, default=default(smplr_eval.evaluate_and_report, "n"),
                   help="held-out test samples")
    a.add_argument("--out", default=str(report.RESULTS), help="folder of the JSON and Markdown tables")


ADD = {"smplr": add_smplr}
