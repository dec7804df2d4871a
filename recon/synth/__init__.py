"""Synthetic benchmark generation (drawn by ``recon.render``): the
SURREAL-like scene sampler and sharded, resumable, reproducible storage with fixed benchmarks."""
