"""What a keypoint source gives the pipeline: ``Keypoints`` for one person, or None."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass
class Keypoints:
    """One person's J+ (24 joints + 18 surface landmarks) as a source detected them."""

    points3d: np.ndarray  # (42, 3) root-relative, metres, OpenCV camera axes
    points2d: np.ndarray  # (42, 2) pixels
    confidence: float  # [0, 1]
    box: tuple[float, float, float, float]  # person box x0, y0, x1, y1 (pixels)
    mask: np.ndarray | None = None  # (H, W) bool person mask, when the source segments
    person_score: float | None = None  # log-odds that this is a person (recon.people.guard), when scored
    found_by: str = ""  # the source that found this person ("mediapipe", "backbone")


class KeypointSource(Protocol):
    """``source(rgb, K) -> Keypoints | None`` (None: no person found); ``name`` goes into result.json."""

    name: str

    def __call__(self, rgb: np.ndarray, k: np.ndarray) -> Keypoints | None: ...
