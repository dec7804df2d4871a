"""Views of an image and boxes for the keypoint sources (``recon.keypoints.sources``): grayscale
tints, padded and mirrored views mapped back, windows, answers that read the same person, a found
person painted over (box geometry: ``recon.people.boxes``).
"""
from __future__ import annotations

import cv2
import numpy as np

from recon.body import skeleton
from recon.keypoints.base import Keypoints
from recon.people.boxes import box_iou, box_overlap
from recon.people.mediapipe import MP_MIRROR, MPPose

GRAY_TINT = (1.05, 0.85, 0.85)  # a warm tint for grayscale images; the choice: CHANGELOG 0.5.0
GRAY_SMALL = 256  # grayscale images are also searched at this longer side


def is_grayscale(rgb: np.ndarray) -> bool:
    """Whether the three channels are equal (a black-and-white photo loaded as RGB)."""
    return bool((rgb[..., 0] == rgb[..., 1]).all() and (rgb[..., 0] == rgb[..., 2]).all())


def tinted(rgb: np.ndarray) -> np.ndarray:
    """A grayscale image with a warm tint: MediaPipe's person detector finds more people in it."""
    return np.clip(rgb.astype(np.float32) * np.asarray(GRAY_TINT, np.float32), 0, 255).astype(np.uint8)


def pad_image(rgb: np.ndarray, factor: float) -> tuple[np.ndarray, int]:
    """The image zero-padded on every side to ``factor`` x its longer side, and the pad in pixels."""
    p = int(round(max(rgb.shape[:2]) * (factor - 1) / 2))
    return (cv2.copyMakeBorder(rgb, p, p, p, p, cv2.BORDER_CONSTANT, value=(0, 0, 0)) if p else rgb), p


def unview(r: MPPose, pad: int, mirrored: bool, shape) -> MPPose:
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


def mirrored_camera(k: np.ndarray, w: int) -> np.ndarray:
    """The intrinsics of the image mirrored left-right (``u -> w - u``)."""
    km = np.array(k, float)
    km[0, 2] = w - km[0, 2]
    return km


def unmirror(p3: np.ndarray, uv: np.ndarray, w: int) -> tuple[np.ndarray, np.ndarray]:
    """J+ found on the mirrored image (width ``w``) -> the same person's J+ in the image: left and
    right swapped, x flipped in 3D and in pixels."""
    mirror = list(skeleton.POINT_MIRROR)
    uv = uv[mirror].copy()
    uv[:, 0] = w - uv[:, 0]
    return p3[mirror] * np.array([-1.0, 1.0, 1.0]), uv


def blank_person(rgb: np.ndarray, kp: Keypoints) -> np.ndarray:
    """The image with one found person painted over (inpainted from the surroundings, at low
    resolution: a flat fill would leave a person-shaped silhouette), so that MediaPipe, asked
    again, finds the next person. The region: the person's mask inside its box, grown a little;
    the box where the source gives no mask."""
    h, w = rgb.shape[:2]
    x0, y0, x1, y1 = kp.box
    size = max(x1 - x0, y1 - y0, 1.0)
    bx = np.zeros((h, w), np.uint8)
    g = 0.1 * size
    bx[max(0, int(y0 - g)):max(0, int(y1 + g)), max(0, int(x0 - g)):max(0, int(x1 + g))] = 1
    region = bx if kp.mask is None else (kp.mask.astype(np.uint8) & bx)
    grow = max(3, int(0.04 * size)) * 2 + 1
    region = cv2.dilate(region, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (grow, grow)))
    s = min(1.0, 256.0 / max(h, w))
    small = cv2.resize(rgb, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    small_region = cv2.resize(region, small.shape[1::-1], interpolation=cv2.INTER_NEAREST)
    filled = cv2.resize(cv2.inpaint(small, small_region, 5, cv2.INPAINT_TELEA), (w, h), interpolation=cv2.INTER_LINEAR)
    out = rgb.copy()
    out[region > 0] = filled[region > 0]
    return out


def windows(h: int, w: int) -> list[tuple[int, int, int, int]]:
    """Where ``MediaPipeSource.people`` looks after the whole image: squares of the short side
    along the long one (half-overlapping) when the image is elongated, and four overlapping
    windows of 60 % of each side. (x0, y0, x1, y1)."""
    out = []
    side, long = min(h, w), max(h, w)
    if long > 1.3 * side:
        n = int(np.ceil((long - side) / (side / 2))) + 1
        for start in np.linspace(0, long - side, n).round().astype(int):
            out.append((start, 0, start + side, h) if w >= h else (0, start, w, start + side))
    ww, wh = int(0.6 * w), int(0.6 * h)
    out += [(x, y, x + ww, y + wh) for y in (0, h - wh) for x in (0, w - ww)]
    return out


def same_person(new: Keypoints, old: Keypoints) -> bool:
    """A find that is someone found already: most of its keypoints inside the first one's box
    (a limb left over by the painting), or most of the smaller box inside the other."""
    x0, y0, x1, y1 = old.box
    p = new.points2d
    inside = (p[:, 0] >= x0) & (p[:, 0] <= x1) & (p[:, 1] >= y0) & (p[:, 1] <= y1)
    return bool(inside.mean() > 0.5 or box_overlap(new.box, old.box) > 0.5)


def same_answer(new: Keypoints, old: Keypoints, near: float = 0.15, iou: float = 0.7) -> bool:
    """Two answers on different boxes that read the same person: their keypoints lie within
    ``near`` of the person's size of each other (median), or their boxes overlap by ``iou``. Unlike
    ``same_person``, a person standing behind another is someone else."""
    b = old.box
    size = max(b[2] - b[0], b[3] - b[1], 1.0)
    d = np.median(np.linalg.norm(new.points2d - old.points2d, axis=1))
    return bool(d < near * size or box_iou(new.box, old.box) > iou)


def scaled(kp: Keypoints, factor: float, shape) -> Keypoints:
    """Keypoints found on a resized copy -> the same in the image (``factor``: image / copy)."""
    mask = None
    if kp.mask is not None:
        mask = cv2.resize(kp.mask.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST) > 0
    return Keypoints(kp.points3d, kp.points2d * factor, kp.confidence, tuple(float(b) * factor for b in kp.box),
                     mask, kp.person_score, kp.found_by)


def shifted(kp: Keypoints, x0: int, y0: int, shape) -> Keypoints:
    """Keypoints found on a window -> the same in the whole image."""
    if x0 == 0 and y0 == 0 and (kp.mask is None or kp.mask.shape == tuple(shape[:2])):
        return kp
    mask = None
    if kp.mask is not None:
        mask = np.zeros(shape[:2], bool)
        mh, mw = kp.mask.shape
        mask[y0:y0 + mh, x0:x0 + mw] = kp.mask
    b = kp.box
    return Keypoints(kp.points3d, kp.points2d + [x0, y0], kp.confidence, (b[0] + x0, b[1] + y0, b[2] + x0, b[3] + y0),
                     mask, kp.person_score, kp.found_by)
