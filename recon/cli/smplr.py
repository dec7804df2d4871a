"""``recon smplr``: SMPLR's networks and the camera-aware lifter, trained on generated data."""
from __future__ import annotations

from recon.cli.parsing import COUNT, POSITIVE, SEED, Parser, actions, known


def add_smplr(p: Parser) -> None:
    lifter = "recon.smplr.lifter_train:LifterTrainConfig"
    action = actions(p)
    a = action("train", "smplr:train", "train all stages (resumable) and export recon/smplr/weights")
    a.add_argument("--stages", nargs="+", choices=known("recon.smplr.train:STAGES"), default=None)
    a.add_argument("--jobs", type=COUNT, default=2, help="train the two independent chains in parallel")
    a.add_argument("--no-export", action="store_true", help="train only; do not write the weights file")
    a = action("train-lifter", "smplr:train_lifter",
               "train the camera-aware 2D -> 3D lifter on generated cameras (resumable)")
    a.add_argument("--steps", type=COUNT, default=known(lifter, "steps"))
    a.add_argument("--width", type=COUNT, default=known("recon.smplr.lifter:LifterConfig.width"))
    a.add_argument("--blocks", type=COUNT, default=known("recon.smplr.lifter:LifterConfig.blocks"))
    a.add_argument("--lr", type=POSITIVE, default=known(lifter, "lr"))
    a.add_argument("--seed", type=SEED, default=known(lifter, "seed"))
    a.add_argument("--init", default="", help="continue from these lifter weights (warm restart)")
    a.add_argument("--residuals", default=None, help="2D residual bank (eval/collect_sources.py output); "
                   "default: Gaussian 2D noise")
    a.add_argument("--out", default=str(known("recon.smplr.lifter:WEIGHTS")), help="weights file")
    a = action("eval", "smplr:evaluate", "the ablation table on held-out samples -> smplr_anny.{json,md}")
    a.add_argument("--n", type=COUNT, default=known("recon.smplr.evaluate:evaluate_and_report.n"),
                   help="held-out test samples")
    a.add_argument("--out", default=str(known("recon.report:RESULTS")), help="folder of the JSON and Markdown tables")


ADD = {"smplr": add_smplr}

