"""Where recon keeps its files: bundled data, built artefacts (cache), the optional shared data,
and atomic writes so that readers never see a partial file."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

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
