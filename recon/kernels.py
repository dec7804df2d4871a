"""The same float kernels on every x86-64 machine. Call ``pin`` before torch and Mesa load.

Libraries pick their SIMD code path by the CPU they run on, and the paths round differently in the
last bits, which a crop search or a person detector can turn into another crop or another
detection. ``pin`` sets the variables that choose one path everywhere (each only if unset, so a
test can ask for another):
- torch's own kernels, oneDNN and MKL: AVX2 (what every x86-64 CPU of the last decade has);
- Mesa's llvmpipe (the synthetic renderer, ``recon.render.raster``): SSE4.1 and 128-bit vectors,
  so no FMA contraction and no AVX-512 code.
MediaPipe's TFLite kernels cannot be pinned: its detections may differ between CPU vendors.
"""
from __future__ import annotations

import os

PINNED = (("ATEN_CPU_CAPABILITY", "avx2"), ("ONEDNN_MAX_CPU_ISA", "AVX2"), ("MKL_CBWR", "AVX2"),
          ("GALLIUM_OVERRIDE_CPU_CAPS", "sse4.1"), ("LP_NATIVE_VECTOR_WIDTH", "128"))


def pin() -> None:
    """Sets the kernel variables (unless already set); torch's work only before torch is imported,
    Mesa's before the first OpenGL context."""
    for var, isa in PINNED:
        os.environ.setdefault(var, isa)

