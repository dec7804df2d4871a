"""Surface normals of a mesh in numpy (float64), as the renders, the overlays and the other
domain's clothes shade and push with them."""
from __future__ import annotations

import numpy as np


def vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (V, 3) in float64."""
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for c in range(3):
        np.add.at(n, f[:, c], fn)
    return n / np.maximum(np.sqrt((n * n).sum(1, keepdims=True)), 1e-30)
