"""SMPLR: denoising autoencoder and pose/shape MLPs (thesis ch. 2.3). Not built yet: see issue 4."""
