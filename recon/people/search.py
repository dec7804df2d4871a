"""Finding people without a face: ``PersonSearch``.

MediaPipe's person detector is anchored on the face: people seen from the back, cut by a border or
small in the frame are where it misses. The search needs no face. Proposals: the person
probability of the selfie-segmentation model in the MediaPipe wheel, over the whole frame and over
four zoomed quarters (small people), its blobs, then the squares of a coarse grid holding the most
of it. On each region (centre x, centre y, side, rotation) MediaPipe's landmark model looks for a
person (``recon.people.mediapipe.MediaPipeLandmarks``; its own presence score gates), coarsely
(the full model) then twice more with the fine model, each time on the region its last answer
implies (MediaPipe's tracking rule). A person's landmarks settle; a phantom's jump: an answer is
kept only when the three passes agree, the guard's score is high enough, and the fine model finds
the same person, mirrored, in the mirrored image (textures that pass for a body rarely do).
"""
from __future__ import annotations

import cv2
import numpy as np

from recon.errors import ReconError
from recon.people import guard as person_guard
from recon.people.mediapipe import DEFAULT_MODEL, MP_MIRROR, MediaPipeLandmarks, MPPose, available, quiet_native_logs

ROI_SCALES = (1.0, 0.7, 0.45)  # grid squares' sides, as a share of the frame's shorter side
MIN_BLOB = 0.002  # a mask blob smaller than this share of the frame is no proposal
# Chosen on other-val's people that MediaPipe's detector misses against person-free frames of the
# other domain and the generator (eval/person_search.py): regions tried, the largest median
# landmark move (share of the person's size) between the coarse and the first fine pass and between
# the two fine passes, the guard's score an answer needs, and the largest median move between the
# answer and the mirrored image's answer mirrored back.
MAX_REGIONS = 8
SETTLE = (0.25, 0.10)
MIN_SCORE = -2.0
MIRROR_AGREE = 0.07


class PersonMask:
    """MediaPipe's selfie segmentation (landscape model, in the wheel): (H, W) person probability."""

    def __init__(self):
        if not available():
            raise ReconError("mediapipe is not installed: scripts/setup.sh installs mediapipe==0.10.21")
        import mediapipe as mp  # noqa: PLC0415 - optional extra

        with quiet_native_logs():
            self.model = mp.solutions.selfie_segmentation.SelfieSegmentation(model_selection=1)
            self.model.process(np.zeros((64, 64, 3), np.uint8))

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        with quiet_native_logs():
            m = self.model.process(np.ascontiguousarray(rgb)).segmentation_mask
        return np.zeros(rgb.shape[:2], np.float32) if m is None else np.array(m, np.float32)


def blob_regions(prob: np.ndarray, threshold: float = 0.5) -> list[tuple[float, float, float, float, float]]:
    """Regions around the blobs of a person-probability map, largest first: (cx, cy, side, 0, mass)."""
    h, w = prob.shape
    m = (prob > threshold).astype(np.uint8)
    n, _, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    out = []
    for i in range(1, n):
        x, y, bw, bh, area = (int(v) for v in stats[i])
        if area >= MIN_BLOB * h * w:
            out.append((x + bw / 2, y + bh / 2, 1.3 * max(bw, bh), 0.0, float(area)))
    return sorted(out, key=lambda r: -r[4])


def grid_regions(h: int, w: int, scales=ROI_SCALES) -> list[tuple[float, float, float, float]]:
    """Squares of each scale over the frame, overlapping by half (cx, cy, side, 0)."""
    out = []
    for s in scales:
        side = s * min(h, w)
        nx = max(1, int(np.ceil((w - side) / (side / 2))) + 1)
        ny = max(1, int(np.ceil((h - side) / (side / 2))) + 1)
        for cy in np.linspace(side / 2, max(h - side / 2, side / 2), ny):
            for cx in np.linspace(side / 2, max(w - side / 2, side / 2), nx):
                out.append((float(cx), float(cy), float(side), 0.0))
    return out


def mass(prob: np.ndarray, roi) -> float:
    """How much person probability a square region holds (its mean over the region's central half)."""
    h, w = prob.shape
    cx, cy, side = roi[:3]
    r = side / 4
    x0, x1 = int(max(0, cx - r)), int(min(w, cx + r))
    y0, y1 = int(max(0, cy - r)), int(min(h, cy + r))
    return float(prob[y0:y1, x0:x1].mean()) if x1 > x0 and y1 > y0 else 0.0


