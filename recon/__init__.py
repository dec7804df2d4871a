"""recon: SMPL-free single-image 3D human reconstruction and garment animation."""
__version__ = "0.1.0"
