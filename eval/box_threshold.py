"""The people stage's bar (issue 88): which answers on the detector's boxes are people.

Every box NanoDet gives from score 0.2 (``recon.people.PersonDetector``) is read by MediaPipe's
landmark model (``recon.keypoints.on_boxes.LandmarksOnBoxes`` with no bar); answers that read
someone already found are dropped. On other-crowd-val an answer is right where its box overlaps a
true person not yet matched (IoU > 0.3), else an extra body; on other-empty-val every answer is a
body where there is no person. Tabled: for the score ``guard + w x (logit(box score) -
logit(DETECTOR_REF))`` and bars t, the right answers kept, the extra ones and the bodies on
person-free images. The shipped choice (``on_boxes.MIN_SCORE``, w = 1) is the row where the
person-free images keep no body and the extra ones fall to a few in 40 images. Writes
eval/results/box-threshold.{md,json}.

    OMP_NUM_THREADS=1 .venv/bin/python eval/box_threshold.py      # ~5 min
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from recon import report
from recon.keypoints.adapter import KeypointAdapter
from recon.keypoints.mediapipe import DEFAULT_MODEL
from recon.keypoints.on_boxes import MIN_SCORE, LandmarksOnBoxes, person_score
from recon.keypoints.views import box_iou, same_answer
from recon.people.detector import PersonDetector
from recon.synth.dataset import open_bench

WEIGHTS = (0.0, 1.0, 2.0)
BARS = (-1.0, -0.5, 0.0, 0.5, 1.0, 1.5)


def answers(bench: str, det: PersonDetector, reader: LandmarksOnBoxes) -> np.ndarray:
    """(right, the guard's score, the detector's term) per answer on a benchmark."""
    ds = open_bench(bench)
    rows = []
    for i in tqdm(range(len(ds)), desc=bench):
        s = ds[i]
        n = int(s.get("n_people", 0))
        truth, free, found = s["boxes"][:n] if n else np.zeros((0, 4)), set(range(n)), []
        for d in det(s["rgb"]):
            kp = reader(s["rgb"], s["K"].astype(np.float64), d.box, d.score)
            if kp is None or any(same_answer(kp, f) for f in found):
                continue
            found.append(kp)
            best = max(((box_iou(kp.box, truth[t]), t) for t in free), default=(0.0, -1))
            if best[0] > 0.3:
                free.discard(best[1])
            detector = person_score(0.0, d.score)  # the detector's term of the answer's score
            rows.append((best[0] > 0.3, kp.person_score - detector, detector))
    return np.array(rows, float).reshape(-1, 3)


def kept(a: np.ndarray, w: float, bar: float) -> int:
    """How many answers reach ``bar`` with the detector's term weighted ``w``."""
    return int(((a[:, 1] + w * a[:, 2]) >= bar).sum())


def main() -> None:
    torch.set_num_threads(1)
    det = PersonDetector(min_score=0.2)
    reader = LandmarksOnBoxes(KeypointAdapter.load(None, DEFAULT_MODEL), DEFAULT_MODEL, flip=False, guard=False)
    crowd, empty = answers("other-crowd-val", det, reader), answers("other-empty-val", det, reader)
    right, wrong = crowd[crowd[:, 0] == 1], crowd[crowd[:, 0] == 0]
    rows, out = [], []
    for w in WEIGHTS:
        for t in BARS:
            r, x, e = (kept(a, w, t) for a in (right, wrong, empty))
            out.append({"weight": w, "bar": t, "right": r, "extra": x, "empty": e})
            mark = " (shipped)" if (w, t) == (1.0, MIN_SCORE) else ""
            rows.append([f"{w:g}", f"{t:g}{mark}", f"{r} of {len(right)}", x, e])
    md = ["# The people stage's bar: answers on the detector's boxes", "",
          "`eval/box_threshold.py`: " + __doc__.split("\n\n")[1].replace("\n", " "), "",
          report.table(rows, ["w (detector)", "bar t", "right (other-crowd-val)", "extra (40 images)",
                              "bodies (other-empty-val, 150 images)"]), "",
          f"{report.describe(report.machine())}."]
    report.write(Path(report.RESULTS) / "box-threshold", {"rows": out}, "\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
