"""The one timer for benchmarks and speed columns: ``torch.utils.benchmark`` (warm-up, blocks of
calls sized to the run time, the median per call over blocks).

``compare`` times several functions in interleaved rounds, so that this machine's drift over
minutes hits all of them alike: speed claims are ratios measured side by side in one run.
``add_seconds`` keeps a resumable job's total time.
"""
from __future__ import annotations

import json
import statistics
from collections.abc import Callable
from pathlib import Path

import torch
from torch.utils import benchmark

from recon import paths


def median_ms(fn: Callable[[], object], min_run_time: float = 0.2, threads: int | None = None) -> float:
    """Median wall time of one ``fn()`` call in milliseconds, on ``threads`` torch threads
    (default: the current setting; torch.utils.benchmark would otherwise pin it to 1)."""
    timer = benchmark.Timer(stmt="fn()", globals={"fn": fn}, num_threads=threads or torch.get_num_threads())
    return timer.blocked_autorange(min_run_time=min_run_time).median * 1000.0


def frames_per_second(fn, batch: int) -> float:
    """Frames a second of ``fn`` processing ``batch`` frames a call (its median time)."""
    return 1000.0 * batch / median_ms(fn)


def compare(fns: dict[str, Callable[[], object]], rounds: int = 5, min_run_time: float = 0.2,
            threads: int | None = None) -> dict[str, float]:
    """Median ms per call of each function, timed in ``rounds`` interleaved rounds (the median
    over rounds of each round's median)."""
    per: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            per[name].append(median_ms(fn, min_run_time, threads))
    return {name: statistics.median(ms) for name, ms in per.items()}


def add_seconds(path: str | Path, seconds: float, workers: int) -> None:
    """Add ``seconds`` to the total in the JSON file ``path`` (a resumable job's time over its runs),
    with the number of worker processes of the last run; written atomically."""
    path = Path(path)
    done = json.loads(path.read_text()) if path.exists() else {"seconds": 0.0}
    done["seconds"] += seconds
    done["workers"] = workers
    paths.atomic_write(path, lambda t: Path(t).write_text(json.dumps(done)))
