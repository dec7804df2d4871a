"""The same float kernels on every x86 machine, and which CPU vendor ran them. Import before torch.

The committed check slices (tests/test_results.py) hold outputs of networks whose last bits differ
between AVX2 and AVX-512 kernels, which a crop search or a person detector can turn into another
crop or another detection. ``pin`` makes torch, oneDNN and MKL use AVX2 kernels; even so, AMD and
Intel CPUs compute some slices apart (MediaPipe's TFLite kernels, measured: 25 % on one 8-image
slice), so a check may hold values per ``vendor`` (``recon.report.recompute_check``).
"""
from __future__ import annotations

import os
import platform

PINNED = (("ATEN_CPU_CAPABILITY", "avx2"), ("ONEDNN_MAX_CPU_ISA", "AVX2"), ("MKL_CBWR", "AVX2"))


def pin() -> None:
    """Sets the kernel variables (unless already set); works only before torch is imported."""
    for var, isa in PINNED:
        os.environ.setdefault(var, isa)


def vendor() -> str:
    """The CPU's vendor id ("GenuineIntel", "AuthenticAMD", ...), else the machine's architecture."""
    try:
        with open("/proc/cpuinfo") as f:
            return next(line.split(":", 1)[1].strip() for line in f if line.startswith("vendor_id"))
    except (OSError, StopIteration):
        return platform.machine()
