"""Train the motion prior of ``recon video`` (recon.video.prior_train) and write its weights.

    OMP_NUM_THREADS=2 .venv/bin/python scripts/train_motion_prior.py [--steps N] [--out FILE]
"""
from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

from recon.video import prior, prior_train


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    cfg = prior_train.PriorTrainConfig()
    ap.add_argument("--steps", type=int, default=cfg.steps)
    ap.add_argument("--width", type=int, default=prior.PriorConfig().width)
    ap.add_argument("--seed", type=int, default=cfg.seed)
    ap.add_argument("--calibration", type=float, nargs=2, default=cfg.calibration, metavar=("SLOW", "FAST"),
                    help="the rotation noise's scale (bias and slow part; the fast part further)")
    ap.add_argument("--noise", default=str(prior_train.NOISE), help="eval/motion_noise.py's measurement")
    ap.add_argument("--out", default=str(prior.WEIGHTS))
    args = ap.parse_args()
    cfg = replace(cfg, steps=args.steps, seed=args.seed, calibration=tuple(args.calibration))
    res = prior_train.train(Path(args.out), cfg, prior.PriorConfig(width=args.width), Path(args.noise))
    print(json.dumps(res["best"], indent=1))


if __name__ == "__main__":
    main()
