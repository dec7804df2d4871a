"""Where MediaPipe finds nobody, may our backbone answer? (issue 52, item 2: find the people it misses)

    OMP_NUM_THREADS=1 .venv/bin/python eval/backbone_fallback.py --n 800      # ~13 min on 1 core

On the first ``n`` synth-val images (a tuning set, never a test number) runs ``recon run``'s
MediaPipe source without the fallback (heavy landmark model, mirror, retries, person guard) and
our backbone's own crop search (``BackboneSource``) on every image; on the person-free images of
eval/phantoms.py (the 30 sample images, the generator's 600) and the bundled photos, the backbone
alone. For each confidence threshold: images found by MediaPipe or, where it found nobody, by a
backbone at least that confident; the backbone answers' 2D error (mean J+ distance / the person's
box height); bodies invented on the person-free images. ``TRUSTED_CONFIDENCE`` in
recon/keypoints/sources.py is the threshold chosen here. Writes eval/results/backbone-fallback.{json,md}.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from phantoms import person_free_sets  # eval/ sibling
from tqdm import tqdm

from recon import camera, report
from recon.keypoints.sources import TRUSTED_CONFIDENCE, BackboneSource, MediaPipeSource
from recon.smplr.lifter_train import box_height
from recon.synth.dataset import SynthDataset, bench_dir

THRESHOLDS = (0.5, 0.55, 0.6, 0.65, 0.7, 0.75)


def synth_val(n: int, backbone: BackboneSource) -> dict:
    """Per image: MediaPipe found someone, the backbone's confidence and 2D error (% box height)."""
    ds, mediapipe = SynthDataset(bench_dir("synth-val")), MediaPipeSource()
    found, conf, err = [], [], []
    for i in tqdm(range(n), desc="synth-val"):
        s = ds[i]
        k = s["K"].astype(np.float64)
        found.append(mediapipe(s["rgb"], k) is not None)
        kp = backbone(s["rgb"], k)
        conf.append(kp.confidence)
        gt = s["points2d"][None].astype(np.float64)
        err.append(float(np.linalg.norm(kp.points2d - gt[0], axis=-1).mean() / box_height(gt)[0] * 100))
    return {"found": found, "conf": conf, "box_pct": err}


def person_free(sets: dict[str, list], backbone: BackboneSource) -> dict[str, dict[str, float]]:
    """The backbone's confidence on each image of the person-free sets and the bundled photos."""
    return {name: {str(k): backbone(im, camera.default_intrinsics(*im.shape[:2])).confidence
                   for k, im in tqdm(images, desc=name)} for name, images in sets.items()}


def photos_on_crop(sets: dict[str, list], backbone: BackboneSource) -> dict[str, dict[str, float]]:
    """On the bundled photos, the backbone on MediaPipe's crop (as the blend runs it): its confidence
    and its distance from MediaPipe's J+ (median 2D, % of MediaPipe's box height)."""
    mediapipe, out = MediaPipeSource(), {}
    for name, im in sets["bundled photos"]:
        k = camera.default_intrinsics(*im.shape[:2])
        kp = mediapipe(im, k)
        b = backbone.on_crop(im, k, kp)
        d = np.median(np.linalg.norm(b.points2d - kp.points2d, axis=1)) / (kp.box[3] - kp.box[1]) * 100
        out[name] = {"confidence": b.confidence, "from_mediapipe_pct_box": float(d)}
    return out


def study(n: int, phantom_images: int) -> dict:
    backbone = BackboneSource(min_confidence=0.0)  # every answer, scored by its confidence afterwards
    sets = person_free_sets(phantom_images)
    return {"images": n, "synth_val": synth_val(n, backbone), "person_free": person_free(sets, backbone),
            "photos_on_crop": photos_on_crop(sets, backbone), "chosen": TRUSTED_CONFIDENCE,
            "threads": torch.get_num_threads()}


def render(d: dict) -> str:
    v = d["synth_val"]
    found, conf, err = np.array(v["found"]), np.array(v["conf"]), np.array(v["box_pct"])
    free = {k: np.array(list(c.values())) for k, c in d["person_free"].items() if "bundled" not in k}
    rows = [["MediaPipe alone (no fallback)", f"{found.sum()} ({found.mean():.1%})", "-", "-", "-"]
            + ["-" for _ in free]]
    for t in THRESHOLDS:
        stand_in = ~found & (conf >= t)
        rows.append([f"+ backbone at confidence >= {t:g}" + (" (shipped)" if t == d["chosen"] else ""),
                     f"{(found | stand_in).sum()} ({(found | stand_in).mean():.1%})", int(stand_in.sum()),
                     float(err[stand_in].mean()) if stand_in.any() else "-",
                     float(np.median(err[stand_in])) if stand_in.any() else "-"]
                    + [int((c >= t).sum()) for c in free.values()])
    head = ["synth-val source", "images found", "backbone answers", "their 2D % box", "median"] + \
           [f"bodies on {k.split(' (')[0]}" for k in free]
    q = lambda c: ", ".join(f"{x:.2f}" for x in np.quantile(c, (0.5, 0.95, 1.0))) if len(c) else "-"  # noqa: E731
    spread = [["synth-val people MediaPipe found", int(found.sum()), q(conf[found])],
              ["synth-val people MediaPipe missed", int((~found).sum()), q(conf[~found])]]
    spread += [[k, len(c), q(c)] for k, c in free.items()]
    photos = d["person_free"].get("bundled photos", {})
    return "\n".join([
        "# The backbone where MediaPipe finds nobody (issue 52, item 2)", "",
        f"`eval/backbone_fallback.py` on the first {d['images']} synth-val images (tuning set) and the person-free "
        "images of eval/phantoms.py. MediaPipe: `recon run`'s source without the fallback (heavy, mirror, retries, "
        "guard). A backbone answer is its own crop search (`recon run --source backbone`), kept where MediaPipe "
        "found nobody and its mean peak confidence reaches the threshold. 2D error: mean J+ distance / the "
        "person's box height.", "",
        report.table(rows, head, ("", "", "", ".2f", ".2f") + ("",) * len(free)), "",
        "The backbone's mean peak confidence (median, 95th percentile, largest):", "",
        report.table(spread, ["images", "n", "confidence"], ("", "", "")), "",
        "On the bundled photos (real people; the backbone learnt our renders): "
        + ", ".join(f"{k} {c:.2f}" for k, c in photos.items()) + ". There the fallback does not answer: what "
        "MediaPipe misses in photos stays missed. On MediaPipe's crop of them (the blend's two passes, "
        "`BackboneSource.on_crop`): " + ", ".join(
            f"{k} {v['confidence']:.2f} ({v['from_mediapipe_pct_box']:.0f} % of the box from MediaPipe's J+)"
            for k, v in d.get("photos_on_crop", {}).items()) + ": the blend leaves them MediaPipe's.",
    ])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=800)
    ap.add_argument("--phantom-images", type=int, default=600)
    ap.add_argument("--out", default=str(report.RESULTS / "backbone-fallback"))
    a = ap.parse_args()
    torch.set_num_threads(1)
    d = study(a.n, a.phantom_images)
    report.write(Path(a.out), d, render(d))
    print(render(d))


if __name__ == "__main__":
    main()
