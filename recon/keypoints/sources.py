"""The image pipeline's keypoint sources: ``source(rgb, K) -> Keypoints | None``.

``MediaPipeSource`` (the default): MediaPipe Pose finds the person and its 33 landmarks and
person mask, the learned adapter maps the landmarks to our J+. ``BackboneSource``: our
volumetric hourglass alone, which finds its own crop (``recon.backbone.search``); trained on
synthetic renders only.
"""
from __future__ import annotations

import cv2
import numpy as np

from recon import camera
from recon.backbone.search import CropSearch
from recon.body import skeleton
from recon.keypoints.adapter import MP_MIRROR, KeypointAdapter
from recon.keypoints.base import Keypoints
from recon.keypoints.mediapipe import MediaPipePose, MPPose

# When MediaPipe finds nobody, it is asked again on these views of the image, in order (view,
# zero-padding factor, detection threshold): its detector misses people behind occluders or cut by
# the frame. Chosen on synth-val (eval/results/error-budget.md, section 3: the three padded views
# each rescue about half of the misses, the four together 79 %); the default threshold is 0.5.
RETRIES = (("plain", 2.0, 0.5), ("plain", 1.5, 0.3), ("mirror", 1.5, 0.5), ("plain", 1.0, 0.3))


def pad_image(rgb: np.ndarray, factor: float) -> tuple[np.ndarray, int]:
    """The image zero-padded on every side to ``factor`` x its longer side, and the pad in pixels."""
    p = int(round(max(rgb.shape[:2]) * (factor - 1) / 2))
    return (cv2.copyMakeBorder(rgb, p, p, p, p, cv2.BORDER_CONSTANT, value=(0, 0, 0)) if p else rgb), p


def _unview(r: MPPose, pad: int, mirrored: bool, shape) -> MPPose:
    """A MediaPipe result on a padded (and mirrored) view -> the same in the original image."""
    h, w = shape[:2]
    xy, vis, world, mask = r.image_xy.copy(), r.visibility, r.world, r.mask
    if mirrored:
        idx = list(MP_MIRROR)
        xy, vis, world = xy[idx], vis[idx], world[idx] * np.array([-1.0, 1.0, 1.0])
        xy[:, 0] = w + 2 * pad - xy[:, 0]
        mask = None if mask is None else mask[:, ::-1]
    xy = xy - pad
    if mask is not None:
        mask = np.ascontiguousarray(mask[pad:pad + h, pad:pad + w])
    return MPPose(xy, vis, world, mask)


class MediaPipeSource:
    """MediaPipe Pose landmarks -> our J+ via the learned adapter (recon.keypoints.adapter).
    ``flip``: also run on the mirrored image and average the two J+ (mirrored back, left and
    right swapped), unless the mirrored run finds nobody or someone else: one more MediaPipe call
    (its gain: eval/results/pipeline-fit-choices.md; its cost: eval/results/bench-pipeline.md).
    ``retry``: when MediaPipe finds nobody, ask it again on the views of ``RETRIES`` (only then:
    no cost on images where it finds the person at once)."""

    name = "mediapipe"

    def __init__(self, adapter_path=None, flip: bool = True, retry: bool = True):
        self.adapter = KeypointAdapter.load(adapter_path)
        self.mp = MediaPipePose()
        self.flip, self.retry = flip, retry
        self._by_threshold = {0.5: self.mp}
        self.last_view = None  # which view found the person in the last call (None: nobody)

    def _detector(self, threshold: float) -> MediaPipePose:
        if threshold not in self._by_threshold:
            self._by_threshold[threshold] = MediaPipePose(min_confidence=threshold)
        return self._by_threshold[threshold]

    def _detect(self, rgb: np.ndarray, k: np.ndarray):
        r = self.mp(rgb)
        return None if r is None else (r, *self.adapter.predict(r, k))

    def _retry(self, rgb: np.ndarray, k: np.ndarray):
        for view, factor, threshold in RETRIES:
            padded, pad = pad_image(rgb, factor)
            if view == "mirror":
                padded = np.ascontiguousarray(padded[:, ::-1])
            r = self._detector(threshold)(padded)
            if r is not None:
                self.last_view = f"{view} x{factor:g} @{threshold:g}"
                r = _unview(r, pad, view == "mirror", rgb.shape)
                return (r, *self.adapter.predict(r, k))
        return None

    def __call__(self, rgb: np.ndarray, k: np.ndarray) -> Keypoints | None:
        found = self._detect(rgb, k)
        self.last_view = None if found is None else "image"
        if found is None and self.retry:
            found = self._retry(rgb, k)
            if found is not None:  # a view found the person: no mirror averaging on top
                r, p3, uv = found
                return Keypoints(p3, uv, float(np.mean(r.visibility)), r.box(), r.mask)
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
