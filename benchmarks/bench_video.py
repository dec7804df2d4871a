"""Frames per second of ``recon video`` end to end (one person, 640 x 480), side by side with
``recon run`` on every frame, in one run on this machine.

    .venv/bin/python benchmarks/bench_video.py [--threads 1] [--frames 90] [--repeat 3]

The clip is synth-video-test's ``walk-03_03`` (eval/video.py renders it into the cache). Rows:
``recon video --no-overlay`` with its defaults (MediaPipe's heavy landmark model in video mode; the
per-frame pass's keypoint stage on a second thread, ``recon.video.perframe``), the same with the
two stages one after the other (``VideoOptions(pipeline=False)``, as before 0.15), with 0.14's 120
iterations of the track optimisation, with the full landmark model, with 0.28's feet (planted
from the 2D keypoints alone, no motion prior), and the default with overlay.mp4 (H.264), also
in 0.28's MPEG-4 part 2; ``recon run`` on each frame (its default: heavy
with mirror pass, backbone, per-image fit). Seconds per stage (per-frame pass, tracks = tracking
and the track optimisation, outputs = BVH/glb/JSON, overlay) and frames/s over all, without
loading the models (its seconds are listed). Rows take turns, ``--repeat`` times; each row's
fastest run counts (this machine's speed drifts).
-> eval/results/bench-video.{json,md}
"""
from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from unittest import mock

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "eval"))
from video import clips  # noqa: E402 - eval/video.py renders and caches the benchmark clips

from recon import report  # noqa: E402
from recon.export import media  # noqa: E402
from recon.pipeline import Reconstructor, ReconstructorConfig  # noqa: E402
from recon.synth.video import SIZE  # noqa: E402
from recon.video import FrameRange, FrameSource, SmoothConfig, VideoOptions, video  # noqa: E402
from recon.video.run import video_config, video_reconstructor  # noqa: E402

OUT = Path(__file__).resolve().parent.parent / "eval" / "results" / "bench-video"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    name, path, truth = next(c for c in clips("synth-video-test") if c[0] == "walk-03_03")
    focal = float(truth.K[0, 0]) / max(SIZE)
    frames = FrameRange(end=a.frames / 30.0)
    base = video_config(ReconstructorConfig(focal_factor=focal))
    rows = {
        "`recon video --no-overlay`": (base, {"overlay": False}),
        "`recon video --no-overlay`, the per-frame stages one after the other (as 0.14)":
            (base, {"overlay": False, "pipeline": False}),
        "`recon video --no-overlay --smooth-steps 120` (0.14's iterations)":
            (base, {"overlay": False, "smooth": SmoothConfig(steps=120)}),
        "`recon video --no-overlay --keypoint-model full`": (replace(base, keypoint_model="full"), {"overlay": False}),
        "`recon video --no-overlay`, feet planted from the 2D keypoints alone (as 0.28)":
            (base, {"overlay": False, "smooth": SmoothConfig(contact_from="image")}),
        "`recon video` (with overlay.mp4)": (base, {}),
        "`recon video` (with overlay.mp4 in MPEG-4 part 2, as 0.28)": (base, {"h264": False}),
    }
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(a.repeat):
            for n, (label, (cfg, options)) in enumerate(rows.items()):
                t0 = time.perf_counter()
                rec = video_reconstructor(cfg, 1)
                loading = time.perf_counter() - t0
                opts = {k: v for k, v in options.items() if k != "h264"}
                encoder = mock.patch.object(media, "h264_available", return_value=False) \
                    if options.get("h264", True) is False else contextlib.nullcontext()
                with encoder:
                    res = video(path, Path(tmp) / str(n), VideoOptions(frames=frames, force=True, **opts),
                                reconstructor=rec, progress=False, log=lambda m: None)
                count = len(res.frames.index)
                row = {**{k: v / count * 1000 for k, v in res.seconds.items()}, "frames": count,
                       "fps": count / sum(res.seconds.values()), "loading_s": loading}
                if label not in results or row["fps"] > results[label]["fps"]:
                    results[label] = row
                print(label, round(row["fps"], 2), "frames/s", flush=True)
    rec = Reconstructor(ReconstructorConfig(focal_factor=focal))
    images = [f.rgb for f in FrameSource(path, frames)]
    rec(images[0], truth.K)  # loads the backbone
    total = float("inf")
    for _ in range(a.repeat):
        t0 = time.perf_counter()
        for rgb in images:
            rec.people([rgb], [truth.K], 1)
        total = min(total, time.perf_counter() - t0)
    results["`recon run` on each frame (default)"] = {"per_frame": total / len(images) * 1000, "frames": len(images),
                                                       "fps": len(images) / total}
    ref = results["`recon run` on each frame (default)"]["fps"]
    head = ["", "per-frame pass (ms/frame)", "tracks", "outputs", "overlay", "frames/s", "x recon run",
            "loading (s)"]
    body = [[k, r.get("per_frame"), r.get("tracks"), r.get("outputs"), r.get("overlay"), r["fps"], r["fps"] / ref,
             r.get("loading_s")] for k, r in results.items()]
    md = "\n".join([
        "# `recon video` frames per second", "",
        f"{a.frames} frames of synth-video-test's {name} (640 x 480, one person), torch threads {a.threads}; "
        f"stage times in ms per frame; frames/s without loading the models; each row's fastest of {a.repeat} "
        "runs, rows taking turns (benchmarks/bench_video.py).", "",
        report.table(body, head, [".1f", ".1f", ".1f", ".1f", ".1f", ".2f", ".2f", ".1f"]), "",
        f"Machine: {report.describe(report.machine())}.", ""])
    report.write(OUT, {"clip": name, "frames": a.frames, "threads": a.threads, "repeat": a.repeat, "rows": results,
                       "machine": report.machine()}, md)
    print(md)


if __name__ == "__main__":
    main()
