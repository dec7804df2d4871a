"""The image pipeline's keypoint sources: ``source(rgb, K) -> Keypoints | None``.

``MediaPipeSource`` (the default): MediaPipe Pose finds the person and its 33 landmarks and
person mask, the learned adapter maps the landmarks to our J+. ``BackboneSource``: our
volumetric hourglass alone, which finds its own crop (``recon.backbone.search``); trained on
synthetic renders only.
"""
from __future__ import annotations

import numpy as np

from recon import camera
from recon.backbone.search import CropSearch
from recon.body import skeleton
from recon.keypoints.adapter import KeypointAdapter
from recon.keypoints.base import Keypoints
from recon.keypoints.mediapipe import MediaPipePose


class MediaPipeSource:
    """MediaPipe Pose landmarks -> our J+ via the learned adapter (recon.keypoints.adapter).
    ``flip``: also run on the mirrored image and average the two J+ (mirrored back, left and
    right swapped), unless the mirrored run finds nobody or someone else: one more MediaPipe call
    (its gain: eval/results/pipeline-fit-choices.md; its cost: eval/results/bench-pipeline.md)."""

    name = "mediapipe"

    def __init__(self, adapter_path=None, flip: bool = True):
        self.adapter = KeypointAdapter.load(adapter_path)
        self.mp = MediaPipePose()
        self.flip = flip

    def _detect(self, rgb: np.ndarray, k: np.ndarray):
        r = self.mp(rgb)
        return None if r is None else (r, *self.adapter.predict(r, k))

    def __call__(self, rgb: np.ndarray, k: np.ndarray) -> Keypoints | None:
        found = self._detect(rgb, k)
        if found is None:
            return None
        r, p3, uv = found
        box = r.box()
        if self.flip:
            w = rgb.shape[1]
            km = np.array(k, float)
            km[0, 2] = w - km[0, 2]  # the mirrored camera: u -> w - u
            mirrored = self._detect(np.ascontiguousarray(rgb[:, ::-1]), km)
            if mirrored is not None:
                mirror = list(skeleton.POINT_MIRROR)
                p3m = mirrored[1][mirror] * np.array([-1.0, 1.0, 1.0])
                uvm = mirrored[2][mirror]
                uvm[:, 0] = w - uvm[:, 0]
                size = max(box[2] - box[0], box[3] - box[1], 1.0)
                inside = camera.inside_image(uv, rgb.shape)  # guesses outside the image may disagree
                d = np.linalg.norm(uvm - uv, axis=1)[inside if inside.any() else slice(None)]
                if np.median(d) < 0.25 * size:  # the same person (another one would be far off)
                    p3, uv = 0.5 * (p3 + p3m), 0.5 * (uv + uvm)
        return Keypoints(p3, uv, float(np.mean(r.visibility)), box, r.mask)


class BackboneSource:
    """The volumetric stacked hourglass (recon.backbone) without any other detector: its crop
    search (``recon.backbone.search.CropSearch``) locates the person and predicts J+. ``None``
    when the mean peak confidence is under ``min_confidence`` (the network saw no person-free
    image in training, so this is a weak test). No person mask."""

    name = "backbone"

    def __init__(self, body=None, weights=None, passes: int = 3, min_confidence: float = 0.05, device: str = "cpu",
                 jit: bool = True, quick_locate: bool = True, flip: bool = False):
        self.search = CropSearch.load(body, weights, device, jit, passes=passes, quick_locate=quick_locate, flip=flip)
        self.min_confidence = min_confidence

    @property
    def flip(self) -> bool:
        return self.search.flip

    def __call__(self, rgb: np.ndarray, k: np.ndarray) -> Keypoints | None:
        pts, uv, conf, _ = self.search.locate(rgb, k)
        c = float(conf.mean())
        if c < self.min_confidence:
            return None
        h, w = rgb.shape[:2]
        x0, y0 = np.clip(uv.min(0), 0, [w, h])
        x1, y1 = np.clip(uv.max(0), 0, [w, h])
        return Keypoints(pts - pts[:1], uv, c, (float(x0), float(y0), float(x1), float(y1)))
