"""Frames per second of ``recon video`` end to end (one person, 640 x 480), side by side with
``recon run`` on every frame, in one run on this machine.

    .venv/bin/python benchmarks/bench_video.py [--threads 1] [--frames 90]

The clip is synth-video-test's ``walk-03_03`` (eval/video.py renders it into the cache). Rows:
``recon video``'s default (heavy landmark model in video mode, our backbone blended where it is
confident, which it is on these renders), then without the backbone (``--backbone-weight 0``: the
cost on real footage, where after three frames it is not asked again for 30), with the full
landmark model, and with the overlay video; ``recon run`` on each frame (its default: heavy with
mirror pass, backbone, per-image fit). Seconds per stage (per-frame pass, tracks = tracking and
the track optimisation, outputs = BVH/glb/JSON, overlay) and frames/s over all.
-> eval/results/bench-video.{json,md}
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "eval"))
from video import clips  # noqa: E402 - eval/video.py renders and caches the benchmark clips

from recon import report  # noqa: E402
from recon.pipeline import Reconstructor, ReconstructorConfig  # noqa: E402
from recon.synth.video import SIZE  # noqa: E402
from recon.video import FrameRange, FrameSource, VideoOptions, video  # noqa: E402
from recon.video.run import video_config  # noqa: E402

OUT = Path(__file__).resolve().parent.parent / "eval" / "results" / "bench-video"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--frames", type=int, default=90)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    name, path, truth = next(c for c in clips("synth-video-test") if c[0] == "walk-03_03")
    focal = float(truth.K[0, 0]) / max(SIZE)
    frames = FrameRange(end=a.frames / 30.0)
    base = video_config(ReconstructorConfig(focal_factor=focal))
    rows = {
        "`recon video` (heavy, video mode, backbone where confident)": (base, False),
        "`recon video --backbone-weight 0` (as on real footage)": (replace(base, backbone_weight=0.0), False),
        "`recon video --keypoint-model full --backbone-weight 0`":
            (replace(base, backbone_weight=0.0, keypoint_model="full"), False),
        "`recon video`, with overlay.mp4": (base, True),
    }
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for n, (label, (cfg, overlay)) in enumerate(rows.items()):
            t0 = time.perf_counter()
            res = video(path, Path(tmp) / str(n), VideoOptions(frames=frames, overlay=overlay), cfg, progress=False,
                        log=lambda m: None)
            total = time.perf_counter() - t0
            count = len(res.frames.index)
            results[label] = {**{k: v / count * 1000 for k, v in res.seconds.items()}, "frames": count,
                              "fps": count / total}
            print(label, round(count / total, 2), "frames/s", flush=True)
    rec = Reconstructor(ReconstructorConfig(focal_factor=focal))
    images = [f.rgb for f in FrameSource(path, frames)]
    rec(images[0], truth.K)  # loads the backbone
    t0 = time.perf_counter()
    for rgb in images:
        rec.people([rgb], [truth.K], 1)
    total = time.perf_counter() - t0
    results["`recon run` on each frame (default)"] = {"per_frame": total / len(images) * 1000, "frames": len(images),
                                                       "fps": len(images) / total}
    ref = results["`recon run` on each frame (default)"]["fps"]
    head = ["", "per-frame pass (ms/frame)", "tracks", "outputs", "overlay", "frames/s", "x recon run"]
    body = [[k, r.get("per_frame"), r.get("tracks"), r.get("outputs"), r.get("overlay"), r["fps"], r["fps"] / ref]
            for k, r in results.items()]
    md = "\n".join([
        "# `recon video` frames per second", "",
        f"{a.frames} frames of synth-video-test's {name} (640 x 480, one person), torch threads {a.threads}; "
        "stage times in ms per frame (benchmarks/bench_video.py).", "",
        report.table(body, head, [".1f", ".1f", ".1f", ".1f", ".1f", ".2f", ".2f"]), "",
        f"Machine: {report.describe(report.machine())}.", ""])
    report.write(OUT, {"clip": name, "frames": a.frames, "threads": a.threads, "rows": results,
                       "machine": report.machine()}, md)
    print(md)


if __name__ == "__main__":
    main()
