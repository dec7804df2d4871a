"""MediaPipe's landmark model on the people stage's boxes: ``LandmarksOnBoxes(...)(rgb, K, box)``.

The people stage (``recon.people``) says where each person is; MediaPipe's own detector, which
wants a face and finds one person per call, is not needed. For each box the landmark model looks
at the square around it, then again at the region its first answer implies (MediaPipe's tracking
rule: centred on the hips, turned with the torso); an answer is a person where three independent
votes agree: the guard (``recon.people.guard``), the detector's box score and MoveNet's
keypoint scores on the answer's box (``recon.keypoints.movenet``, a second pose model that sees no
body in a wall); with ``movenet`` MoveNet's keypoints are also fused in, and with ``flip`` the
mirrored image's answer on the mirrored region is averaged in (left and right swapped) where it agrees.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from recon.keypoints.adapter import KeypointAdapter
from recon.keypoints.base import Keypoints
from recon.keypoints.movenet import MoveNet, fuse
from recon.keypoints.views import mirrored_camera, unmirror
from recon.people import guard as person_guard
from recon.people import models as people_models
from recon.people.mediapipe import MediaPipeLandmarks, MPPose

BOX_GROWTH = 1.25  # the first region's side: the box's longer side times this (MediaPipe's own margin)
AGREE = 0.25  # the mirrored answer is averaged in where its median keypoint lies within this share of the box
# An answer is a person where its log-odds reach MIN_SCORE: the guard's, plus the detector's against
# a box score of DETECTOR_REF, plus MoveNet's against a mean keypoint score of MOVENET_REF. The
# image's first person may instead reach MIN_SCORE_ALONE on the guard's and the detector's alone
# (MoveNet misreads some lone people: cut, turned away), which is also the bar where MoveNet is not
# installed. Chosen on other-crowd-val's people against the bodies found on other-empty-val and the
# extra ones in other-crowd-val, other-val's people kept (eval/box_threshold.py).
DETECTOR_REF = 0.35
# A MultiPose box (``recon.people.multipose``) votes with its own score against this (chosen on
# other-crowd-val against other-empty-val: eval/crowd_proposals.py)
MULTIPOSE_REF = 0.35
MOVENET_REF = 0.25
MIN_SCORE = 1.5
MIN_SCORE_ALONE = 1.0


def logit(p: float) -> float:
    p = min(max(float(p), 1e-6), 1 - 1e-6)
    return float(np.log(p / (1 - p)))


def detector_term(box_score: float, view: str = "image") -> float:
    """The box's vote: the log-odds of its score against the reference of the model that proposed it."""
    return logit(box_score) - logit(MULTIPOSE_REF if view == "multipose" else DETECTOR_REF)


def movenet_term(mean_score: float) -> float:
    """MoveNet's vote on an answer's box: the log-odds of its mean keypoint score against MOVENET_REF."""
    return logit(mean_score) - logit(MOVENET_REF)


@dataclass
class Reading:
    """The landmark model's answer on a box, its votes (log-odds: "guard", "detector", "movenet"
    where installed) and MoveNet's (keypoints, scores) on its box."""
    pose: MPPose
    votes: dict[str, float]
    movenet: tuple[np.ndarray, np.ndarray] | None

    @property
    def score(self) -> float:
        """The log-odds that the answer is a person: the sum of the votes."""
        return float(sum(self.votes.values()))

    @property
    def score_alone(self) -> float:
        """The guard's and the detector's votes, without MoveNet's."""
        return float(self.votes["guard"] + self.votes["detector"])


def is_person(got: Reading, bar: float = MIN_SCORE, first: bool = False) -> bool:
    """Whether a reading is a person: all its votes reach ``bar``, or for the image's ``first``
    person (nobody found yet), the guard's and the detector's reach MIN_SCORE_ALONE."""
    return got.score >= bar or (first and got.score_alone >= MIN_SCORE_ALONE)


def box_roi(box) -> tuple[float, float, float, float]:
    """The square region around a box: (centre x, centre y, side, rotation 0)."""
    x0, y0, x1, y1 = box
    return 0.5 * (x0 + x1), 0.5 * (y0 + y1), BOX_GROWTH * max(x1 - x0, y1 - y0, 1.0), 0.0


class LandmarksOnBoxes:
    """One person's keypoints from a box (see the module docstring). ``model``: MediaPipe's landmark
    model; ``passes``: looks at the region (the first on the box's square, each next on the last
    answer's region); ``guard``: refuse answers that are no person (``is_person``; ``min_score``:
    the bar for all the votes, default the one for the votes installed); ``movenet``: MoveNet's
    weight in its 2D keypoints fused into MediaPipe's (0: MediaPipe's alone; MoveNet still votes
    where it is installed)."""

    name = "mediapipe"

    def __init__(self, adapter: KeypointAdapter, model: str, flip: bool = True, guard: bool = True, passes: int = 2,
                 min_score: float | None = None, movenet: float = 0.0):
        self.landmarks = MediaPipeLandmarks(model)
        self.movenet = MoveNet() if people_models.available("movenet-thunder") else None
        self.movenet_weight = movenet if self.movenet is not None else 0.0
        self.adapter, self.flip, self.guard, self.passes = adapter, flip, guard, passes
        self.min_score = min_score if min_score is not None else MIN_SCORE if self.movenet else MIN_SCORE_ALONE
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

    def read(self, rgb: np.ndarray, box, box_score: float = DETECTOR_REF, view: str = "image") -> Reading | None:
        """The answer on a box with its votes, before any bar (``view``: the detector's view that
        proposed the box); None where the landmark model sees nobody."""
        r = self.pose(rgb, box)
        if r is None:
            return None
        votes = {"guard": self.person_guard.score(person_guard.evidence(r, rgb.shape)),
                 "detector": detector_term(box_score, view)}
        moved = None
        if self.movenet is not None:
            moved = self.movenet(rgb, r.box(0.0))
            votes["movenet"] = movenet_term(float(np.mean(moved[1])))
        return Reading(r, votes, moved)

    def is_person(self, got: Reading, first: bool = False) -> bool:
        return not self.guard or is_person(got, self.min_score, first)

    def __call__(self, rgb: np.ndarray, k: np.ndarray, box, box_score: float = DETECTOR_REF, first: bool = False,
                 view: str = "image") -> Keypoints | None:
        """The person on ``box`` (the detector's ``box_score`` in its ``view``; ``first``: nobody
        found in the image yet), or None."""
        got = self.read(rgb, box, box_score, view)
        if got is None or not self.is_person(got, first):
            return None
        return self.keypoints(rgb, k, got)

    def keypoints(self, rgb: np.ndarray, k: np.ndarray, got: Reading) -> Keypoints:
        """A reading's keypoints: MoveNet's fused in, the mirrored image's answer averaged in where it agrees."""
        r = got.pose
        if got.movenet is not None and self.movenet_weight > 0:
            r = fuse(r, *got.movenet, self.movenet_weight)
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
        return Keypoints(p3, uv, float(np.mean(r.visibility)), found, r.mask, got.score, self.name)
