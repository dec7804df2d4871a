"""The people stage's bar (issue 88): which answers on the detector's boxes are people.

Every box NanoDet gives from score 0.2 (``recon.people.PersonDetector``) is read by MediaPipe's
landmark model (``recon.keypoints.on_boxes.LandmarksOnBoxes`` with no bar); answers that read
someone already found are dropped. On other-crowd-val an answer is right where its box overlaps a
true person not yet matched (IoU > 0.3), else an extra body; on other-empty-val every answer is a
body where there is no person; on other-val (one person each) the images whose person is found.
Tabled: for the score ``guard + (logit(box score) - logit(DETECTOR_REF)) + w x (logit(MoveNet's mean
keypoint score) - logit(MOVENET_REF))`` and bars t, the right answers kept, the extra ones, the
bodies on person-free images and the people of other-val; also with the first-person rule
(``on_boxes.is_person``: an image's first answer kept may instead reach MIN_SCORE_ALONE without
MoveNet's vote, as 0.26 kept lone people). The shipped choice (w = 1, ``on_boxes.MIN_SCORE``, the
first-person rule) keeps at least as many right answers as the bar without MoveNet (w = 0, t = 1,
0.26's) with fewer extra bodies, none on person-free images. Writes
eval/results/box-threshold.{md,json}.

    OMP_NUM_THREADS=1 .venv/bin/python eval/box_threshold.py      # ~30 min
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from recon import report
from recon.keypoints.adapter import KeypointAdapter
from recon.keypoints.on_boxes import MIN_SCORE, MIN_SCORE_ALONE, LandmarksOnBoxes
from recon.keypoints.views import same_answer
from recon.people.boxes import box_iou
from recon.people.detector import PersonDetector
from recon.people.mediapipe import DEFAULT_MODEL
from recon.synth.dataset import open_bench

WEIGHTS = (0.0, 0.5, 1.0, 1.5)
BARS = (0.5, 1.0, 1.25, 1.5, 1.75, 2.0)


def truth_boxes(s: dict) -> np.ndarray:
    """The true people's boxes: a crowd scene's, or a one-person image's silhouette box."""
    n = int(s.get("n_people", 0))
    if n:
        return s["boxes"][:n]
    if "silhouette" in s and s["silhouette"].any():
        ys, xs = np.nonzero(s["silhouette"])
        return np.array([[xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]], float)
    return np.zeros((0, 4))


def answers(bench: str, det: PersonDetector, reader: LandmarksOnBoxes) -> np.ndarray:
    """(image, right, the guard's and detector's score, MoveNet's term) per answer on a benchmark."""
    ds = open_bench(bench)
    rows = []
    for i in tqdm(range(len(ds)), desc=bench):
        s = ds[i]
        truth, found = truth_boxes(s), []
        free = set(range(len(truth)))
        for d in det(s["rgb"]):
            got = reader.read(s["rgb"], d.box, d.score)
            if got is None:
                continue
            kp = reader.keypoints(s["rgb"], s["K"].astype(np.float64), got)
            if any(same_answer(kp, f) for f in found):
                continue
            found.append(kp)
            best = max(((box_iou(kp.box, truth[t]), t) for t in free), default=(0.0, -1))
            if best[0] > 0.3:
                free.discard(best[1])
            rows.append((i, best[0] > 0.3, got.votes["guard"] + got.votes["detector"], got.votes["movenet"]))
    return np.array(rows, float).reshape(-1, 4)


def kept(a: np.ndarray, w: float, bar: float, first: bool = False) -> np.ndarray:
    """Which answers reach ``bar`` with MoveNet's term weighted ``w``; with ``first``, an image's
    first answer kept may instead reach MIN_SCORE_ALONE without MoveNet (``on_boxes.is_person``)."""
    keep = (a[:, 2] + w * a[:, 3]) >= bar
    if first:
        have: set[int] = set()
        for j, image in enumerate(a[:, 0].astype(int)):
            keep[j] |= image not in have and a[j, 2] >= MIN_SCORE_ALONE
            if keep[j]:
                have.add(image)
    return keep


def main() -> None:
    torch.set_num_threads(1)
    det = PersonDetector(min_score=0.2)
    reader = LandmarksOnBoxes(KeypointAdapter.load(None, DEFAULT_MODEL), DEFAULT_MODEL, flip=False, guard=False)
    crowd, empty, single = (answers(b, det, reader) for b in ("other-crowd-val", "other-empty-val", "other-val"))
    right = crowd[crowd[:, 1] == 1]
    n_crowd, n_single = len(open_bench("other-crowd-val")), len(open_bench("other-val"))
    rows, out = [], []
    for first in (False, True):
        for w in WEIGHTS if not first else WEIGHTS[1:]:
            for t in BARS if not first else BARS[2:]:
                k_crowd = kept(crowd, w, t, first)
                r, x = int((k_crowd & (crowd[:, 1] == 1)).sum()), int((k_crowd & (crowd[:, 1] == 0)).sum())
                e = int(kept(empty, w, t, first).sum())
                one = single[kept(single, w, t, first) & (single[:, 1] == 1)]
                people = len(np.unique(one[:, 0]))
                out.append({"movenet_weight": w, "bar": t, "first_alone": first, "right": r, "extra": x, "empty": e,
                            "other_val_found": people})
                mark = (" (shipped)" if (w, t, first) == (1.0, MIN_SCORE, True) else
                        " (0.26)" if (w, t, first) == (0.0, 1.0, False) else "")
                rows.append([f"{w:g}", f"{t:g}{mark}", f"{MIN_SCORE_ALONE:g}" if first else "-",
                             f"{r} of {len(right)}", x, e, f"{people} of {n_single}"])
    md = ["# The people stage's bar: answers on the detector's boxes", "",
          "`eval/box_threshold.py`: " + __doc__.split("\n\n")[1].replace("\n", " "), "",
          report.table(rows, ["w (MoveNet)", "bar t", "first person: bar without MoveNet", "right (other-crowd-val)",
                              f"extra ({n_crowd} images)", "bodies (other-empty-val, 150 images)",
                              "found (other-val)"]), "",
          f"{report.describe(report.machine())}."]
    report.write(Path(report.RESULTS) / "box-threshold", {"rows": out}, "\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
