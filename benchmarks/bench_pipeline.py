"""Latency of the image pipeline, batch 1, per stage, both keypoint sources side by side
(median over repeats on the bundled photos).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_pipeline.py [--repeats 10]

Stages: keypoints (MediaPipe Pose + adapter, with and without the mirror averaging, or our hourglass: 3 passes = whole image with the
first hourglass only, then two metric crops, the last averaged with its mirror image; also
without that flip, with 2 passes, with the whole network in the first pass, and eager instead of
the TorchScript trace), SMPLR (DAE + Omega + Psi + full anny mesh) + placement, and the optional
fit (`recon run` default: 30 steps, to the keypoints and, with MediaPipe, its person mask; also
to the keypoints only).
Prints ms and each total relative to the MediaPipe pipeline.
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch

from recon import io
from recon.body import default_body
from recon.demo import example_photos
from recon.pipeline import BackboneSource, MediaPipeSource, Reconstructor, default_intrinsics


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=10)
    a = ap.parse_args()
    torch.set_num_threads(1)
    body = default_body()
    images = [io.load_image(p) for p in example_photos()]
    sources = {"mediapipe": "mediapipe",
               "mediapipe, no mirror averaging (`--no-flip`)": MediaPipeSource(flip=False),
               "backbone, 3 passes (default)": BackboneSource(body),
               "backbone, 3 passes, flip on the last (`--flip`)": BackboneSource(body, flip=True),
               "backbone, 2 passes": BackboneSource(body, passes=2),
               "backbone, 3 passes, whole network in the first": BackboneSource(body, quick_locate=False),
               "backbone, 3 passes, eager (no TorchScript)": BackboneSource(body, jit=False)}
    recs = {s: Reconstructor(body, source=src, refine_steps=30) for s, src in sources.items()}
    t = {s: {"keypoints": [], "backbone, one pass": [], "smplr+mesh+place": [], "fit": [], "fit, keypoints only": []}
         for s in sources}
    for _ in range(a.repeats):  # sources interleaved: this machine's speed drifts over minutes
        for source, rec in recs.items():
            for img in images:
                k = default_intrinsics(*img.shape[:2])
                rec.refine_steps = 0
                t0 = time.perf_counter()
                r0 = rec.batch([img], [k])[0]
                total = (time.perf_counter() - t0) * 1000
                t[source]["keypoints"].append(r0.timings_ms["keypoints"])
                t[source]["smplr+mesh+place"].append(total - r0.timings_ms["keypoints"])
                rec.refine_steps = 30
                t[source]["fit"].append(rec.batch([img], [k])[0].timings_ms["refine"])
                sil, rec.silhouette = rec.silhouette, 0.0
                t[source]["fit, keypoints only"].append(rec.batch([img], [k])[0].timings_ms["refine"])
                rec.silhouette = sil
                if isinstance(rec.source, BackboneSource):
                    from recon.backbone.model import whole_image_crop

                    t1 = time.perf_counter()
                    rec.source.net.predict([img], [whole_image_crop(img.shape, k)])
                    t[source]["backbone, one pass"].append((time.perf_counter() - t1) * 1000)
    rows = {s: {k: statistics.median(v) for k, v in ts.items() if v} for s, ts in t.items()}
    print(f"{len(images)} photos x {a.repeats} repeats, 1 thread, batch 1 (median ms)\n")
    print("| source | keypoints | of which one backbone pass | SMPLR + mesh + place | **total without fit** | "
          "x MediaPipe pipeline | fit (30 steps; MediaPipe: + mask) | fit, keypoints only |\n|---|---|---|---|---|---|---|---|")
    base = rows["mediapipe"]["keypoints"] + rows["mediapipe"]["smplr+mesh+place"]
    for s, m in rows.items():
        tot = m["keypoints"] + m["smplr+mesh+place"]
        one = f"{m['backbone, one pass']:.1f}" if "backbone, one pass" in m else "-"
        print(f"| {s} | {m['keypoints']:.1f} | {one} | {m['smplr+mesh+place']:.1f} | **{tot:.1f}** | {tot / base:.2f} | "
              f"{m['fit']:.1f} | {m['fit, keypoints only']:.1f} |")


if __name__ == "__main__":
    main()
