"""The crop search's depth factors, calibrated on synth-val (``recon backbone calibrate``, and
``recon backbone train`` after training), and the committed check of the search's first pass
(``check``, recomputed by tests/test_results.py): the data side of ``recon.backbone.search``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from recon import paths
from recon.backbone.model import WEIGHTS, Backbone
from recon.backbone.search import CropSearch, crop_from_keypoints, whole_image_crop
from recon.body import default_body
from recon.body.base import BodyModel
from recon.smplr.features import template_distances
from recon.synth.dataset import BENCHMARKS, SynthDataset, bench_dir
from recon.synth.scene import SceneSampler

DEPTH_METHOD = "foreshortened"  # the crop-depth estimate that calibration writes
CHECK_FIRST, CHECK_IMAGES = 300, 8  # the synth-val slice tests/test_results.py recomputes


def calibrate_depth_scale(search: CropSearch, samples, passes: int = 2) -> tuple[float, ...]:
    """Median (true crop depth / estimated crop depth) after each of the first ``passes`` passes
    of ``search`` over ``samples`` (dicts with rgb, K, points3d), for the estimate
    ``search.net.depth_method`` names. Run on synth-val; the factors absorb the template's size
    against the sampled bodies and the network's pull towards the crop centre (which shrinks 2D
    bones when the person is small in the first pass)."""
    scale: list[float] = []
    for p in range(passes):
        ratios = []
        for s in samples:
            k = s["K"].astype(np.float64)
            # the crop of pass p + 2 is the raw estimate after pass p + 1 (each pass as at run time)
            _, _, _, crop = search.locate(s["rgb"], k, depth_scale=scale + [1.0], passes=p + 2)
            ratios.append(float(s["points3d"][:24].astype(np.float64).mean(0)[2]) / crop.zc)
        scale.append(float(np.median(ratios)))
    return tuple(scale)


def calibrated(ck: dict, calibrate_on: int = 300, body: BodyModel | None = None) -> dict:
    """``ck`` (a weights checkpoint) with crop-depth factors for ``DEPTH_METHOD`` calibrated on
    the first ``calibrate_on`` images of the stored synth-val benchmark."""
    ck = ck | {"crop_depth_method": DEPTH_METHOD, "crop_depth_scale": (1.0, 1.0)}
    search = CropSearch(Backbone.from_checkpoint(ck), template_distances(body or default_body()).cpu().numpy())
    ds = SynthDataset(bench_dir("synth-val"))
    return ck | {"crop_depth_scale": calibrate_depth_scale(search, [ds[i] for i in range(calibrate_on)])}


def calibrate(weights: Path, out: Path | None = None, calibrate_on: int = 300) -> Path:
    """``recon backbone calibrate``: (re)calibrate the crop-depth factors of a weights file for
    ``DEPTH_METHOD``; writes ``out`` (default: in place, atomically)."""
    weights = Path(weights)
    ck = calibrated(paths.load_checkpoint(weights, "recon backbone train + export"), calibrate_on)
    out = Path(out or weights)
    paths.atomic_write(out, lambda t: torch.save(ck, t))
    return out


def check(first: int = CHECK_FIRST, n: int = CHECK_IMAGES) -> dict:
    """The shipped search's first pass (the whole image through the first hourglass) on synth-val
    images first .. first + n - 1, rendered on the fly: per image the depth (m) of the crop it
    chooses for the next pass and the mean of its 24 joints in the image (px), the continuous
    quantities before the search's first crop. The later passes see crops those choose, which a
    CPU's last bits can move: their accuracy is the benchmark (backbone-crop-search.md)."""
    body = default_body()
    b = BENCHMARKS["synth-val"]
    scenes = SceneSampler(body, b["split"], b["seed"])
    search = CropSearch.load(body, WEIGHTS)
    depth, centre = [], []
    for i in range(first, first + n):
        s = scenes.sample(i)
        k = s["K"].astype(np.float64)
        pts, uv, _ = search.net.predict([s["rgb"]], [whole_image_crop(s["rgb"].shape, k)],
                                        locate=search.quick_locate)
        crop = crop_from_keypoints(uv[0], k, search.template, search.net.depth_scale[0],
                                   search.depth_points(pts[0]))
        depth.append(float(crop.zc))
        centre.append(uv[0][:24].mean(0).astype(float).tolist())
    return {"first_crop_depth_m": depth, "first_pass_joints_px": centre}
