"""SMPLR (thesis ch. 2.3): J+ (24 joints + 18 landmarks) -> denoising autoencoder ->
pose network Omega / shape network Psi -> body model. Trained purely on generated 3D data.

>>> from recon.smplr import SMPLR
>>> model = SMPLR.load()                 # shipped weights, anny body
>>> out = model(points)                   # points: (B, 42, 3) metres; mode="2d" lifts 2D input
>>> out.body.vertices, out.rotmats, out.shape
"""
from recon.smplr.model import SMPLR, SMPLROutput

__all__ = ["SMPLR", "SMPLROutput"]
