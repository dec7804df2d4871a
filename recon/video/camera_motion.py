"""How the camera turned between frames, from the background: corners tracked by pyramidal
Lucas-Kanade optical flow outside the people's boxes (their motion is not the camera's), and the
rotation that best explains them. For a camera that only turns (a pan, a tilt, a hand-held
camera's shake about its centre) the background moves by the homography ``K R K^-1`` whatever its
depth, so a RANSAC homography of the tracked points, taken back through ``K`` and projected onto
the rotations, is the turn; a camera that also moves gives the rotation of its distant background.

``CameraRotations(k)(frames)`` ((image, people's boxes) pairs) -> (T, 3, 3) rotations of each
frame's camera relative to the first one's (OpenCV camera axes: ``x_t = R_t x_0`` for a direction),
and how many points each step rested on; or frame by frame, ``add(image, boxes)`` (``hold()`` for a
frame that could not be read) then ``result()``. ``recon video`` takes the turn out of the people's
motion when the camera turned more than ``MOVING_DEGREES``.
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np

MOVING_DEGREES = 2.0  # a camera that turned more than this over a clip is not static


@dataclass
class CameraRotations:
    """The turn of the camera frame to frame (module doc). ``corners``: points looked for per
    frame; ``min_points``: below this many background points a step is taken as no turn."""

    k: np.ndarray
    corners: int = 400
    min_points: int = 12
    ransac_px: float = 1.0
    max_side: int = 320  # frames are looked at this small (the turn is a few parameters: cheap and enough)

    def __post_init__(self):
        self._rotations, self._used, self._prev = [], [], None

    def __call__(self, frames: Iterable[tuple[np.ndarray, np.ndarray | None]]) -> tuple[np.ndarray, np.ndarray]:
        """``frames``: (RGB (H, W, 3) uint8, the people's (n, 4) x0, y0, x1, y1 boxes or None),
        streamed. Returns (T, 3, 3) rotations relative to the first frame and (T,) the background
        points each step used (0 for the first frame and for steps taken as still)."""
        self.__post_init__()
        for rgb, boxes in frames:
            self.add(rgb, boxes)
        return self.result()

    def add(self, rgb: np.ndarray, boxes: np.ndarray | None) -> None:
        """The next frame, as it comes (``recon video`` feeds the frames of its per-frame pass)."""
        f = min(1.0, self.max_side / max(rgb.shape[:2]))
        if self._prev is None:
            self._k = np.diag([f, f, 1.0]) @ np.asarray(self.k, float)
            self._k_inv = np.linalg.inv(self._k)
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        if f < 1.0:
            size = (round(rgb.shape[1] * f), round(rgb.shape[0] * f))
            gray = cv2.resize(gray, size, interpolation=cv2.INTER_AREA)
        mask = background_mask(gray.shape, None if boxes is None else np.asarray(boxes, float) * f)
        if self._prev is None:
            self._rotations.append(np.eye(3))
            self._used.append(0)
        else:
            step, n = self._step(self._prev[0], gray, self._prev[1] & mask, self._k, self._k_inv)
            self._rotations.append(step @ self._rotations[-1])
            self._used.append(n)
        self._prev = (gray, mask)

    def hold(self) -> None:
        """A frame that could not be read: taken as turned like the last one read."""
        self._rotations.append(self._rotations[-1] if self._rotations else np.eye(3))
        self._used.append(0)

    def result(self) -> tuple[np.ndarray, np.ndarray]:
        """The frames added so far: (T, 3, 3) rotations and (T,) points used (``__call__``)."""
        if not self._rotations:
            return np.eye(3)[None], np.zeros(1, int)
        return np.stack(self._rotations), np.array(self._used)

    def _step(self, a: np.ndarray, b: np.ndarray, mask: np.ndarray, k: np.ndarray, k_inv: np.ndarray
              ) -> tuple[np.ndarray, int]:
        """The rotation from frame ``a``'s camera to ``b``'s, and the points it rests on."""
        pts = cv2.goodFeaturesToTrack(a, self.corners, 0.01, 5, mask=mask.astype(np.uint8))
        if pts is None or len(pts) < self.min_points:
            return np.eye(3), 0
        nxt, status, _ = cv2.calcOpticalFlowPyrLK(a, b, pts, None, winSize=(21, 21), maxLevel=3)
        back, status_back, _ = cv2.calcOpticalFlowPyrLK(b, a, nxt, None, winSize=(21, 21), maxLevel=3)
        ok = (status[:, 0] == 1) & (status_back[:, 0] == 1) & (np.linalg.norm(back - pts, axis=-1)[:, 0] < 0.5)
        if ok.sum() < self.min_points:
            return np.eye(3), 0
        h, inliers = cv2.findHomography(pts[ok], nxt[ok], cv2.RANSAC, self.ransac_px)
        if h is None or inliers.sum() < self.min_points:
            return np.eye(3), 0
        return nearest_rotation(k_inv @ h @ k), int(inliers.sum())


def background_mask(shape: tuple[int, int], boxes: np.ndarray | None, grow: float = 0.1) -> np.ndarray:
    """(H, W) bool: True away from the people's boxes (each grown by ``grow`` of its size)."""
    mask = np.ones(shape, bool)
    for x0, y0, x1, y1 in (np.asarray(boxes, float).reshape(-1, 4) if boxes is not None else []):
        g = grow * max(x1 - x0, y1 - y0)
        mask[max(0, int(y0 - g)):max(0, int(y1 + g + 1)), max(0, int(x0 - g)):max(0, int(x1 + g + 1))] = False
    return mask


def nearest_rotation(m: np.ndarray) -> np.ndarray:
    """The rotation nearest to ``m`` up to scale (a homography is known up to one)."""
    u, _, vt = np.linalg.svd(m)
    r = u @ vt
    return r if np.linalg.det(r) > 0 else u @ np.diag([1.0, 1.0, -1.0]) @ vt


def turned_degrees(rotations: np.ndarray) -> float:
    """The largest angle (degrees) between the first frame's camera and any later one's."""
    cos = (np.trace(rotations, axis1=1, axis2=2) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max())
