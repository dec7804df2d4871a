"""Synthetic benchmark generation: a moderngl rasteriser (RGB, part labels, depth), the
SURREAL-like scene sampler and sharded, resumable, reproducible storage with fixed benchmarks."""
