"""Run the keypoint sources over stored synth-val images and cache what they return (one npz per
source in ``<cache>/error-budget/``), for eval/error_budget.py.

    OMP_NUM_THREADS=1 .venv/bin/python eval/collect_sources.py --source mediapipe --n 2000
    OMP_NUM_THREADS=1 .venv/bin/python eval/collect_sources.py --source backbone --n 500
    OMP_NUM_THREADS=1 .venv/bin/python eval/collect_sources.py --data residuals-s5 --n 3000

``residuals-s5`` (``recon synth generate --out ~/.cache/recon/synth/residuals-s5 --split train
--seed 5 --n 3000 --no-vertices``: train-split poses, images no model has seen) gives the 2D
residual bank of the camera-aware lifter's noise model (``recon.smplr.lifter_train``).

Per image: found, J+ 3D (root-relative) and 2D, confidence, box. For MediaPipe, every miss of its
first answer is retried in ways a fallback could use: the views ``MediaPipeSource`` retries
(zero-padded x2; x1.5 at threshold 0.3; mirrored and padded x1.5; threshold 0.3) and others (the
image upscaled x2, padded x1.5, the ground-truth person box cropped and upscaled: the ceiling of
any person detector feeding MediaPipe a crop, threshold 0.2), to tell which are worth it.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm import tqdm

from recon import paths
from recon.backbone.crop import Crop
from recon.body import default_body
from recon.keypoints.sources import BackboneSource, MediaPipeSource
from recon.keypoints.views import pad_image
from recon.people.mediapipe import MediaPipePose
from recon.synth.dataset import BENCHMARKS, SynthDataset, bench_dir

# The first four are the retries `MediaPipeSource` ships (``RETRIES``, in that order); "retries" =
# any of them. The rest are alternatives that were measured and not chosen.
RESCUES = ("pad2", "pad1.5@0.3", "mirror-pad1.5", "conf0.3", "retries", "upscale2", "pad1.5", "gtbox", "conf0.2")


def out_dir() -> Path:
    d = paths.cache_dir() / "error-budget"
    d.mkdir(parents=True, exist_ok=True)
    return d


def gt_box(s: dict, margin: float = 0.2) -> tuple[int, int, int, int]:
    m = s["silhouette"]
    ys, xs = np.nonzero(m)
    x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
    c, half = np.array([(x0 + x1) / 2, (y0 + y1) / 2]), (1 + margin) * max(x1 - x0, y1 - y0) / 2
    return int(c[0] - half), int(c[1] - half), int(c[0] + half), int(c[1] + half)


def rescue(kind: str, rgb: np.ndarray, s: dict, mp: dict[float, MediaPipePose]) -> bool:
    h, w = rgb.shape[:2]
    if kind == "pad2":
        return mp[0.5](pad_image(rgb, 2.0)[0]) is not None
    if kind == "pad1.5@0.3":
        return mp[0.3](pad_image(rgb, 1.5)[0]) is not None
    if kind == "mirror-pad1.5":
        return mp[0.5](np.ascontiguousarray(pad_image(rgb, 1.5)[0][:, ::-1])) is not None
    if kind == "conf0.3":
        return mp[0.3](rgb) is not None
    if kind == "upscale2":
        return mp[0.5](cv2.resize(rgb, (2 * w, 2 * h), interpolation=cv2.INTER_CUBIC)) is not None
    if kind == "pad1.5":
        return mp[0.5](pad_image(rgb, 1.5)[0]) is not None
    if kind == "gtbox":
        x0, y0, x1, y1 = gt_box(s)
        p = max(0, -x0, -y0, x1 - w, y1 - h)
        padded = cv2.copyMakeBorder(rgb, p, p, p, p, cv2.BORDER_CONSTANT, value=(0, 0, 0))
        crop = padded[y0 + p:y1 + p, x0 + p:x1 + p]
        return mp[0.5](cv2.resize(crop, (384, 384), interpolation=cv2.INTER_CUBIC)) is not None
    if kind == "conf0.2":
        return mp[0.2](rgb) is not None
    raise ValueError(kind)


def dataset(name: str) -> SynthDataset:
    """A fixed benchmark by name, else a folder under <cache>/synth (``recon synth generate``)."""
    return SynthDataset(bench_dir(name) if name in BENCHMARKS else paths.cache_dir() / "synth" / name)


def collect(source: str, n: int, data: str = "synth-val") -> Path:
    ds = dataset(data)
    n = min(n, len(ds))
    body = default_body()
    if source == "mediapipe":
        # its first answer (full landmark model, as committed); the rescues below are the retries' study
        src = MediaPipeSource(retry=False, guard=False, model="full")
        mp = {c: MediaPipePose("full", segmentation=False, min_confidence=c) for c in (0.5, 0.3, 0.2)}
    elif source in ("backbone", "backbone-gtcrop"):
        src = BackboneSource(body)
    else:
        raise SystemExit(f"unknown source {source}")
    found = np.zeros(n, bool)
    p3, p2 = np.zeros((n, 42, 3)), np.zeros((n, 42, 2))
    conf, box = np.zeros(n), np.zeros((n, 4))
    rescued = np.zeros((n, len(RESCUES)), bool)
    gt2, gt3 = np.zeros((n, 42, 2)), np.zeros((n, 42, 3))
    for i in tqdm(range(n), desc=source, mininterval=10):
        s = ds[i]
        k = s["K"].astype(np.float64)
        gt2[i], gt3[i] = s["points2d"], s["points3d"]
        if source == "backbone-gtcrop":
            crop = Crop.around(s["points3d"][:24].astype(np.float64).mean(0), k)
            pts, uv, c = src.search.net.predict([s["rgb"]], [crop])
            found[i], p3[i], p2[i], conf[i] = True, pts[0] - pts[0][:1], uv[0], float(np.mean(c))
            continue
        kp = src(s["rgb"], k)
        if kp is None:
            if source == "mediapipe":
                got = {r: rescue(r, s["rgb"], s, mp) for r in RESCUES if r != "retries"}
                got["retries"] = any(got[r] for r in RESCUES[:4])
                rescued[i] = [got[r] for r in RESCUES]
            continue
        found[i], p3[i], p2[i], conf[i], box[i] = True, kp.points3d, kp.points2d, kp.confidence, kp.box
    path = out_dir() / f"{source}-{data}-{n}.npz"
    paths.atomic_write(path, lambda t: np.savez(open(t, "wb"), found=found, points3d=p3, points2d=p2, confidence=conf,
                                                box=box, rescued=rescued, rescues=np.array(RESCUES),
                                                gt_points2d=gt2, gt_points3d=gt3))
    return path


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--source", default="mediapipe", choices=("mediapipe", "backbone", "backbone-gtcrop"))
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--data", default="synth-val", help="benchmark name or folder under <cache>/synth")
    a = ap.parse_args()
    torch.set_num_threads(1)
    print(collect(a.source, a.n, a.data))


if __name__ == "__main__":
    main()
