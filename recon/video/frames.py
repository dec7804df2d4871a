"""The frames of a video, or of a folder of images, in order: ``FrameSource(path, FrameRange())``.

A video is anything OpenCV's FFmpeg backend reads (mp4, avi, mov, webm, mkv); a folder holds one
image per frame in any format Pillow reads, in natural name order (``frame2`` before ``frame10``).
A frame that cannot be decoded comes with its error instead of pixels (``Frame.error``): the caller
reports and skips it, the frames after it still come. In a video, frames are numbered as OpenCV
delivers them: after an unreadable packet its FFmpeg backend may skip one more, so later numbers
(and times) can run a frame early.
"""
from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from recon.errors import ReconError
from recon.io import ImageError, load_image

FOLDER_FPS = 30.0  # a folder of frames has no rate of its own
MAX_BAD_IN_A_ROW = 25  # a video that stops decoding for this many frames has ended (or is unreadable)


class VideoError(ReconError):
    """A video or frame folder that cannot be read at all."""


@dataclass(frozen=True)
class FrameRange:
    """Which frames to take: ``start`` / ``end`` in seconds (``end`` exclusive, None: to the end),
    one source frame in every ``every``, and at most ``fps`` frames a second (the first frame of
    each 1/fps interval; None: the source's rate). A folder's frames are ``folder_fps`` apart."""

    start: float = 0.0
    end: float | None = None
    every: int = 1
    fps: float | None = None
    folder_fps: float = FOLDER_FPS

    def __post_init__(self):
        if self.start < 0 or (self.end is not None and self.end <= self.start):
            raise VideoError(f"frame range: need 0 <= start < end, got start={self.start} end={self.end}")
        if self.every < 1:
            raise VideoError(f"frame range: every must be at least 1, got {self.every}")
        for name in ("fps", "folder_fps"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise VideoError(f"frame range: {name} must be a positive number, got {value}")


@dataclass
class Frame:
    index: int  # the frame's number in the source, from 0
    time: float  # seconds from the source's first frame
    rgb: np.ndarray | None  # (H, W, 3) uint8, None when it could not be decoded
    error: str = ""  # why there are no pixels


def natural_key(name: str) -> list:
    """Sort key that orders the numbers inside names by value: frame2 < frame10."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


class FrameSource:
    """``for frame in FrameSource(path, FrameRange(...))``: the chosen frames of a video file or a
    folder of images. ``fps``: the source's frame rate; ``count``: its frames (a video's container
    may not know: 0); ``size``: (H, W) of its frames."""

    def __init__(self, path: str | Path, frames: FrameRange | None = None):
        self.path, self.range = Path(path), frames or FrameRange()
        if not self.path.exists():
            raise VideoError(f"{self.path}: no such file or folder")
        if self.path.is_dir():
            self.files = sorted((p for p in self.path.iterdir() if p.is_file() and not p.name.startswith(".")),
                                key=lambda p: natural_key(p.name))
            if not self.files:
                raise VideoError(f"{self.path}: an empty folder (a folder holds one image per frame)")
            self.fps, self.count = self.range.folder_fps, len(self.files)
            self.size = self._first_size()
        else:
            self.files = None
            cap = self._open()
            fps = cap.get(cv2.CAP_PROP_FPS)
            self.fps = fps if math.isfinite(fps) and fps > 0 else FOLDER_FPS
            self.count = max(int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), 0)
            self.size = (int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)), int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)))
            cap.release()

    def _open(self) -> cv2.VideoCapture:
        cap = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG)
        if not cap.isOpened():
            raise VideoError(f"{self.path}: not a video OpenCV can read (mp4, avi, mov, webm, mkv), nor a folder")
        return cap

    def _first_size(self) -> tuple[int, int]:
        for f in self.files:
            try:
                return load_image(f).shape[:2]
            except ImageError:
                continue
        raise VideoError(f"{self.path}: none of its {len(self.files)} files is an image Pillow can read")

    def wanted(self, index: int) -> bool:
        """Whether source frame ``index`` is in the range, before the ``fps`` thinning."""
        t = index / self.fps
        r = self.range
        return t >= r.start - 1e-9 and (r.end is None or t < r.end - 1e-9) and \
            (index - math.ceil(r.start * self.fps - 1e-9)) % r.every == 0

    def __iter__(self) -> Iterator[Frame]:
        last_slot = None
        for index, read in self._source():
            t = index / self.fps
            if self.range.end is not None and t >= self.range.end - 1e-9:
                return
            if not self.wanted(index):
                continue
            if self.range.fps is not None:  # the first frame of each 1/fps interval from the start
                slot = math.floor((t - self.range.start) * self.range.fps + 1e-9)
                if slot == last_slot:
                    continue
                last_slot = slot
            rgb, error = read()
            yield Frame(index, t, rgb, error)

    def _source(self) -> Iterator[tuple[int, object]]:
        """(index, read) per source frame; ``read()`` -> (rgb or None, error), called only for the
        frames kept (a video's skipped frames are grabbed, not converted)."""
        if self.files is not None:
            for index, f in enumerate(self.files):
                yield index, lambda f=f: self._read_file(f)
            return
        cap = self._open()
        try:
            index, bad = 0, 0
            while True:
                if not cap.grab():
                    bad += 1  # unreadable, or the end: said only if a readable frame follows
                    if bad > MAX_BAD_IN_A_ROW:
                        return
                    continue
                for _ in range(bad):
                    yield index, lambda: (None, "the decoder could not read this frame")
                    index += 1
                bad = 0
                yield index, lambda: self._retrieve(cap)
                index += 1
        finally:
            cap.release()

    def _retrieve(self, cap: cv2.VideoCapture) -> tuple[np.ndarray | None, str]:
        ok, bgr = cap.retrieve()
        if not ok or bgr is None:
            return None, "the decoder could not convert this frame"
        return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)), ""

    def _read_file(self, f: Path) -> tuple[np.ndarray | None, str]:
        try:
            rgb = load_image(f)
        except ImageError as e:
            return None, str(e)
        if rgb.shape[:2] != self.size:
            return None, f"{f.name}: {rgb.shape[1]}x{rgb.shape[0]}, not the first frame's {self.size[1]}x{self.size[0]}"
        return rgb, ""
