"""Benchmark methods (baselines and our pipelines) and the runner that scores them on the
synthetic benchmarks: MPJPE P1/P2, per-group errors, landmark error, PVE, silhouette IoU."""
