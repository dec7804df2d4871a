"""Latency of the image pipeline, batch 1, per stage, for both keypoint sources side by side
(median over repeats on the bundled photos, sources interleaved: this machine's speed drifts).

    .venv/bin/python benchmarks/bench_pipeline.py [--repeats 5] [--threads 1]

Stages: keypoints (``recon run``'s people stage: NanoDet's boxes, each read by MediaPipe with
MoveNet fused in; without MoveNet's fusion; without the people stage, as 0.25 found people;
MediaPipe Pose + adapter, with ``recon run``'s backbone blend and fallback (on
these photos the blend's two backbone passes run, but the backbone is not trusted there) and
without, its heavy, full and lite landmark models, with and without the mirror averaging; or our
hourglass: 3 passes = the whole image through the first
hourglass, then two metric crops; also with a flip on the last, 2 passes, the whole network in the
first pass, and eager instead of the TorchScript trace), SMPLR (DAE + Omega + Psi + the full mesh)
+ placement (with MediaPipe, the shape head's reading of the mask too), and the fit (``recon
run``'s default: 30 steps to the keypoints and, with MediaPipe, its person mask; also to the
keypoints only). SMPLR includes the camera-aware lifter (``recon run``'s default ``--lift
blend``); a second MediaPipe row runs 0.2's route (``--lift source``) side by side, and a third
without the shape head.
-> eval/results/bench-pipeline.{json,md}
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import torch

from recon import camera, io, report
from recon.backbone.search import whole_image_crop
from recon.body import default_body
from recon.demo import example_photos
from recon.fit import FitConfig
from recon.keypoints import BackboneSource, MediaPipeSource
from recon.pipeline import Reconstructor
from recon.reconstruction import NoPersonFound, ReconstructorConfig

OUT = Path(__file__).resolve().parent.parent / "eval" / "results" / "bench-pipeline"


COMMANDS = {  # `recon run` over a folder of photos, whole commands (outputs included), on one core
    "`recon run` (defaults)": [],
    "`recon run --no-overlay`": ["--no-overlay"],
    "`recon run --no-detect` (0.25's front end)": ["--no-detect"],
    "0.11.0's defaults (`--no-search --fallback --backbone-weight 0.5`)":
        ["--no-search", "--fallback", "--backbone-weight", "0.5"],
}


def whole_commands(n: int, repeats: int) -> list[list]:
    """Each of ``COMMANDS`` over the first ``n`` images of other-val (640 x 480 / 480 x 640 JPEGs,
    written as files), pinned to one core (taskset) with one torch thread; the median wall time of
    ``repeats`` runs each into a fresh folder, the commands interleaved."""
    from recon.synth.dataset import SynthDataset, bench_dir  # noqa: PLC0415 - only this mode needs it

    ds = SynthDataset(bench_dir("other-val"), keys=("rgb",))
    times: dict[str, list[float]] = {c: [] for c in COMMANDS}
    with tempfile.TemporaryDirectory() as tmp:
        photos = Path(tmp) / "photos"
        photos.mkdir()
        for i in range(n):
            cv2.imwrite(str(photos / f"{i:03d}.jpg"), ds[i]["rgb"][..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 95])
        exe = [sys.executable, "-m", "recon.cli", "--threads", "1", "run", str(photos)]
        pin = ["taskset", "-c", "0"] if shutil.which("taskset") else []
        for r in range(repeats):
            for c, flags in COMMANDS.items():
                out = Path(tmp) / f"out-{r}-{len(times[c])}-{abs(hash(c))}"
                t0 = time.perf_counter()
                subprocess.run(pin + exe + ["--out", str(out), *flags], check=True, capture_output=True,
                               env={**os.environ, "OMP_NUM_THREADS": "1"})
                times[c].append(time.perf_counter() - t0)
    base = statistics.median(times["0.11.0's defaults (`--no-search --fallback --backbone-weight 0.5`)"])
    return [[c, statistics.median(v), statistics.median(v) / n, n / statistics.median(v), statistics.median(v) / base]
            for c, v in times.items()]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--photos", type=int, default=20, help="photos of the whole-command rows (0: none)")
    ap.add_argument("--command-repeats", type=int, default=2)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    body = default_body()
    images = [io.load_image(p) for p in example_photos()]
    cfg = ReconstructorConfig().as_installed()  # recon run's: the people stage, MediaPipe, our backbone

    def mediapipe(**changes) -> MediaPipeSource:
        return MediaPipeSource(**({"fallback": cfg.fallback, "backbone_weight": cfg.backbone_weight,
                                   "detect": cfg.detect, "movenet": cfg.movenet} | changes))

    sources = {"mediapipe (`recon run` default: people stage + heavy landmark model + MoveNet + mirror averaging "
               "+ backbone)": mediapipe(),
               "mediapipe, no people stage (`--no-detect`: 0.25's front end)": mediapipe(detect=False, movenet=0.0),
               "mediapipe, people stage, MoveNet not fused (`--movenet 0`; it still votes)": mediapipe(movenet=0.0),
               "mediapipe alone, no backbone (`--no-fallback --backbone-weight 0`)":
                   mediapipe(fallback=False, backbone_weight=0.0),
               "mediapipe, full landmark model (`--keypoint-model full`)": mediapipe(model="full"),
               "mediapipe, lite landmark model (`--keypoint-model lite`)": mediapipe(model="lite"),
               "mediapipe, no person guard (`--no-guard`)": mediapipe(guard=False),
               "mediapipe, no mirror averaging (`--no-flip`)": mediapipe(flip=False),
               "backbone, 3 passes (`--source backbone`)": BackboneSource(body),
               "backbone, 3 passes, flip on the last (`--flip`)": BackboneSource(body, flip=True),
               "backbone, 2 passes": BackboneSource(body, passes=2),
               "backbone, 3 passes, whole network in the first": BackboneSource(body, quick_locate=False),
               "backbone, 3 passes, eager (no TorchScript)": BackboneSource(body, jit=False)}
    recs = {s: Reconstructor(body=body, source=src) for s, src in sources.items()}
    old = "mediapipe, SMPLR on the adapter's 3D, no lifter (0.2's `recon run`: `--lift source`)"
    headless = "mediapipe, SMPLR's shape, no shape head (`--no-shape-head`)"
    first = sources[next(iter(sources))]
    recs = {**dict(list(recs.items())[:1]), old: Reconstructor(body=body, source=first, lift="source"),
            headless: Reconstructor(body=body, source=first, shape_head=False), **dict(list(recs.items())[1:])}
    sources = {s: r.source for s, r in recs.items()}
    fits = {"none": FitConfig(steps=0), "fit": FitConfig(), "fit, keypoints only": FitConfig(silhouette=0.0)}
    t = {s: {k: [] for k in ("keypoints", "one backbone pass", "smplr", "fit", "fit, keypoints only")} for s in sources}
    missed: dict[str, int] = {}
    for _ in range(a.repeats):  # sources interleaved
        for source, rec in recs.items():
            for img in images:
                k = camera.default_intrinsics(*img.shape[:2])
                rec.fit = fits["none"]
                t0 = time.perf_counter()
                r0 = rec.batch([img], [k])[0]
                total = (time.perf_counter() - t0) * 1000
                if isinstance(r0, NoPersonFound):  # no stage times to compare
                    missed[source] = missed.get(source, 0) + 1
                    continue
                t[source]["keypoints"].append(r0.timings_ms["keypoints"])
                t[source]["smplr"].append(total - r0.timings_ms["keypoints"])
                for name in ("fit", "fit, keypoints only"):
                    rec.fit = fits[name]
                    t[source][name].append(rec.batch([img], [k])[0].timings_ms["refine"])
                if isinstance(rec.source, BackboneSource):
                    t1 = time.perf_counter()
                    rec.source.search.net.predict([img], [whole_image_crop(img.shape, k)])
                    t[source]["one backbone pass"].append((time.perf_counter() - t1) * 1000)
    med = {s: {k: statistics.median(v) if v else None for k, v in ts.items()} for s, ts in t.items()}
    base = next(iter(med.values()))
    base = base["keypoints"] + base["smplr"]
    rows = [[s, m["keypoints"], m["one backbone pass"], m["smplr"], m["keypoints"] + m["smplr"],
             (m["keypoints"] + m["smplr"]) / base, m["fit"], m["fit, keypoints only"]] for s, m in med.items()]
    commands = whole_commands(a.photos, a.command_repeats) if a.photos else []
    data = {"machine": report.machine(), "photos": len(images), "repeats": a.repeats, "median_ms": med,
            "missed": missed, "whole_commands": commands}
    where = report.describe(data["machine"])
    whole = ["", f"## Whole commands: `recon run` over {a.photos} photos of other-val (640 x 480 or 480 x 640 JPEGs), "
             "outputs included", "",
             "Pinned to one core (`taskset -c 0`), `recon --threads 1`, each into a fresh folder; median of "
             f"{a.command_repeats} runs, the commands interleaved. x 0.11: the wall time relative to 0.11.0's "
             "defaults in the same run.", "",
             report.table(commands, ["command", "wall s", "s / photo", "photos / s", "x 0.11"],
                          ["", ".1f", ".2f", ".2f", ".2f"])] if commands else []
    md = "\n".join([
        "# Image pipeline latency, batch 1 (median ms over the bundled photos)", "",
        f"`benchmarks/bench_pipeline.py --repeats {a.repeats} --threads {a.threads}`; {where}. "
        "x MediaPipe: the total without the fit, relative to the first row." +
        "".join(f" {s}: nobody found in {n} of its {a.repeats * len(images)} runs (not timed)."
                for s, n in missed.items()), "",
        report.table(rows, ["source", "keypoints", "of which one backbone pass", "SMPLR (+ shape head) + mesh + place",
                            "total without fit", "x MediaPipe", "fit (30 steps; MediaPipe: + mask)",
                            "fit, keypoints only"], ["", ".1f", ".1f", ".1f", ".1f", ".2f", ".1f", ".1f"]), *whole])
    print(Path(report.write(OUT, data, md)).read_text())


if __name__ == "__main__":
    main()
