"""The per-frame pass of ``recon video``: every frame through the image pipeline (without its
per-image fit), stored batch by batch so that a killed run resumes.

``PerFrame.run(frames)`` reconstructs batches of ``batch`` frames with a ``recon.Reconstructor``
whose keypoint source is MediaPipe in video mode (one person) or ``MediaPipeSource`` with
``people()`` (several), and writes each finished batch atomically as ``<work>/batch-<first>.npz``;
a batch already there is read back instead of computed. ``Detections`` are all the people found,
one row each, with what the tracker and the track optimisation need.
"""
from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from recon import paths
from recon.pipeline import Reconstructor
from recon.video.frames import Frame
from recon.video.track import HIST_BINS, appearance

APPEARANCE = HIST_BINS[0] * HIST_BINS[1]


@dataclass
class Detections:
    """People found in the frames, one row each (N rows); ``frame`` is the position of the row's
    frame among the frames taken (not the source's index)."""

    frame: np.ndarray  # (N,) int
    points2d: np.ndarray  # (N, 42, 2) pixels
    points3d: np.ndarray  # (N, 42, 3) lifted J+, root-relative
    box: np.ndarray  # (N, 4)
    confidence: np.ndarray  # (N,)
    rotmats: np.ndarray  # (N, 24, 3, 3) SMPLR's pose, root into the camera frame
    shape: np.ndarray  # (N, S)
    translation: np.ndarray  # (N, 3) camera frame
    appearance: np.ndarray  # (N, APPEARANCE), NaN where the person showed too few pixels

    @classmethod
    def empty(cls, num_shape: int) -> Detections:
        z = lambda *s: np.zeros((0, *s), np.float32)  # noqa: E731
        return cls(np.zeros(0, np.int64), z(42, 2), z(42, 3), z(4), z(), z(24, 3, 3), z(num_shape), z(3),
                   z(APPEARANCE))

    @classmethod
    def concat(cls, parts: list[Detections]) -> Detections:
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)))

    def __len__(self) -> int:
        return len(self.frame)


@dataclass
class FrameLog:
    """The frames taken: source index, time, and why a frame has no pixels ("" where it has)."""

    index: list[int]
    time: list[float]
    error: list[str]


def _batches(frames: Iterable[Frame], size: int) -> Iterator[list[Frame]]:
    batch: list[Frame] = []
    for f in frames:
        batch.append(f)
        if len(batch) == size:
            yield batch
            batch = []
    if batch:
        yield batch


class PerFrame:
    """``rec``: the Reconstructor (built by the caller: its source decides video or image mode);
    ``k``: the intrinsics of every frame; ``work``: the folder of finished batches."""

    def __init__(self, rec: Reconstructor, k: np.ndarray, work: Path, max_people: int = 1, batch: int = 30):
        self.rec, self.k, self.work = rec, np.asarray(k, float), Path(work)
        self.max_people, self.batch = max_people, batch
        self.work.mkdir(parents=True, exist_ok=True)

    def run(self, frames: Iterable[Frame], on_batch=None) -> tuple[Detections, FrameLog]:
        """Every frame's people; ``on_batch(frames, resumed, boxes)`` after each batch (progress;
        ``boxes``: per frame of the batch, its people's (n, 4) boxes)."""
        found, log, position = [], FrameLog([], [], []), 0
        for batch in _batches(frames, self.batch):
            path = self.work / f"batch-{batch[0].index:08d}.npz"
            dets = self._load(path, batch) if path.exists() else None
            resumed = dets is not None
            if dets is None:
                dets = self._compute(batch)
                arrays = {f.name: getattr(dets, f.name) for f in fields(Detections)}
                arrays["indices"] = np.array([f.index for f in batch])
                paths.atomic_write(path, lambda tmp, a=arrays: np.savez(open(tmp, "wb"), **a))
            boxes = [dets.box[dets.frame == n] for n in range(len(batch))]
            dets.frame = dets.frame + position
            found.append(dets)
            for f in batch:
                log.index.append(f.index)
                log.time.append(f.time)
                log.error.append(f.error)
            position += len(batch)
            if on_batch is not None:
                on_batch(batch, resumed, boxes)
        return (Detections.concat(found) if found else Detections.empty(self.rec.body.num_shape_params)), log

    def _load(self, path: Path, batch: list[Frame]) -> Detections | None:
        """A finished batch, or None when it is not this batch's (another range) or unreadable."""
        try:
            with np.load(path, allow_pickle=False) as z:
                if z["indices"].tolist() != [f.index for f in batch]:
                    return None
                return Detections(**{f.name: z[f.name] for f in fields(Detections)})
        except (OSError, ValueError, KeyError):
            return None

    def _compute(self, batch: list[Frame]) -> Detections:
        good = [n for n, f in enumerate(batch) if f.rgb is not None]
        rows = []
        if good:
            images = [batch[n].rgb for n in good]
            results = self.rec.people(images, [self.k] * len(images), self.max_people)
            for n, res in zip(good, results, strict=True):
                if isinstance(res, Exception):
                    continue
                for r in res:
                    kp = r.keypoints
                    hist = appearance(batch[n].rgb, kp.box, kp.mask)
                    rows.append((n, kp.points2d, kp.points3d, kp.box, kp.confidence, r.rotmats, r.shape,
                                 r.translation, np.full(APPEARANCE, np.nan) if hist is None else hist))
        if not rows:
            return Detections.empty(self.rec.body.num_shape_params)
        cols = list(zip(*rows, strict=True))
        return Detections(np.array(cols[0], np.int64), *(np.stack(c).astype(np.float32) for c in cols[1:]))


def stamp(digest: str, options: dict, config: dict, version: str) -> dict:
    """What the per-frame pass is made from: the input's bytes, the options, recon's version."""
    return {"recon": version, "input": digest, "options": options, "reconstructor": config}


def same_work(work: Path, made_from: dict) -> bool:
    """Whether ``work`` holds batches made from ``made_from`` (else it is started again)."""
    try:
        return json.loads((work / "made_from.json").read_text()) == json.loads(json.dumps(made_from))
    except (OSError, ValueError):
        return False

