"""Write the training record a weights file carries (its config and learning curve) as readable
JSON beside the other results, when new weights are shipped.

    .venv/bin/python scripts/training_record.py recon/garment/weights/pbns_dress.pt
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from recon import paths

OUT = Path(__file__).resolve().parent.parent / "eval" / "results" / "training"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("weights", type=Path, nargs="+")
    for w in ap.parse_args().weights:
        ck = paths.load_checkpoint(w, "the trainer that wrote it")
        if "meta_json" in ck:  # PBNS, resizers, the keypoint adapter
            record = json.loads(ck["meta_json"])
        elif "curve_json" in ck:  # the backbone
            keys = ("config", "train_config", "step", "val_mpjpe_mm", "fine_tuned_from")
            record = {k: ck[k] for k in keys if k in ck}
            record["history"] = json.loads(ck["curve_json"])
        else:
            raise SystemExit(f"{w} carries no training record")
        print(paths.write_text(OUT / f"{w.stem}.json", json.dumps(record, indent=1) + "\n"))


if __name__ == "__main__":
    main()