def proposals(prob: np.ndarray, max_regions: int = 6, min_mass: float = 0.05) -> list[tuple]:
    """The regions to look at, most promising first: the mask's blobs, then the grid squares
    holding the most person probability (at least ``min_mass``), ``max_regions`` in all."""
    h, w = prob.shape
    out = [r[:4] for r in blob_regions(prob)]
    grid = sorted(((mass(prob, r), r) for r in grid_regions(h, w)), key=lambda x: -x[0])
    out += [r for m, r in grid if m >= min_mass]
    return out[:max_regions]


def settled(a: MPPose, b: MPPose, size: float) -> float:
    """The median landmark move between two answers, as a share of ``size``."""
    return float(np.median(np.linalg.norm(a.image_xy - b.image_xy, axis=1)) / max(size, 1.0))


class PersonSearch:
    """``PersonSearch(model)(rgb) -> (MPPose, guard score) | None``: a person MediaPipe's detector
    missed (see the module docstring); ``model``: the fine landmark model. ``last_tried``: regions
    looked at in the last call."""

    def __init__(self, model: str = DEFAULT_MODEL, max_regions: int = MAX_REGIONS, settle=SETTLE,
                 min_score: float = MIN_SCORE, mirror_agree: float = MIRROR_AGREE):
        self.mask = PersonMask()
        self.coarse = MediaPipeLandmarks("full")
        self.fine = MediaPipeLandmarks(model)
        self.guard = person_guard.for_model(self.fine.model)
        self.max_regions, self.settle, self.min_score = max_regions, settle, min_score
        self.mirror_agree = mirror_agree
        self.last_tried = 0

    def probability(self, rgb: np.ndarray) -> np.ndarray:
        """The person probability over the frame: the whole frame's and four zoomed quarters' (60 %
        of each side), the larger of them per pixel."""
        h, w = rgb.shape[:2]
        p = self.mask(rgb)
        th, tw = int(0.6 * h), int(0.6 * w)
        for y0 in (0, h - th):
            for x0 in (0, w - tw):
                q = self.mask(np.ascontiguousarray(rgb[y0:y0 + th, x0:x0 + tw]))
                np.maximum(p[y0:y0 + th, x0:x0 + tw], q, out=p[y0:y0 + th, x0:x0 + tw])
        return p

    def __call__(self, rgb: np.ndarray) -> tuple[MPPose, float] | None:
        self.last_tried = 0
        for roi in proposals(self.probability(rgb), self.max_regions):
            self.last_tried += 1
            found = self.look(rgb, roi)
            if found is not None:
                return found
        return None

    def look(self, rgb: np.ndarray, roi) -> tuple[MPPose, float] | None:
        """The three passes on one region; the settled answer and its guard score, or None."""
        r1 = self.coarse(rgb, roi)
        r2 = None if r1 is None else self.fine(rgb, r1.roi())
        r3 = None if r2 is None else self.fine(rgb, r2.roi())
        if r3 is None:
            return None
        ev = person_guard.evidence(r3, rgb.shape)
        if settled(r1, r2, ev["box_px"]) > self.settle[0] or settled(r2, r3, ev["box_px"]) > self.settle[1]:
            return None
        score = self.guard.score(ev)
        if score < self.min_score or self.mirrored(rgb, r3, ev["box_px"]) > self.mirror_agree:
            return None
        return r3, score

    def mirrored(self, rgb: np.ndarray, r: MPPose, size: float) -> float:
        """The median landmark move between ``r`` and the fine model's answer on the mirrored image
        (mirrored back, left and right swapped), as a share of ``size``; inf where it finds nobody."""
        w = rgb.shape[1]
        cx, cy, side, rot = r.roi()
        m = self.fine(np.ascontiguousarray(rgb[:, ::-1]), (w - cx, cy, side, -rot))
        if m is None:
            return float("inf")
        xy = m.image_xy[list(MP_MIRROR)].copy()
        xy[:, 0] = w - xy[:, 0]
        return float(np.median(np.linalg.norm(xy - r.image_xy, axis=1)) / max(size, 1.0))
