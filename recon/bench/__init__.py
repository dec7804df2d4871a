"""Benchmark runner: methods predict from a synthetic sample's image (and intrinsics); the
runner scores MPJPE P1/P2, per-group errors, landmark error, PVE and silhouette IoU."""
