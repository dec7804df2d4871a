"""Wall-clock timing for benchmarks and latency tables: median of repeats after a warm-up."""
from __future__ import annotations

import statistics
import time


def median_ms(fn, repeats: int = 20, warmup: int = 1) -> float:
    """Median wall time of ``fn()`` in milliseconds."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1000 * statistics.median(times)
