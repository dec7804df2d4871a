"""Images and videos, written atomically: PNG/JPEG (OpenCV), MP4 (H.264 through PyAV where it is
installed, which browsers play; else OpenCV's MPEG-4 part 2) and GIF (Pillow)."""
from __future__ import annotations

from collections.abc import Iterable
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from recon.paths import atomic_write


def write_image(path: str | Path, rgb) -> None:
    """Atomically write an (H, W, 3) RGB uint8 image; the format follows the suffix."""

    def write(tmp):
        if not cv2.imwrite(tmp, rgb[..., ::-1]):
            raise OSError(f"cannot write image {path}")

    atomic_write(path, write)


def write_mp4(path: str | Path, frames: Iterable[np.ndarray], fps: float, size: tuple[int, int],
              quality: int | None = None, browser: bool = False) -> Path:
    """RGB frames of ``size`` (H, W), streamed (a generator is consumed frame by frame) into an MP4,
    atomically. ``browser``: H.264 (PyAV's libx264, which browsers play; odd sizes padded by a
    pixel), else, or where PyAV is missing, OpenCV's MPEG-4 part 2 (``quality`` 0-100). OSError
    where no encoder is there."""
    if browser and h264_available():
        atomic_write(path, lambda tmp: _write_h264(tmp, frames, fps, size))
        return Path(path)

    def write(tmp):
        vw = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*"mp4v"), fps, (size[1], size[0]))
        try:
            if not vw.isOpened():
                raise OSError("OpenCV has no MP4 encoder here")
            if quality is not None:
                vw.set(cv2.VIDEOWRITER_PROP_QUALITY, quality)
            for f in frames:
                vw.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
        finally:
            vw.release()

    atomic_write(path, write)
    return Path(path)


def h264_available() -> bool:
    """Whether PyAV with its libx264 encoder is installed."""
    try:
        import av  # noqa: PLC0415 - looked up when a video is written: `recon --help` stays instant
        av.codec.Codec("libx264", "w")
    except (ImportError, ValueError):  # no PyAV, or a build without libx264 (UnknownCodecError)
        return False
    return True


def _write_h264(tmp: str, frames: Iterable[np.ndarray], fps: float, size: tuple[int, int]) -> None:
    import av  # noqa: PLC0415 - as in h264_available
    h, w = size[0] + size[0] % 2, size[1] + size[1] % 2  # yuv420p needs even sides
    with av.open(tmp, "w", format="mp4", options={"movflags": "+faststart"}) as box:
        stream = box.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
        stream.options = {"crf": "23", "preset": "veryfast"}
        for f in frames:
            if f.shape[:2] != (h, w):
                f = np.pad(f, ((0, h - f.shape[0]), (0, w - f.shape[1]), (0, 0)), mode="edge")
            box.mux(stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="rgb24")))
        box.mux(stream.encode())


def write_video(path: Path, frames: list[np.ndarray], fps: float) -> Path:
    """MP4 (H.264 where PyAV has it, else OpenCV's MPEG-4 part 2) or, for a .gif path or where no
    MP4 encoder is there, GIF. Written atomically; returns the path written."""
    if path.suffix.lower() == ".mp4":
        try:
            return write_mp4(path, frames, fps, frames[0].shape[:2], browser=True)
        except OSError:
            path = path.with_suffix(".gif")
    images = [Image.fromarray(f) for f in frames]
    atomic_write(path, lambda t: images[0].save(t, format="GIF", save_all=True, append_images=images[1:],
                                                duration=round(1000 / fps), loop=0))
    return path
