"""The tracker alone: identity switches and people left out, from the clips' stored detections.

    OMP_NUM_THREADS=1 .venv/bin/python eval/tracking.py            # ~1 min with detections stored

Every clip of the video sets (``recon.synth.video.VIDEO_BENCHMARKS``) is passed through
``recon video``'s per-frame pass once (its detections stored under
``~/.cache/recon/eval-video-work/<clip>``, as eval/video.py leaves them); then each tracker
variant of ``VARIANTS`` follows the people. A detection belongs to the true person whose projected
J+ lie closest (median distance under a quarter of the box's height, and under half the next
person's: a detection that mixes two people belongs to neither); for each true person the
track ids of its detections in frame order give its identity switches (an id that changes) and
its tracks (how many ids it got); detections of a person in no track kept are left out (a track
cut where a person's box jumped is dropped when short, or when it is not among the longest).
Choices are made on the val sets (``synth-video-val``,
``synth-video-occlusion-val``: look-alikes, one passing behind the other), the test sets are
reported. Writes eval/results/tracking.{json,md}.
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).parent))
import video as video_eval  # noqa: E402

from recon import camera, report  # noqa: E402
from recon.body import default_body  # noqa: E402
from recon.video.perframe import Detections  # noqa: E402
from recon.video.run import detections_per_frame  # noqa: E402
from recon.video.track import TrackerConfig, track  # noqa: E402

SETS = ("synth-video-val", "synth-video-moving-val", "synth-video-occlusion-val", "synth-video-test",
        "synth-video-moving-test", "synth-video-occlusion-test")
VARIANTS = {
    "0.29 (box, keypoints, colours)": TrackerConfig(motion=False),
    "0.30 (+ motion through gaps, size, depth)": TrackerConfig(),
}


def owners(dets: Detections, truth) -> np.ndarray:
    """(N,) the true person of each detection, -1 where none lies close."""
    uv = camera.project(truth.points.reshape(-1, 3), truth.K).reshape(truth.points.shape[:-1] + (2,))
    out = np.full(len(dets), -1)
    for n in range(len(dets)):
        f = int(dets.frame[n])
        d = np.median(np.linalg.norm(uv[:, f] - dets.points2d[n][None], axis=-1), axis=1)
        d[~truth.visible[:, f]] = np.inf
        height = max(dets.box[n, 3] - dets.box[n, 1], 1.0)
        near = np.sort(d)
        if near[0] < 0.25 * height and (len(near) < 2 or near[1] > 2 * near[0]):
            out[n] = int(d.argmin())
    return out


def identities(dets: Detections, truth, cfg: TrackerConfig) -> dict:
    """Identity switches and tracks per true person for one tracker configuration."""
    people = truth.joints.shape[0]
    tracks = track(detections_per_frame(dets, truth.visible.shape[1]), replace(cfg, max_people=people))
    owner = owners(dets, truth)
    switches, ids = 0, []
    for p in range(people):
        seq = sorted((d.frame, t.id) for t in tracks for d in t.detections if owner[d.index] == p)
        switches += sum(a[1] != b[1] for a, b in zip(seq, seq[1:]))
        ids.append(len({i for _, i in seq}))
    kept = {d.index for t in tracks for d in t.detections}
    owned = np.flatnonzero(owner >= 0)
    return {"switches": switches, "tracks_per_person": ids,
            "left_out": int(sum(n not in kept for n in owned)), "detections": int(len(owned))}


def measure() -> dict:
    torch.set_num_threads(1)
    body = default_body()
    out = {}
    for bench in SETS:
        for name, path, truth in video_eval.clips(bench):
            dets = video_eval.stored_detections(name, path, truth, body)
            out[f"{bench}/{name}"] = {v: identities(dets, truth, cfg) for v, cfg in VARIANTS.items()}
    return out


def markdown(res: dict) -> str:
    lines = ["# The tracker on stored detections: identity switches", "",
             "Made by `eval/tracking.py` (module doc: how a detection is given to a true person). Each cell: "
             "identity switches (the tracks each true person got), and where any, the detections of people left "
             "out of every track. Chosen on the val sets; the test sets reported. A detection whose keypoints mix "
             "the two people of a crossing may be given here to the one hidden, which counts against the tracker; "
             "eval/video.py counts switches on the finished tracks (occlusion sets: "
             "[val](synth-video-occlusion-val.md), [test](synth-video-occlusion-test.md)).",
             "", "| clip | " + " | ".join(VARIANTS) + " |", "|---|" + "---|" * len(VARIANTS)]
    for clip, row in res.items():
        cells = [f"{r['switches']} ({', '.join(map(str, r['tracks_per_person']))})"
                 + (f"; {r['left_out']} of {r['detections']} left out" if r["left_out"] else "") for r in row.values()]
        lines.append(f"| {clip} | " + " | ".join(cells) + " |")
    for split in ("val", "test"):
        tot = [sum(row[v]["switches"] for c, row in res.items() if split in c.split("/")[0]) for v in VARIANTS]
        lines.append(f"| **all {split} clips** | " + " | ".join(f"**{t}**" for t in tot) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(report.RESULTS / "tracking"))
    args = ap.parse_args()
    res = measure()
    md = markdown(res)
    print(md)
    report.write(Path(args.out), {"clips": res, "machine": report.machine()}, md)


if __name__ == "__main__":
    main()
