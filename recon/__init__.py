"""recon: SMPL-free single-image 3D human reconstruction and garment animation.

    >>> import recon
    >>> rec = recon.Reconstructor()                       # MediaPipe + adapter -> SMPLR -> fit
    >>> r = rec(recon.load_image("photo.jpg"))            # recon.Reconstruction, camera frame
    >>> body = recon.body.create()                        # the anny body model
    >>> smplr = recon.SMPLR.load()                        # joints + landmarks -> body

The names below load their subpackage on first use, so ``import recon`` stays light.
"""
from __future__ import annotations

import importlib

from recon.version import __version__ as __version__

_EXPORTS = {
    "Reconstructor": "recon.pipeline", "ReconstructorConfig": "recon.reconstruction",
    "Reconstruction": "recon.reconstruction", "NoPersonFound": "recon.reconstruction", "RunOptions": "recon.run",
    "FitConfig": "recon.fit", "SMPLR": "recon.smplr", "Lifter": "recon.smplr", "load_image": "recon.io",
    "ReconError": "recon.errors",
}


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    if name in ("body", "camera"):
        return importlib.import_module(f"recon.{name}")
    raise AttributeError(f"module 'recon' has no attribute {name!r}")


__all__ = sorted([*_EXPORTS, "body", "camera"])
