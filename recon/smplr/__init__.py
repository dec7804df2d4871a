"""SMPLR (thesis ch. 2.3): J+ (24 joints + 18 landmarks) -> denoising autoencoder ->
pose network Omega / shape network Psi -> body model. Trained purely on generated 3D data.

>>> from recon.smplr import SMPLR
>>> model = SMPLR.load()                 # shipped weights, anny body
>>> out = model(points)                   # points: (B, 42, 3) metres; mode="2d" lifts 2D input
>>> out.body.vertices, out.rotmats, out.shape
>>> points, root = Lifter.load().lift(uv, K)   # 2D J+ (pixels) + intrinsics -> 3D J+ in the camera
"""
from recon.smplr.lifter import Lifter
from recon.smplr.model import SMPLR, SMPLROutput

__all__ = ["SMPLR", "SMPLROutput", "Lifter"]
