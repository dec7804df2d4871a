"""The camera-turn estimator alone (``recon.video.camera_motion``) against the truth, and its
ablations: every clip of the four video sets, hard still clips (a walker close to the camera, two
people, both also as a portrait crop whose background is a few columns) and a close pan, fed the
people's true boxes (their landmarks' extent, as the keypoint stage gives them); and OpenCV's
vtest.avi (80 s from a fixed camera, real footage; nobody masked) where scripts/setup.sh extracted it.

    .venv/bin/python eval/camera_turn.py      # ~5 min on one core

Rows: the estimator as shipped; "chained": each frame matched to the one before (a new key
every frame); "no confidence": every step that could be fitted is taken as measured (no limit on
inliers' share, spread, rate or spikes). Per group of clips: still clips, the largest turn read
and how many read over 1 degree or taken as turning (over 2, known); turning clips, the largest and
mean error of any frame's camera (degrees) and how many would be taken as still.
-> eval/results/camera-turn.{json,md}
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import cv2
import numpy as np
import video as video_eval  # eval/video.py, beside this file

from recon import camera, paths, report
from recon.body import default_body
from recon.synth.photos import photo_path
from recon.synth.video import VIDEO_GENERATOR, Actor, ClipRenderer, ClipSpec, ClipTruth, write_clip
from recon.video.camera_motion import CameraRotations, TurnEstimate, turned_degrees
from recon.video.frames import FrameSource

SETS = ("synth-video-val", "synth-video-moving-val", "synth-video-test", "synth-video-moving-test")
HARD = [ClipSpec("close-walk", (Actor("03_03", 200),), 90, 51, "middle", 1.8),
        ClipSpec("close-two", (Actor("03_01", 0, (0.0, 0.4), 0.0), Actor("14_17", 100, (0.6, -0.4))), 90, 52,
                 "middle", 2.2, yaw=20.0),
        ClipSpec("close-pan", (Actor("02_01"),), 80, 53, "middle", 2.0, camera="pan")]
PORTRAIT = (185, 455)  # columns kept of the 640: a 270 x 480 portrait frame
VTEST = ("opencv-doc", "usr/share/doc/opencv-doc/examples/data", "vtest.avi")  # recon.synth.photos.photo_path
VARIANTS = {
    "recon video (key frames, confidence)": {},
    "chained frame to frame": {"rekey_share": np.inf},
    "no confidence": {"min_points": 12, "min_inlier_share": 0.0, "min_spread": 0.0, "max_degrees_per_second": np.inf,
                      "spike_degrees_per_second": np.inf},
}


def hard_clips(renderer) -> list[tuple[str, list[np.ndarray], ClipTruth]]:
    """The hard clips, rendered into the cache when missing, whole and as a portrait crop."""
    root = paths.cache_dir() / "synth" / f"camera-turn-hard-v{VIDEO_GENERATOR}"
    out = []
    for spec in HARD:
        mp4, npz = root / f"{spec.name}.mp4", root / f"{spec.name}.npz"
        if not (mp4.exists() and npz.exists()):
            frames, truth = renderer.render(spec)
            write_clip(frames, mp4)
            truth.save(npz)
        frames, truth = [f.rgb for f in FrameSource(mp4)], ClipTruth.load(npz)
        out.append((spec.name, frames, truth))
        k = truth.K.copy()
        k[0, 2] -= PORTRAIT[0]
        out.append((spec.name + " (portrait)", [np.ascontiguousarray(f[:, PORTRAIT[0]:PORTRAIT[1]]) for f in frames],
                    replace(truth, K=k)))
    return out


def true_boxes(truth: ClipTruth) -> list[np.ndarray]:
    """Per frame (n, 4): the extent of each visible person's landmarks."""
    out = []
    for f in range(truth.points.shape[1]):
        boxes = []
        for p in np.flatnonzero(truth.visible[:, f]):
            uv = camera.project(truth.points[p, f], truth.K)
            boxes.append([*uv.min(0), *uv.max(0)])
        out.append(np.array(boxes, float).reshape(-1, 4))
    return out


def errors(found: TurnEstimate, truth: ClipTruth) -> np.ndarray:
    """(T,) degrees between each frame's found turn and the true one."""
    cos = (np.einsum("fij,fij->f", found.rotations, video_eval.true_turns(truth)) - 1) / 2
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def score(clips, variant: dict, fps: float = 30.0) -> dict:
    """Per clip: the true and found turn, the share measured, the largest and mean frame error."""
    out = {}
    for name, frames, truth in clips:
        boxes = true_boxes(truth)
        t0 = time.perf_counter()
        found = CameraRotations(truth.K, fps, **variant)(zip(frames, boxes, strict=True))
        seconds = time.perf_counter() - t0
        e = errors(found, truth)
        out[name] = {"true": video_eval.true_turn(truth), "found": found.degrees, "known": found.known,
                     "turned": found.turned, "measured": found.measured_share, "max_error": float(e.max()),
                     "mean_error": float(e.mean()), "ms_per_frame": 1000 * seconds / len(frames)}
    return out


