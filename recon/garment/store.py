"""Where outfit weights live: the shipped presets beside this package, your own garments in the
cache. Every module that reads or writes PBNS or resizer weights asks here."""
from __future__ import annotations

import difflib
from pathlib import Path

from recon import paths
from recon.errors import MissingFile, ReconError
from recon.garment.templates import PRESETS, outfit_name

SHIPPED_DIR = Path(__file__).resolve().parent / "weights"


def user_dir() -> Path:
    """Where outfits trained from your own garment meshes go (``<cache>/garments``)."""
    return paths.cache_dir() / "garments"


def pbns_path(outfit: str) -> Path:
    """PBNS weights of a preset (shipped), of your own garment (by name or mesh path), or a .pt path."""
    if outfit.endswith(".pt"):
        return Path(outfit)
    name = outfit_name(outfit)
    return (SHIPPED_DIR if name in PRESETS else user_dir()) / f"pbns_{name}.pt"


def ncs_path(outfit: str) -> Path:
    """NCS weights (dynamic model) of a preset (shipped) or of your own garment (the cache)."""
    name = outfit_name(outfit)
    return (SHIPPED_DIR if name in PRESETS else user_dir()) / f"ncs_{name}.pt"


def taylor_path(outfit: str) -> Path:
    """The Taylor model (example database) of an outfit: built on this machine by ``recon garment
    train --model taylor`` (tens of MB, not shipped), in the cache for presets and your garments."""
    return user_dir() / f"taylor_{outfit_name(outfit)}.pt"


def author_path(outfit: str) -> Path:
    """The keyframe-authoring model of an outfit (``recon garment train --model author``): built on
    this machine from its own simulations, in the cache (``outfit`` may carry a variant suffix)."""
    return user_dir() / f"author_{outfit}.pt"


def deepsd_path(name: str = "deepsd") -> Path:
    """DeePSD's weights (any outfit, no training per outfit): shipped as ``deepsd.pt``; the
    ablation variants ``recon garment train --model deepsd`` trains beside them go to the cache."""
    return (SHIPPED_DIR if name == "deepsd" else user_dir()) / f"{name}.pt"


def gcvae_path(name: str = "gcvae") -> Path:
    """The GCVAE garment space (``recon garment train --model gcvae``): shipped as ``gcvae.pt``;
    its ablation variants go to the cache."""
    return (SHIPPED_DIR if name == "gcvae" else user_dir()) / f"{name}.pt"


def resizer_path(outfit: str, pbns: str | Path | None = None) -> Path:
    """The resizer of an outfit: shipped for the presets (their templates never change), else
    beside its PBNS weights (``pbns``, default where ``recon garment train`` writes them)."""
    name = outfit_name(outfit)
    if name in PRESETS:
        return SHIPPED_DIR / f"resize_{name}.pt"
    return Path(pbns or pbns_path(name)).parent / f"resize_{name}.pt"


def trained_outfits() -> list[str]:
    """Names of every outfit with PBNS weights: the shipped presets, then your own."""
    found = sorted(p.stem[5:] for p in SHIPPED_DIR.glob("pbns_*.pt"))
    own = user_dir()
    return found + sorted(p.stem[5:] for p in own.glob("pbns_*.pt")) if own.exists() else found


def check_outfit(outfit: str) -> None:
    """Refuse an outfit that is not a preset, a trained garment of yours, a weights file or a
    garment mesh, listing the presets (and the closest one)."""
    if outfit in PRESETS or Path(outfit).is_file() or pbns_path(outfit).exists():
        return
    close = difflib.get_close_matches(outfit, list(PRESETS), n=1)
    hint = f" (did you mean {close[0]}?)" if close else ""
    raise ReconError(f"unknown outfit {outfit!r}{hint}; presets: {', '.join(PRESETS)}; or your own garment mesh "
                     "(.obj, .ply, .glb) trained with `recon garment train --outfit MESH`")


def trained_pbns(outfit: str) -> Path:
    """The PBNS weights of an outfit that must exist (MissingFile names the command that makes them)."""
    check_outfit(outfit)
    path = pbns_path(outfit)
    if not path.exists():
        raise MissingFile(f"no trained outfit {path}: run `recon garment train --outfit {outfit}`")
    return path
