"""MediaPipe's landmark model on the people stage's boxes: ``LandmarksOnBoxes(...)(rgb, K, box)``.

The people stage (``recon.people``) says where each person is; MediaPipe's own detector, which
wants a face and finds one person per call, is not needed. For each box the landmark model looks
at the square around it, then again at the region its first answer implies (MediaPipe's tracking
rule: centred on the hips, turned with the torso); the guard (``recon.keypoints.guard``) refuses
answers that are no person; with ``movenet`` MoveNet's keypoints are fused in
(``recon.keypoints.movenet``), and with ``flip`` the mirrored image's answer on the mirrored region
is averaged in (left and right swapped) where it agrees.
"""
from __future__ import annotations

import numpy as np

from recon.keypoints import guard as person_guard
from recon.keypoints.adapter import KeypointAdapter
from recon.keypoints.base import Keypoints
from recon.keypoints.mediapipe import MediaPipeLandmarks, MPPose
from recon.keypoints.movenet import MoveNet, fuse
from recon.keypoints.views import mirrored_camera, unmirror

BOX_GROWTH = 1.25  # the first region's side: the box's longer side times this (MediaPipe's own margin)
AGREE = 0.25  # the mirrored answer is averaged in where its median keypoint lies within this share of the box
# An answer is a person where the guard's log-odds plus the detector's (against a box score of
# DETECTOR_REF) reach MIN_SCORE: chosen on other-crowd-val's people against the bodies found on
# other-empty-val and the extra ones in other-crowd-val (eval/box_threshold.py).
DETECTOR_REF = 0.35
MIN_SCORE = 1.0


def person_score(guard_score: float, box_score: float) -> float:
    """The log-odds that an answer on a box is a person: the guard's plus the detector's."""
    p = min(max(box_score, 1e-6), 1 - 1e-6)
    return guard_score + float(np.log(p / (1 - p)) - np.log(DETECTOR_REF / (1 - DETECTOR_REF)))


def box_roi(box) -> tuple[float, float, float, float]:
    """The square region around a box: (centre x, centre y, side, rotation 0)."""
    x0, y0, x1, y1 = box
    return 0.5 * (x0 + x1), 0.5 * (y0 + y1), BOX_GROWTH * max(x1 - x0, y1 - y0, 1.0), 0.0


class LandmarksOnBoxes:
    """One person's keypoints from a box (see the module docstring). ``model``: MediaPipe's landmark
    model; ``passes``: looks at the region (the first on the box's square, each next on the last
    answer's region); ``guard``: refuse answers whose ``person_score`` is under ``min_score``;
    ``movenet``: MoveNet's weight in its 2D keypoints fused into MediaPipe's (0: MediaPipe's alone)."""

    name = "mediapipe"

    def __init__(self, adapter: KeypointAdapter, model: str, flip: bool = True, guard: bool = True, passes: int = 2,
                 min_score: float = MIN_SCORE, movenet: float = 0.0):
        self.landmarks = MediaPipeLandmarks(model)
        self.movenet = MoveNet() if movenet > 0 else None
        self.movenet_weight = movenet
        self.adapter, self.flip, self.guard, self.passes = adapter, flip, guard, passes
        self.min_score = min_score
        self.person_guard = person_guard.for_model(self.landmarks.model)

    def pose(self, rgb: np.ndarray, box) -> MPPose | None:
        """The landmark model's settled answer on a box, or None where it sees nobody."""
        r, roi = None, box_roi(box)
        for _ in range(self.passes):
            r = self.landmarks(rgb, roi)
            if r is None:
                return None
            roi = r.roi()
        return r

    def __call__(self, rgb: np.ndarray, k: np.ndarray, box, box_score: float = DETECTOR_REF) -> Keypoints | None:
        """The person on ``box`` (the detector's ``box_score``), or None."""
        r = self.pose(rgb, box)
        if r is None:
            return None
        score = person_score(self.person_guard.score(person_guard.evidence(r, rgb.shape)), box_score)
        if self.guard and score < self.min_score:
            return None
        if self.movenet is not None:
            r = fuse(r, *self.movenet(rgb, r.box(0.0)), self.movenet_weight)
        p3, uv = self.adapter.predict(r, k)
        found = r.box()
        if self.flip:
            h, w = rgb.shape[:2]
            cx, cy, side, rot = r.roi()
            m = self.landmarks(np.ascontiguousarray(rgb[:, ::-1]), (w - cx, cy, side, -rot))
            if m is not None:
                p3m, uvm = unmirror(*self.adapter.predict(m, mirrored_camera(k, w)), w)
                size = max(found[2] - found[0], found[3] - found[1], 1.0)
                if np.median(np.linalg.norm(uvm - uv, axis=1)) < AGREE * size:
                    p3, uv = 0.5 * (p3 + p3m), 0.5 * (uv + uvm)
        return Keypoints(p3, uv, float(np.mean(r.visibility)), found, r.mask, score, self.name)