def summary(per_clip: dict) -> dict:
    still = {n: c for n, c in per_clip.items() if c["true"] < 0.1}
    moving = {n: c for n, c in per_clip.items() if c["true"] >= 0.1}
    return {"still_clips": len(still), "still_max_found": max((c["found"] for c in still.values()), default=None),
            "still_over_1": sum(c["found"] > 1.0 for c in still.values()),
            "still_taken_as_turning": sum(c["turned"] for c in still.values()),
            "moving_clips": len(moving),
            "moving_max_error": max((c["max_error"] for c in moving.values()), default=None),
            "moving_mean_error": float(np.mean([c["mean_error"] for c in moving.values()])) if moving else None,
            "moving_taken_as_still": sum(not c["turned"] for c in moving.values()),
            "ms_per_frame": float(np.mean([c["ms_per_frame"] for c in per_clip.values()]))}


def markdown(rows: dict, vtest: dict | None, machine: dict) -> str:
    head = ["clips", "estimator", "still clips", "largest still turn (deg)", "still > 1 deg", "still taken as turning",
            "turning clips", "largest error (deg)", "mean error (deg)", "turning taken as still", "ms a frame"]
    body = [[group, v, s["still_clips"], s["still_max_found"], s["still_over_1"], s["still_taken_as_turning"],
             s["moving_clips"], s["moving_max_error"], s["moving_mean_error"], s["moving_taken_as_still"],
             s["ms_per_frame"]]
            for group, by_variant in rows.items() for v, s in ((v, summary(c)) for v, c in by_variant.items())]
    lines = ["# The camera's turn from the background (recon.video.camera_motion)", "",
             "eval/camera_turn.py: the estimator alone on each clip with the people's true boxes (the end-to-end "
             "numbers, with the keypoint stage's boxes: eval/results/synth-video-*.md). Errors: the largest and mean "
             "angle between a frame's found and true camera, over the turning clips' frames; ms a frame: the "
             "estimator's time (OpenCV on one thread; frames are looked at 320 px wide).", "",
             report.table(body, head, ["", "", "", ".2f", "", "", "", ".2f", ".3f", "", ".1f"]), ""]
    if vtest:
        lines += ["OpenCV's vtest.avi (a fixed camera, 795 frames at 10 fps, nobody masked): turn read over the clip "
                  + ", ".join(f"{v} {t:.2f} deg" for v, t in vtest.items()) + ".", ""]
    per = [[group, name, c["true"], c["found"], f"{100 * c['measured']:.0f} %", c["max_error"]]
           for group, by_variant in rows.items() for name, c in by_variant[next(iter(VARIANTS))].items()]
    lines += ["Per clip, as shipped:", "",
              report.table(per, ["clips", "clip", "true turn", "found turn", "measured", "largest error"],
                           ["", "", ".2f", ".2f", "", ".2f"]), "", f"Machine: {report.describe(machine)}.", ""]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    cv2.setNumThreads(1)  # the times: one core, as beside the per-frame pass
    groups = {bench: [(n, [f.rgb for f in FrameSource(p)], t) for n, p, t in video_eval.clips(bench)] for bench in SETS}
    groups["hard (close people, portrait)"] = hard_clips(ClipRenderer(default_body()))
    rows = {g: {v: score(c, kw) for v, kw in VARIANTS.items()} for g, c in groups.items()}
    for g, by_variant in rows.items():
        for v, c in by_variant.items():
            print(g, v, summary(c))
    vtest = None
    path = photo_path(*VTEST)
    if path.is_file():
        src = FrameSource(path)
        frames = [f.rgb for f in src]
        h, w = frames[0].shape[:2]
        k = camera.default_intrinsics(h, w)
        vtest = {v: turned_degrees(CameraRotations(k, src.fps, **kw)((f, None) for f in frames).rotations)
                 for v, kw in VARIANTS.items()}
        print("vtest.avi", vtest)
    machine = report.machine()
    out = args.out or report.RESULTS / "camera-turn"
    report.write(out, {"rows": rows, "vtest": vtest, "machine": machine}, markdown(rows, vtest, machine))


if __name__ == "__main__":
    main()
