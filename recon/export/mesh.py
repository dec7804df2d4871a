"""Meshes as files (trimesh's exporters, written atomically): .obj for a posed body or outfit,
.ply / .glb / .stl for a static mesh; the format follows the suffix. Rigged and animated bodies
are ``recon.export.glb``."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from recon.paths import atomic_write


def write_mesh(path: str | Path, vertices: np.ndarray, faces: np.ndarray) -> Path:
    """Atomically write the mesh (V, 3) / (F, 3) in the format of ``path``'s suffix."""
    mesh = trimesh.Trimesh(np.asarray(vertices), np.asarray(faces), process=False)
    atomic_write(path, lambda t: mesh.export(t, file_type=Path(path).suffix[1:].lower()))
    return Path(path)
