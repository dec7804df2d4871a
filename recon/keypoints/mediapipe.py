"""MediaPipe Pose (0.10.21) as a person detector and 2D/3D keypoint source, with one of its three
landmark models. Optional extra: scripts/setup.sh installs it without its dependency pins (numpy<2,
protobuf<5 and jax conflict with ours) and adds the lite and heavy models, which the wheel lacks,
from the npm package @mediapipe/pose (docs/install.md)."""
from __future__ import annotations

import contextlib
import importlib.util
import logging
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recon.errors import ReconError

NUM_MP = 33  # MediaPipe Pose landmarks
# The landmark models by name, as MediaPipe's model_complexity; the wheel ships only "full".
MODELS = {"lite": 0, "full": 1, "heavy": 2}
DEFAULT_MODEL = "heavy"  # recon run's: the most accurate (scripts/setup.sh installs it)
log = logging.getLogger(__name__)
_WARNED: set[str] = set()  # models already reported missing: one line per process


@dataclass
class MPPose:
    image_xy: np.ndarray  # (33, 2) pixels
    visibility: np.ndarray  # (33,) in [0, 1]
    world: np.ndarray  # (33, 3) metres, hip-centred, camera-aligned axes (OpenCV: y down, z forward)
    mask: np.ndarray | None  # (H, W) bool person mask

    def box(self, margin: float = 0.15) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1) around the visible landmarks, grown by ``margin`` of its size."""
        p = self.image_xy[self.visibility > 0.3] if (self.visibility > 0.3).sum() >= 4 else self.image_xy
        lo, hi = p.min(0), p.max(0)
        g = margin * (hi - lo).max()
        return float(lo[0] - g), float(lo[1] - g), float(hi[0] + g), float(hi[1] + g)


@contextlib.contextmanager
def quiet_native_logs():
    """MediaPipe's C++ (TFLite, absl) writes INFO and W0000 lines straight to the process' stderr:
    they go to /dev/null for the duration, unless recon logs at DEBUG (``recon -v``)."""
    if logging.getLogger("recon").isEnabledFor(logging.DEBUG):
        yield
        return
    sys.stderr.flush()
    saved, null = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(null)


def available() -> bool:
    """Whether the optional mediapipe package is installed."""
    return importlib.util.find_spec("mediapipe") is not None


def model_file(model: str) -> Path:
    """Where MediaPipe looks for a landmark model: inside its own package (without the file it
    would try to download it, so ``resolve_model`` checks first)."""
    if model not in MODELS:
        raise ReconError(f"unknown MediaPipe landmark model {model!r}; choose one of {', '.join(MODELS)}")
    package = Path(importlib.util.find_spec("mediapipe").origin).parent
    return package / "modules" / "pose_landmark" / f"pose_landmark_{model}.tflite"


def resolve_model(model: str) -> str:
    """``model`` if its file is installed, else "full" (the wheel's own) with a one-line warning."""
    if model_file(model).is_file():
        return model
    if model not in _WARNED:
        _WARNED.add(model)
        log.warning("MediaPipe's %s landmark model is not installed (scripts/setup.sh adds it): using full",
                    model)
    return "full"


class MediaPipePose:
    """One person per image: ``MediaPipePose()(rgb) -> MPPose | None`` (None: nobody found).
    ``model``: the landmark model, "lite", "full" or "heavy" (``MODELS``); ``self.model`` is the one
    used ("full" when the one asked for is not installed). ``video``: MediaPipe's video mode, for
    the frames of one video in order: it follows the person from the last frame's landmarks and
    runs its detector only when it has lost them (faster; its landmarks are filtered over time)."""

    def __init__(self, model: str = "full", segmentation: bool = True, min_confidence: float = 0.5,
                 video: bool = False):
        if not available():
            raise ReconError("mediapipe is not installed: scripts/setup.sh installs mediapipe==0.10.21 "
                             "(or use `recon run --source backbone`)")
        import mediapipe as mp  # noqa: PLC0415 - optional extra, imported only when used

        self.model = resolve_model(model)
        with quiet_native_logs():
            self.pose = mp.solutions.pose.Pose(static_image_mode=not video, model_complexity=MODELS[self.model],
                                               enable_segmentation=segmentation,
                                               min_detection_confidence=min_confidence)
            # The graph opens its calculators (which log) on its own threads after the constructor
            # returns: one image through it makes them finish inside this quiet window (an empty
            # image: in video mode it leaves nothing to follow).
            self.pose.process(np.zeros((64, 64, 3), np.uint8))

    def __call__(self, rgb: np.ndarray) -> MPPose | None:
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"expected an (H, W, 3) uint8 RGB image, got {rgb.shape} {rgb.dtype}")
        h, w = rgb.shape[:2]
        with quiet_native_logs():
            r = self.pose.process(np.ascontiguousarray(rgb))
        if r.pose_landmarks is None or r.pose_world_landmarks is None:
            return None
        lm = r.pose_landmarks.landmark
        xy = np.array([[p.x * w, p.y * h] for p in lm], np.float64)
        vis = np.array([p.visibility for p in lm], np.float64)
        world = np.array([[p.x, p.y, p.z] for p in r.pose_world_landmarks.landmark], np.float64)
        mask = None if r.segmentation_mask is None else np.asarray(r.segmentation_mask) > 0.5
        return MPPose(xy, vis, world, mask)

    def close(self) -> None:
        self.pose.close()
