"""recon: SMPL-free single-image 3D human reconstruction and garment animation.

Entry points (imported lazily, so ``import recon`` stays light):
``recon.body.create()`` (body models), ``recon.SMPLR.load()`` (joints + landmarks -> mesh).
"""
__version__ = "0.1.0"


def __getattr__(name):
    if name == "SMPLR":
        from recon.smplr import SMPLR

        return SMPLR
    raise AttributeError(f"module 'recon' has no attribute {name!r}")
