"""People followed across the frames of a video: per-frame detections -> tracks.

``track(detections)`` assigns each frame's detections to the tracks alive (Hungarian assignment,
``scipy.optimize.linear_sum_assignment``). Each track's box centre, box height and depth are
carried on by straight lines fitted to its last ``history`` frames, through any gap
(``Track.predicted``); a detection may join a track only near that prediction (``max_offset``
box heights, growing with the gap), and the cost adds the ratios of box height and depth, the
keypoints' distance (the track's last keypoints moved with the prediction) and the distance of the
colour histograms of the person's pixels. So a person hidden behind another comes out on the far
side under their own id even where the two look alike. A track missing for up to ``max_gap``
frames keeps waiting (the gap is bridged later), after that it is retired. A detection that
matches no live track takes the id of a retired track whose appearance (the colour histogram of
the person's pixels) it matches, else starts a new track. Tracks shorter than ``min_frames`` are
dropped (flickering phantoms), and at most ``max_people`` tracks are kept, the longest ones.
``TrackerConfig(motion=False)``: 0.29's cost (box overlap with the track's box moved by its
velocity, keypoints, colours).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from recon.people.boxes import box_iou

HIST_BINS = (12, 8)  # hue, saturation


@dataclass
class Detection:
    """One person found in one frame: its box (x0, y0, x1, y1), J+ 2D (42, 2), and the colour
    histogram of its pixels (``appearance``), None where it has none."""

    frame: int
    box: np.ndarray
    points2d: np.ndarray
    appearance: np.ndarray | None = None
    index: int = 0  # its place among the frame's detections
    depth: float | None = None  # metres from the camera (the per-frame pass's placement), None where unknown


@dataclass
class Track:
    id: int
    detections: list[Detection] = field(default_factory=list)

    @property
    def frames(self) -> list[int]:
        return [d.frame for d in self.detections]

    @property
    def last(self) -> Detection:
        return self.detections[-1]

    def predicted_box(self, frame: int) -> np.ndarray:
        """The last box moved on by the velocity of the last two detections."""
        box = self.last.box
        if len(self.detections) < 2:
            return box
        a, b = self.detections[-2], self.last
        v = (b.box - a.box) / max(b.frame - a.frame, 1)
        return box + v * min(frame - b.frame, 5)

    def appearance(self) -> np.ndarray | None:
        hs = [d.appearance for d in self.detections[-30:] if d.appearance is not None]
        return None if not hs else np.mean(hs, 0).astype(np.float32)

    def predicted(self, frame: int, history: int = 10) -> tuple[np.ndarray, float, float | None]:
        """Box centre, box height and depth at ``frame``: straight lines fitted to the detections of
        the last ``history`` frames before the track's last one, carried on through any gap."""
        recent = [d for d in self.detections[-history:] if d.frame > self.last.frame - history]
        t = np.array([d.frame for d in recent], float) - self.last.frame
        centre = np.array([box_centre(d.box) for d in recent])
        height = np.log([max(d.box[3] - d.box[1], 1.0) for d in recent])
        depths = [d.depth for d in recent if d.depth is not None and d.depth > 0]
        depth = np.log(depths) if len(depths) == len(recent) else None
        ahead = frame - self.last.frame

        def line(y):
            if len(t) < 3:
                return y[-1]
            slope, at_last = np.polyfit(t, y, 1)
            return at_last + slope * ahead
        c = np.array([line(centre[:, 0]), line(centre[:, 1])])
        return c, float(np.exp(line(height))), None if depth is None else float(np.exp(line(depth)))


