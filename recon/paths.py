"""Where recon keeps its files: bundled data, built artefacts (cache), the optional shared data,
and atomic writes so that readers never see a partial file."""
from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
import torch

from recon.errors import MissingFile

REPO_ROOT = Path(__file__).resolve().parent.parent
DATA_DIR = Path(__file__).resolve().parent / "data"  # shipped with the package: example photos, pose set


def cache_dir() -> Path:
    """$RECON_CACHE_DIR, else ~/.cache/recon. Created on first use."""
    d = Path(os.environ.get("RECON_CACHE_DIR", Path.home() / ".cache" / "recon"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def shared_dir() -> Path:
    """$RECON_SHARED_DIR, else ../shared beside the repository: the raw mocap clips that
    `recon poses build` retargets. Nothing else needs it."""
    return Path(os.environ.get("RECON_SHARED_DIR", REPO_ROOT.parent / "shared"))


def load_checkpoint(path: str | Path, trained_by: str) -> dict:
    """``torch.load(path, weights_only=True)`` on the CPU; a missing file names the command that makes it."""
    path = Path(path)
    if not path.exists():
        raise MissingFile(f"weights {path} not found: train them with `{trained_by}`")
    return torch.load(path, map_location="cpu", weights_only=True)


def cast_floats(state: dict, dtype: torch.dtype) -> dict:
    """A state dict with its floating tensors in ``dtype`` (weights files: float16 where that
    changes no published number; loading copies them back into float32 parameters)."""
    return {k: v.to(dtype) if torch.is_tensor(v) and v.is_floating_point() else v for k, v in state.items()}


def atomic_write(path: str | Path, write) -> None:
    """Call ``write(tmp_path)`` then rename onto ``path``: readers never see a partial file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    try:
        write(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; final files get the usual mode
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_text(path: str | Path, text: str) -> Path:
    """Atomically write a text file."""
    atomic_write(path, lambda t: Path(t).write_text(text))
    return Path(path)


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


def write_image(path: str | Path, rgb) -> None:
    """Atomically write an (H, W, 3) RGB uint8 image; the format follows the suffix."""

    def write(tmp):
        if not cv2.imwrite(tmp, rgb[..., ::-1]):
            raise OSError(f"cannot write image {path}")

    atomic_write(path, write)
