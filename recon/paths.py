"""Where recon keeps built artefacts (body-model export, retargeted mocap)."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent


def cache_dir() -> Path:
    """$RECON_CACHE_DIR, else ~/.cache/recon. Created on first use."""
    d = Path(os.environ.get("RECON_CACHE_DIR", Path.home() / ".cache" / "recon"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def shared_dir() -> Path:
    """$RECON_SHARED_DIR, else ../shared beside the repository (mocap data, papers)."""
    return Path(os.environ.get("RECON_SHARED_DIR", REPO_ROOT.parent / "shared"))


def load_checkpoint(path: str | Path, trained_by: str) -> dict:
    """``torch.load(path, weights_only=True)`` on the CPU; a missing file names the command that makes it."""
    import torch

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"weights {path} not found: train them with `{trained_by}`")
    return torch.load(path, map_location="cpu", weights_only=True)


def atomic_write(path: Path, write) -> None:
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


def write_image(path: Path, rgb) -> None:
    """Atomically write an (H, W, 3) RGB uint8 image; the format follows the suffix."""
    import cv2

    def write(tmp):
        if not cv2.imwrite(tmp, rgb[..., ::-1]):
            raise OSError(f"cannot write image {path}")

    atomic_write(path, write)
