"""The backbone's crop search: finding the person in a photo without ground truth.

The network was trained on metric crops (2.5 m around the mean joint, ``recon.backbone.crop``),
so it must be shown the person at that scale. ``CropSearch.locate`` runs ``passes`` passes:
the first over the whole image (its first hourglass only: it only locates), then metric crops
centred on the predicted joints at the depth where the template's bone lengths match the
predicted 2D bones (``recon.camera.depth_from_bones``, each bone foreshortened as the previous
pass predicted it in 3D), times a factor per pass calibrated on synth-val (``recon.backbone.calibrate``), the
last pass optionally averaged with its mirror image. Variants and their accuracy:
eval/results/backbone-crop-search.md. The calibration (on synthetic data) is
``recon.backbone.calibrate``'s: the search itself imports no data code.
"""
from __future__ import annotations

import numpy as np

from recon import camera
from recon.backbone.crop import EXTENT_M, Crop
from recon.backbone.model import Backbone
from recon.body import default_body
from recon.body.base import BodyModel
from recon.smplr.features import template_distances


def crop_from_keypoints(uv: np.ndarray, k: np.ndarray, template: np.ndarray, depth_scale: float = 1.0,
                        points: np.ndarray | None = None) -> Crop:
    """Metric crop around 2D joints: centre = mean of the 24 joints back-projected at the
    bone-length depth (foreshortened by ``points``, see ``recon.camera.depth_from_bones``)
    times ``depth_scale``."""
    z = camera.depth_from_bones(uv, k, template, points) * depth_scale
    return Crop.around(camera.unproject(uv[:24].mean(0), z, k), k)


def whole_image_crop(shape: tuple[int, ...], k: np.ndarray) -> Crop:
    """Square crop over the whole image (first pass before the person is located)."""
    h, w = shape[:2]
    side = float(max(h, w))
    return Crop((w - side) / 2, (h - side) / 2, side, float(k[0, 0] * EXTENT_M / side), k)


class CropSearch:
    """``CropSearch(backbone, template).locate(rgb, K) -> (J+ (42, 3) camera frame, 2D (42, 2),
    confidences (42,), last crop)``.

    Args:
        net: the trained network; its ``depth_scale`` holds the calibrated factors per pass.
        template: the template body's 41 J+ bone lengths (``recon.smplr.features.template_distances``).
        passes: passes in all (the first one whole-image).
        quick_locate: the whole-image pass through the first hourglass only (the shipped factors
            are calibrated for it); False runs the whole network there.
        flip: average the last pass with its mirror image (gain: backbone-crop-search.md; cost:
            bench-pipeline.md, both in eval/results).
    """

    def __init__(self, net: Backbone, template: np.ndarray, passes: int = 3, quick_locate: bool = True,
                 flip: bool = False):
        self.net, self.template = net, np.asarray(template, dtype=np.float64)
        self.passes, self.quick_locate, self.flip = passes, quick_locate, flip

    @classmethod
    def load(cls, body: BodyModel | None = None, weights=None, device: str = "cpu", jit: bool = True,
             **kwargs) -> CropSearch:
        return cls(Backbone.load(weights, device, jit), template_distances(body or default_body()).cpu().numpy(),
                   **kwargs)

    def depth_points(self, pts: np.ndarray) -> np.ndarray | None:
        """The predicted J+ that foreshorten the bones of the crop-depth estimate, or None for
        weights calibrated for plain bone lengths."""
        return pts if self.net.depth_method == "foreshortened" else None

    def locate(self, rgb: np.ndarray, k: np.ndarray, depth_scale=None, passes: int | None = None):
        """Run the passes (default ``self.passes``); returns the last pass' (J+ camera frame, 2D,
        confidences, crop). ``depth_scale`` overrides the calibrated factors (calibration)."""
        scale = self.net.depth_scale if depth_scale is None else depth_scale
        crop = whole_image_crop(rgb.shape, k)
        passes = self.passes if passes is None else passes
        for p in range(passes):
            last = p == passes - 1
            pts, uv, conf = self.net.predict([rgb], [crop], locate=self.quick_locate and p == 0 and passes > 1,
                                             flip=self.flip and last)
            if not last:  # bone-length depth, times the factor calibrated on synth-val
                crop = crop_from_keypoints(uv[0], k, self.template, scale[min(p, len(scale) - 1)],
                                           self.depth_points(pts[0]))
        return pts[0], uv[0], conf[0], crop
