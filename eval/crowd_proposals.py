"""MultiPose as a second source of boxes in crowds (issue 88): which of its boxes to read.

With more than one person wanted, the people stage's NanoDet boxes (``recon.people.PersonDetector``)
are followed by MoveNet MultiPose's (``recon.people.multipose``) that overlap none of them by more
than ``o`` (IoU); every box is read by ``LandmarksOnBoxes`` and judged by ``on_boxes.is_person``,
a MultiPose box voting with its score against ``MULTIPOSE_REF``; an answer that reads someone
already read is dropped. On other-crowd-val an answer is right where its box overlaps a true person
not yet matched (IoU > 0.3), else an extra body; on other-empty-val every answer kept is a body
where there is no person. Tabled for MultiPose's input side, ``o`` and its reference score: the
right answers kept, the extra ones and the bodies on person-free images, against NanoDet's boxes
alone (the 0.27 people stage). Writes eval/results/crowd-proposals.{md,json}.

    OMP_NUM_THREADS=1 .venv/bin/python eval/crowd_proposals.py      # ~15 min on 2 cores
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from recon import report
from recon.executor import Call, ExecutorConfig, WorkerSpec, in_order
from recon.keypoints.adapter import KeypointAdapter
from recon.keypoints.on_boxes import DETECTOR_REF, MIN_SCORE, MULTIPOSE_REF, LandmarksOnBoxes, Reading, is_person, logit
from recon.keypoints.views import same_answer
from recon.people.boxes import box_iou
from recon.people.detector import PersonDetector
from recon.people.mediapipe import DEFAULT_MODEL
from recon.people.multipose import OVERLAP, SIZE, MultiPoseDetector
from recon.synth.dataset import open_bench

SIZES = (384, 512, 640)
OVERLAPS = (0.3, 0.5, 0.7)
REFS = (0.2, 0.35, 0.5)
SHIPPED = (SIZE, OVERLAP, MULTIPOSE_REF)


def truth_boxes(s: dict) -> np.ndarray:
    n = int(s.get("n_people", 0))
    return s["boxes"][:n] if n else np.zeros((0, 4))


def answers(bench: str, n: int | None = None) -> list[dict]:
    """Every answer on a benchmark's NanoDet boxes, then on each MultiPose size's boxes, in that
    order per image: its votes, its MultiPose box's overlap with NanoDet's and whether it is right."""
    torch.set_num_threads(1)
    det = PersonDetector()
    multi = {size: MultiPoseDetector(size=size, min_score=0.1) for size in SIZES}
    reader = LandmarksOnBoxes(KeypointAdapter.load(None, DEFAULT_MODEL), DEFAULT_MODEL, flip=True, guard=False)
    ds = open_bench(bench)
    rows = []
    for i in tqdm(range(min(n or len(ds), len(ds))), desc=bench):
        s = ds[i]
        rgb, k, truth = s["rgb"], s["K"].astype(np.float64), truth_boxes(s)
        nano = det(rgb)
        proposals = [(d, 0, 0.0) for d in nano]
        for size, m in multi.items():
            for d in m(rgb):
                proposals.append((d, size, max((box_iou(d.box, b.box) for b in nano), default=0.0)))
        found = {0: []} | {size: [] for size in multi}
        free = {0: set(range(len(truth)))} | {size: set(range(len(truth))) for size in multi}
        for d, size, overlap in proposals:
            got = reader.read(rgb, d.box, d.score, d.view)
            if got is None:
                continue
            kp = reader.keypoints(rgb, k, got)
            seen = found[0] + (found[size] if size else [])
            if any(same_answer(kp, f) for f in seen):
                continue
            found[size].append(kp)
            taken = free[0] & free[size] if size else free[0]
            best = max(((box_iou(kp.box, truth[t]), t) for t in taken), default=(0.0, -1))
            right = best[0] > 0.3
            if right:
                free[size].discard(best[1])
                if not size:
                    for f in free.values():
                        f.discard(best[1])
            rows.append({"image": i, "size": size, "overlap": overlap, "score": d.score, "right": right,
                         "guard": got.votes["guard"], "movenet": got.votes.get("movenet", 0.0)})
    return rows


def kept(rows: list[dict], size: int, overlap: float, ref: float) -> list[dict]:
    """The answers ``on_boxes.is_person`` keeps, NanoDet's then MultiPose's of one setting."""
    out, have = [], set()
    for r in rows:
        if r["size"] not in (0, size) or (r["size"] and r["overlap"] > overlap):
            continue
        votes = {"guard": r["guard"], "detector": logit(r["score"]) - logit(ref if r["size"] else DETECTOR_REF),
                 "movenet": r["movenet"]}
        if is_person(Reading(None, votes, None), MIN_SCORE, first=r["image"] not in have):
            out.append(r)
            have.add(r["image"])
    return out


def answers_of(task: tuple[str, int | None]) -> list[dict]:
    return answers(*task)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=None, help="the first n images of each benchmark")
    a = ap.parse_args()
    jobs = [("other-crowd-val", a.n), ("other-empty-val", a.n)]  # one benchmark a core
    crowd, empty = in_order(WorkerSpec(Call, (answers_of,)), jobs, ExecutorConfig(workers=2, threads=1))
    n_crowd = len({r["image"] for r in crowd})
    base = kept(crowd, 0, 0.0, 1.0)
    base_r = sum(r["right"] for r in base)
    rows, out = [["NanoDet alone (0.27)", "-", "-", base_r, len(base) - base_r, len(kept(empty, 0, 0.0, 1.0))]], []
    for size in SIZES:
        for overlap in OVERLAPS:
            for ref in REFS:
                c, e = kept(crowd, size, overlap, ref), kept(empty, size, overlap, ref)
                r = sum(x["right"] for x in c)
                out.append({"size": size, "overlap": overlap, "ref": ref, "right": r, "extra": len(c) - r,
                            "empty": len(e)})
                mark = " (shipped)" if (size, overlap, ref) == SHIPPED else ""
                rows.append([f"+ MultiPose {size} px{mark}", f"{overlap:g}", f"{ref:g}", r, len(c) - r, len(e)])
    md = ["# MultiPose's boxes in crowds", "",
          "`eval/crowd_proposals.py`: " + __doc__.split("\n\n")[1].replace("\n", " "), "",
          report.table(rows, ["boxes", "o (overlap with NanoDet's)", "MultiPose ref", "right (other-crowd-val)",
                              f"extra ({n_crowd} images)", "bodies (other-empty-val)"]), "",
          f"{report.describe(report.machine())}."]
    report.write(Path(report.RESULTS) / "crowd-proposals", {"rows": out}, "\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
