"""Result files: numbers in JSON, the same numbers as Markdown tables beside them.

Every evaluation writes ``<name>.json`` (what code and tests read back) and ``<name>.md``
(what people read), both through ``write`` and both atomically; tables come from ``table``
(tabulate's GitHub format), so every results file looks the same.
"""
from __future__ import annotations

import datetime
import importlib
import json
import os
import platform
from collections.abc import Sequence
from pathlib import Path

import torch
from tabulate import tabulate

from recon.paths import write_text

RESULTS = Path("eval/results")  # where evaluations write by default (relative to the working folder)
# how far a committed check value may move between CPUs unless its check says otherwise: float noise
# (the last bits of float kernels) through networks without a discrete decision
CHECK_TOLERANCE = {"rtol": 1e-3, "atol": 1e-6}


def table(rows: Sequence[Sequence], headers: Sequence[str], floatfmt: str | Sequence[str] = ".1f") -> str:
    """A Markdown (GitHub) table. Floats are formatted with ``floatfmt`` (one format, or one per
    column), None prints as "-", anything else as ``str`` (text is never re-parsed as a number)."""
    fmts = [floatfmt] * len(headers) if isinstance(floatfmt, str) else list(floatfmt)

    def cell(v, fmt):
        if v is None:
            return "-"
        return format(v, fmt) if isinstance(v, float) else str(v)

    body = [[cell(v, f) for v, f in zip(row, fmts, strict=True)] for row in rows]
    return tabulate(body, headers=list(headers), tablefmt="github", disable_numparse=True)


def write(stem: str | Path, data, markdown: str) -> Path:
    """``stem.json`` (``data``) and ``stem.md`` (``markdown``), atomically; returns the .md path."""
    stem = Path(stem)
    write_text(stem.with_suffix(".json"), json.dumps(data, indent=1) + "\n")
    return write_text(stem.with_suffix(".md"), markdown.rstrip("\n") + "\n")


def read(stem: str | Path):
    """The JSON of a results file (``stem`` with or without a suffix)."""
    return json.loads(Path(stem).with_suffix(".json").read_text())


def recompute_check(stem: str | Path) -> tuple:
    """(the committed check slice of a results file, the same slice recomputed now, its tolerance):
    each results JSON's ``check`` names the function and arguments that compute its values, and may
    say how far they may move between CPUs (``tolerance``: rtol, atol; else ``CHECK_TOLERANCE``)."""
    check = read(stem)["check"]
    module, name = check["function"].split(":")
    actual = getattr(importlib.import_module(module), name)(**check["kwargs"])
    return check["values"], json.loads(json.dumps(actual)), {**CHECK_TOLERANCE, **check.get("tolerance", {})}


def record_check(stem: str | Path) -> dict:
    """Recomputes the check slice of a results file and stores it as its ``values`` (after a change
    that moves them by float noise only), the results themselves untouched; returns the values."""
    data = read(stem)
    _, actual, _ = recompute_check(stem)
    data["check"]["values"] = actual
    write_text(Path(stem).with_suffix(".json"), json.dumps(data, indent=1) + "\n")
    return actual


def machine() -> dict:
    """Where and when a measurement ran (benchmarks record it beside their numbers)."""
    cpu = platform.processor()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"date": datetime.datetime.now().isoformat(timespec="minutes"), "cpu": cpu, "cores": os.cpu_count(),
            "torch_threads": torch.get_num_threads(), "torch": torch.__version__}


def describe(m: dict) -> str:
    """``machine()`` as one line of prose for a results page."""
    return f"{m['date']}, {m['cpu']} ({m['cores']} cores), {m['torch_threads']} torch thread(s), torch {m['torch']}"
