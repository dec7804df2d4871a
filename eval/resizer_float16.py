"""How far float16 storage moves the resizer tables: each outfit's whole garment-resize table (200
test conditions) computed with the shipped float16 resizer and with the float32 file it was
rounded from (read from git at REV), side by side; prints the largest change per outfit.

    OMP_NUM_THREADS=1 .venv/bin/python eval/resizer_float16.py [--rev 96a589e]   # ~5 min
"""
from __future__ import annotations

import argparse
import subprocess
import tempfile
from pathlib import Path

import torch
from weights_float16 import largest_changes  # eval/ sibling

from recon.body import default_body
from recon.garment import store
from recon.garment.pbns import eval as pbns_eval
from recon.garment.templates import PRESETS

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rev", default="96a589e", help="a commit with the float32 resizers")
    args = ap.parse_args()
    torch.set_num_threads(1)
    body, old_dir, shipped = default_body(), Path(tempfile.mkdtemp()), store.resizer_path
    for outfit in PRESETS:
        old = old_dir / f"resize_{outfit}.pt"
        old.write_bytes(subprocess.run(["git", "show", f"{args.rev}:recon/garment/weights/{old.name}"], cwd=ROOT,
                                       check=True, capture_output=True).stdout)
        new_rows = pbns_eval.resize_rows(body, outfit, 200)[0]
        store.resizer_path = lambda name, pbns=None: old_dir / f"resize_{name}.pt"
        try:
            old_rows = pbns_eval.resize_rows(body, outfit, 200)[0]
        finally:
            store.resizer_path = shipped
        largest, where = max(largest_changes(old_rows, new_rows))
        print(f"{outfit}: largest change {largest:.2g} at {where}")


if __name__ == "__main__":
    main()
