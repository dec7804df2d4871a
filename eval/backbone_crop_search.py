"""The backbone's crop search without ground truth, variant by variant, on stored synth-val images.

    OMP_NUM_THREADS=1 .venv/bin/python eval/backbone_crop_search.py [--calibrate 300 --n 500]

``recon.backbone.search.CropSearch`` finds the person by itself: a whole-image pass, then metric
crops at a depth estimated from the predicted bones. For each variant — the depth estimate
(plain bone lengths x 0.85, or each bone foreshortened as the previous pass predicted it in 3D)
and the locating pass (whole network, or its first hourglass only) — the crop factors are
calibrated on synth-val images 0 .. calibrate-1 (as `recon backbone calibrate` does) and the
pelvis-aligned joint MPJPE (mm) after 2, 3 and 4 passes is measured on the next ``n`` images,
with the median depth error of the last crop. Results: eval/results/backbone-crop-search.md.
"""
from __future__ import annotations

import argparse

import numpy as np
import torch

from recon import report
from recon.backbone.calibrate import calibrate_depth_scale
from recon.backbone.search import CropSearch
from recon.body import default_body
from recon.synth.dataset import SynthDataset, bench_dir


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--calibrate", type=int, default=300)
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    body = default_body()
    ds = SynthDataset(bench_dir("synth-val"))
    cal = [ds[i] for i in range(a.calibrate)]
    test = [ds[i] for i in range(a.calibrate, a.calibrate + a.n)]
    print(f"synth-val: factors calibrated on images 0-{a.calibrate - 1}, scored on "
          f"{a.calibrate}-{a.calibrate + a.n - 1}; MPJPE mm (mean / median), depth error = median "
          "|log(true / crop depth)| of the last crop, %\n")
    rows = []
    for method in ("bones", "foreshortened"):
        for quick in (False, True):
            src = CropSearch.load(body, quick_locate=quick)
            src.net.depth_method = method
            src.net.depth_scale = calibrate_depth_scale(src, cal, passes=3)
            cells, depth = [], None
            for passes in (2, 3, 4):
                err, lz = [], []
                for s in test:
                    k = s["K"].astype(np.float64)
                    pts, _, _, crop = src.locate(s["rgb"], k, passes=passes)
                    gt = s["points3d"].astype(np.float64)
                    err.append(np.linalg.norm((pts[:24] - pts[:1]) - (gt[:24] - gt[:1]), axis=1).mean() * 1000)
                    lz.append(abs(np.log(gt[:24].mean(0)[2] / crop.zc)))
                cells.append(f"{np.mean(err):.1f} / {np.median(err):.1f}")
                if passes == 3:
                    depth = 100 * float(np.median(lz))
            rows.append([method, "first hourglass" if quick else "whole network",
                         ", ".join(f"{f:.3f}" for f in src.net.depth_scale), *cells, depth])
    print(report.table(rows, ["depth estimate", "locating pass", "factors", "2 passes", "3 passes", "4 passes",
                              "depth error, 3 passes"]))


if __name__ == "__main__":
    main()
