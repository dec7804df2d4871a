"""The per-frame pass of ``recon video``: every frame through the image pipeline (without its
per-image fit), stored batch by batch so that a killed run resumes.

``PerFrame.run(frames)`` reconstructs batches of ``batch`` frames with a ``recon.Reconstructor``
whose keypoint source is MediaPipe in video mode (one person) or ``MediaPipeSource`` with
``people()`` (several), and writes each finished batch atomically as ``<work>/batch-<first>.npz``;
a batch already there is read back instead of computed. Two stages overlap (``pipeline``): a
thread decodes the next ``STEP`` frames and finds their keypoints (MediaPipe runs outside
Python's lock) while the caller's thread lifts and places the people of the frames before, so
two cores share the work; the results are those of the stages run one after the other.
``Detections`` are all the people found, one row each, with what the tracker and the track
optimisation need.
"""
from __future__ import annotations

import json
import queue
import threading
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from recon import paths
from recon.pipeline import Reconstructor
from recon.reconstruction import FoundPeople
from recon.video.frames import Frame
from recon.video.track import HIST_BINS, appearance

APPEARANCE = HIST_BINS[0] * HIST_BINS[1]
STEP = 10  # frames through the two stages at a time (a stored batch is several)


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


def ahead(items: Iterator, depth: int = 1) -> Iterator:
    """``items``, computed by a background thread up to ``depth`` items ahead of the consumer; its
    exception is raised in the consumer; the thread stops when the consumer does."""
    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    end = object()

    def put(x) -> bool:
        while not stop.is_set():
            try:
                q.put(x, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            for x in items:
                if not put((x, None)):
                    return
            put((end, None))
        except BaseException as e:  # noqa: BLE001 - handed to the consumer, raised there
            put((None, e))
        finally:
            close = getattr(items, "close", None)
            if close is not None:
                close()

    worker = threading.Thread(target=produce, name="recon-ahead", daemon=True)
    worker.start()
    try:
        while True:
            x, error = q.get()
            if error is not None:
                raise error
            if x is end:
                return
            yield x
    finally:
        stop.set()
        worker.join()


class PerFrame:
    """``rec``: the Reconstructor (built by the caller: its source decides video or image mode);
    ``k``: the intrinsics of every frame; ``work``: the folder of finished batches; ``pipeline``:
    overlap decoding and keypoints with the rest (module doc)."""

    def __init__(self, rec: Reconstructor, k: np.ndarray, work: Path, max_people: int = 1, batch: int = 30,
                 pipeline: bool = True):
        self.rec, self.k, self.work = rec, np.asarray(k, float), Path(work)
        self.max_people, self.batch, self.pipeline = max_people, batch, pipeline
        self.work.mkdir(parents=True, exist_ok=True)

    def run(self, frames: Iterable[Frame], on_batch=None) -> tuple[Detections, FrameLog]:
        """Every frame's people; ``on_batch(frames, resumed, boxes)`` after each batch (progress;
        ``boxes``: per frame of the batch, its people's (n, 4) boxes)."""
        found, log, position, parts = [], FrameLog([], [], []), 0, []
        stages = self._first_stage(frames)
        for batch, path, dets, keypoints, last in (ahead(stages) if self.pipeline else stages):
            resumed = dets is not None
            if dets is None:
                parts.append(self._second_stage(batch, keypoints))
                if not last:
                    continue
                dets, parts = Detections.concat(parts), []
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

    def _first_stage(self, frames: Iterable[Frame]) -> Iterator[tuple]:
        """Per batch: (frames, its file, its stored detections, None, True), or where not stored,
        per ``STEP`` frames of it (stages overlap at this grain): (frames, its file, None, the
        keypoint stage {position in the batch: FoundPeople} of those that decoded, whether the
        batch's last step)."""
        for batch in _batches(frames, self.batch):
            path = self.work / f"batch-{batch[0].index:08d}.npz"
            dets = self._load(path, batch) if path.exists() else None
            if dets is not None:
                yield batch, path, dets, None, True
                continue
            for start in range(0, len(batch), STEP):
                good = [n for n in range(start, min(start + STEP, len(batch))) if batch[n].rgb is not None]
                answers = self.rec.find_people([batch[n].rgb for n in good], [self.k] * len(good), self.max_people)
                yield batch, path, None, dict(zip(good, answers, strict=True)), start + STEP >= len(batch)

    def _load(self, path: Path, batch: list[Frame]) -> Detections | None:
        """A finished batch, or None when it is not this batch's (another range) or unreadable."""
        try:
            with np.load(path, allow_pickle=False) as z:
                if z["indices"].tolist() != [f.index for f in batch]:
                    return None
                return Detections(**{f.name: z[f.name] for f in fields(Detections)})
        except (OSError, ValueError, KeyError):
            return None

    def _second_stage(self, batch: list[Frame], keypoints: dict[int, FoundPeople]) -> Detections:
        good = sorted(keypoints)
        rows = []
        if good:
            results = self.rec.people_from([batch[n].rgb for n in good], [keypoints[n] for n in good])
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