def appearance(rgb: np.ndarray, box, mask: np.ndarray | None = None) -> np.ndarray | None:
    """Normalised hue-saturation histogram of the person's pixels (its mask inside its box, or
    the middle of the box without a mask); None when too few pixels."""
    h, w = rgb.shape[:2]
    x0, y0, x1, y1 = (int(round(v)) for v in box)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if x1 - x0 < 4 or y1 - y0 < 4:
        return None
    crop = np.ascontiguousarray(rgb[y0:y1, x0:x1])
    if mask is not None:
        m = np.ascontiguousarray(mask[y0:y1, x0:x1]).astype(np.uint8)
    else:
        m = np.zeros(crop.shape[:2], np.uint8)
        cy, cx = (y1 - y0) // 2, (x1 - x0) // 2
        m[cy - (y1 - y0) // 4:cy + (y1 - y0) // 4, cx - (x1 - x0) // 6:cx + (x1 - x0) // 6] = 1
    if m.sum() < 20:
        return None
    hsv = cv2.cvtColor(crop, cv2.COLOR_RGB2HSV)
    hist = cv2.calcHist([hsv], [0, 1], m, list(HIST_BINS), [0, 180, 0, 256]).ravel()
    return (hist / max(hist.sum(), 1e-6)).astype(np.float32)


def appearance_distance(a: np.ndarray | None, b: np.ndarray | None) -> float:
    """Bhattacharyya distance of two histograms in [0, 1]; 1 where one is missing."""
    if a is None or b is None:
        return 1.0
    return float(cv2.compareHist(a, b, cv2.HISTCMP_BHATTACHARYYA))


def _keypoint_distance(a: np.ndarray, b: np.ndarray, box) -> float:
    size = max(box[2] - box[0], box[3] - box[1], 1.0)
    return float(np.median(np.linalg.norm(a - b, axis=1)) / size)


@dataclass
class TrackerConfig:
    max_gap: int = 30  # frames a track waits for its person before it is retired
    min_iou: float = 0.1  # a detection joins a track when the boxes overlap this much ...
    max_keypoint_distance: float = 0.5  # ... or the keypoints are this close (units of the box size)
    appearance: float = 1.0  # weight of the colour histograms' distance in the assignment (people crossing)
    reid_distance: float = 0.35  # a retired track's appearance this close gives its id back
    motion: bool = True  # predict each track's box and depth through gaps (people passing behind others)
    history: int = 10  # frames of a track its motion is fitted to
    max_offset: float = 0.3  # a detection joins a track within this distance of its predicted box centre
    # (units of the box's height), growing by ``offset_growth`` per frame of gap
    offset_growth: float = 0.03
    size: float = 1.0  # weight of |log| of the box heights' ratio and of the depths' ratio
    min_frames: int = 5  # shorter tracks are dropped
    max_people: int | None = None


def track(detections: list[list[Detection]], cfg: TrackerConfig | None = None) -> list[Track]:
    """Tracks of the per-frame ``detections`` (frame f's list at index f, each with ``frame`` f),
    numbered from 0 in order of first appearance."""
    cfg = cfg or TrackerConfig()
    live: list[Track] = []
    retired: list[Track] = []
    next_id = 0
    for f, dets in enumerate(detections):
        for t in [t for t in live if f - t.last.frame > cfg.max_gap]:
            live.remove(t)
            retired.append(t)
        matched: set[int] = set()
        if live and dets:
            cost = np.array([_costs(t, dets, f, cfg) for t in live])
            rows, cols = linear_sum_assignment(cost)
            for i, j in zip(rows, cols, strict=True):
                if cost[i, j] < 1e6:
                    live[i].detections.append(dets[j])
                    matched.add(j)
        for j, d in enumerate(dets):
            if j in matched:
                continue
            back = _reidentified(d, retired, cfg)
            if back is not None:
                retired.remove(back)
                back.detections.append(d)
                live.append(back)
            else:
                live.append(Track(next_id, [d]))
                next_id += 1
    tracks = [t for t in live + retired if len(t.detections) >= cfg.min_frames]
    if cfg.max_people is not None:
        tracks = sorted(tracks, key=lambda t: -len(t.detections))[:cfg.max_people]
    tracks = sorted(tracks, key=lambda t: (t.detections[0].frame, t.id))
    for n, t in enumerate(tracks):
        t.id = n
    return tracks


def box_centre(box) -> np.ndarray:
    """(2,) the middle of an (x0, y0, x1, y1) box."""
    return np.array([(box[0] + box[2]) / 2, (box[1] + box[3]) / 2])


def _costs(t: Track, dets: list[Detection], frame: int, cfg: TrackerConfig) -> list[float]:
    """The costs of giving each of ``dets`` to track ``t`` (1e6 where one may not join it); the
    track's look and predicted place are worked out once for them all."""
    look = t.appearance()
    apps = [0.5 if look is None or d.appearance is None else appearance_distance(look, d.appearance) for d in dets]
    if not cfg.motion:
        pred = t.predicted_box(frame)
        out = []
        for d, app in zip(dets, apps, strict=True):
            iou = box_iou(pred, d.box)
            kd = _keypoint_distance(t.last.points2d, d.points2d, d.box)
            ok = iou >= cfg.min_iou or kd <= cfg.max_keypoint_distance
            out.append((1.0 - iou) + min(kd, 1.0) + cfg.appearance * app if ok else 1e6)
        return out
    centre, height, depth = t.predicted(frame, cfg.history)
    reach = cfg.max_offset + cfg.offset_growth * (frame - t.last.frame - 1)
    moved = t.last.points2d + (centre - box_centre(t.last.box))  # the last keypoints carried with the prediction
    out = []
    for d, app in zip(dets, apps, strict=True):
        offset = float(np.linalg.norm(box_centre(d.box) - centre)) / height
        if offset > reach:
            out.append(1e6)
            continue
        size = abs(np.log(max(d.box[3] - d.box[1], 1.0) / height))
        if depth is not None and d.depth is not None and d.depth > 0:
            size = (size + abs(np.log(d.depth / depth))) / 2
        kd = _keypoint_distance(moved, d.points2d, d.box)
        out.append(offset + cfg.size * size + min(kd, 1.0) + cfg.appearance * app)
    return out


def _reidentified(d: Detection, retired: list[Track], cfg: TrackerConfig) -> Track | None:
    """The retired track that looks most like ``d``, if close enough."""
    best, best_d = None, cfg.reid_distance
    for t in retired:
        dist = appearance_distance(d.appearance, t.appearance())
        if dist < best_d:
            best, best_d = t, dist
    return best
