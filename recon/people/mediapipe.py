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
from typing import Literal

import numpy as np

from recon.errors import ReconError

NUM_MP = 33  # MediaPipe Pose landmarks
# Left/right flip map of MediaPipe Pose's 33 landmarks.
MP_MIRROR = (0, 4, 5, 6, 1, 2, 3, 8, 7, 10, 9) + tuple(i + 1 if i % 2 else i - 1 for i in range(11, 33))
# The landmark models by name, as MediaPipe's model_complexity; the wheel ships only "full".
LandmarkModel = Literal["lite", "full", "heavy"]
MODELS = {"lite": 0, "full": 1, "heavy": 2}
DEFAULT_MODEL: LandmarkModel = "heavy"  # recon run's: the most accurate (scripts/setup.sh installs it)
log = logging.getLogger(__name__)
_WARNED: set[str] = set()  # models already reported missing: one line per process


@dataclass
class MPPose:
    image_xy: np.ndarray  # (33, 2) pixels
    visibility: np.ndarray  # (33,) in [0, 1]
    world: np.ndarray  # (33, 3) metres, hip-centred, camera-aligned axes (OpenCV: y down, z forward)
    mask: np.ndarray | None  # (H, W) bool person mask
    aux: np.ndarray | None = None  # (2, 2) pixels: the hips' centre and a point above the head (its ROI)

    def roi(self) -> tuple[float, float, float, float]:
        """The region MediaPipe would look at next for this person (its tracking rule): (centre x,
        centre y, side, rotation in radians) in pixels, from ``aux`` (else the landmarks' box)."""
        if self.aux is None:
            x0, y0, x1, y1 = self.box(0.0)
            return 0.5 * (x0 + x1), 0.5 * (y0 + y1), 1.25 * max(x1 - x0, y1 - y0), 0.0
        c, top = self.aux
        d = top - c
        return float(c[0]), float(c[1]), float(2.5 * np.hypot(*d)), float(np.arctan2(d[0], -d[1]))

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

    def __init__(self, model: str = DEFAULT_MODEL, segmentation: bool = True, min_confidence: float = 0.5,
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


ROI_GRAPH = """
input_stream: "image"
input_stream: "roi"
output_stream: "landmarks"
output_stream: "aux"
output_stream: "world_landmarks"
output_stream: "segmentation_mask"
node {
  calculator: "PoseLandmarkByRoiCpu"
  input_side_packet: "MODEL_COMPLEXITY:model_complexity"
  input_side_packet: "ENABLE_SEGMENTATION:enable_segmentation"
  input_stream: "IMAGE:image"
  input_stream: "ROI:roi"
  output_stream: "LANDMARKS:landmarks"
  output_stream: "AUXILIARY_LANDMARKS:aux"
  output_stream: "WORLD_LANDMARKS:world_landmarks"
  output_stream: "SEGMENTATION_MASK:segmentation_mask"
}
"""


class MediaPipeLandmarks:
    """MediaPipe's landmark model alone on a region of the image, without its face-anchored person
    detector: ``MediaPipeLandmarks()(rgb, roi) -> MPPose | None``, ``roi`` = (centre x, centre y,
    side, rotation in radians) in pixels, a square the model sees upright. None where the model's
    own presence score says nobody is there (MediaPipe's threshold, 0.5). What finds people the
    detector misses: back views, bodies cut by a border (``recon.keypoints.sources``)."""

    def __init__(self, model: str = DEFAULT_MODEL, segmentation: bool = True):
        if not available():
            raise ReconError("mediapipe is not installed: scripts/setup.sh installs mediapipe==0.10.21")
        from mediapipe.framework.formats import rect_pb2  # noqa: PLC0415 - optional extra
        from mediapipe.python.solution_base import SolutionBase  # noqa: PLC0415

        self.model = resolve_model(model)
        self._rect = rect_pb2.NormalizedRect
        with quiet_native_logs():
            self.graph = SolutionBase(graph_config=ROI_GRAPH, side_inputs={
                "model_complexity": MODELS[self.model], "enable_segmentation": segmentation})
            # As in MediaPipePose: the calculators open (and log) on the graph's own threads; one
            # image through it makes that happen inside this quiet window.
            self.graph.process({"image": np.zeros((64, 64, 3), np.uint8),
                                "roi": self._rect(x_center=0.5, y_center=0.5, width=1.0, height=1.0)})

    def __call__(self, rgb: np.ndarray, roi: tuple[float, float, float, float]) -> MPPose | None:
        h, w = rgb.shape[:2]
        cx, cy, side, rot = roi
        rect = self._rect(x_center=cx / w, y_center=cy / h, width=side / w, height=side / h, rotation=rot)
        with quiet_native_logs():
            r = self.graph.process({"image": np.ascontiguousarray(rgb), "roi": rect})
        if r.landmarks is None or r.world_landmarks is None:
            return None
        lm = r.landmarks.landmark
        xy = np.array([[p.x * w, p.y * h] for p in lm], np.float64)[:NUM_MP]
        vis = np.array([p.visibility for p in lm], np.float64)[:NUM_MP]
        world = np.array([[p.x, p.y, p.z] for p in r.world_landmarks.landmark], np.float64)[:NUM_MP]
        aux = np.array([[p.x * w, p.y * h] for p in r.aux.landmark], np.float64) if r.aux is not None else None
        mask = None if r.segmentation_mask is None else np.asarray(r.segmentation_mask) > 0.5
        return MPPose(xy, vis, world, mask, aux)

    def close(self) -> None:
        self.graph.close()
