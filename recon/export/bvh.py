"""BVH writer: a skeleton's motion (rest joints, local rotations, root positions) as a BVH file
that Blender, MotionBuilder and most retargeting tools read (the reader is ``recon.poses.bvh``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from recon.paths import write_text


def write_bvh(path: str | Path, names: list[str], parents: list[int], rest_joints: np.ndarray, rotmats: np.ndarray,
              root_positions: np.ndarray, fps: float = 30.0, unit: float = 100.0) -> Path:
    """Write a skeleton's motion as BVH (atomically), e.g. ``recon run``'s pose on the body's skeleton.

    Args:
        rest_joints: (J, 3) joint positions of the rest pose, metres (the offsets come from them).
        rotmats: (F, J, 3, 3) per-joint rotations relative to the parent in world-aligned rest axes
            (recon's convention, also BVH's when the rest axes are the world's).
        root_positions: (F, 3) where the root joint is, metres.
        unit: file units per metre (100: centimetres, what most BVH tools expect).
    Channels: the root's position and every joint's rotation as intrinsic Z, X, Y Euler angles."""
    rest = np.asarray(rest_joints, np.float64)
    rot = np.asarray(rotmats, np.float64)
    if rot.ndim != 4 or rot.shape[1:] != (len(names), 3, 3) or len(root_positions) != len(rot):
        raise ValueError(f"rotmats must be (F, {len(names)}, 3, 3) with one root position per frame")
    children: dict[int, list[int]] = {}
    for k, p in enumerate(parents):
        children.setdefault(p, []).append(k)
    lines = ["HIERARCHY"]

    def joint(k: int, depth: int) -> None:
        pad = "  " * depth
        off = (rest[k] - rest[parents[k]]) * unit if parents[k] >= 0 else np.zeros(3)
        lines.append(f"{pad}{'ROOT' if parents[k] < 0 else 'JOINT'} {names[k]}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}")
        pos = "Xposition Yposition Zposition " if parents[k] < 0 else ""
        lines.append(f"{pad}  CHANNELS {6 if parents[k] < 0 else 3} {pos}Zrotation Xrotation Yrotation")
        for c in children.get(k, []):
            joint(c, depth + 1)
        if k not in children:  # a leaf: BVH wants an end site
            lines.extend([f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET 0.000000 {0.05 * unit:.6f} 0.000000",
                          pad + "  }"])
        lines.append(pad + "}")

    order: list[int] = []

    def visit(k: int) -> None:  # channel order = depth-first order of the hierarchy
        order.append(k)
        for c in children.get(k, []):
            visit(c)

    for root in children[-1]:
        joint(root, 0)
        visit(root)
    euler = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_euler("ZXY", degrees=True).reshape(len(rot), -1, 3)
    lines += ["MOTION", f"Frames: {len(rot)}", f"Frame Time: {1.0 / fps:.6f}"]
    root_pos = np.asarray(root_positions, np.float64) * unit
    for f in range(len(rot)):
        vals = [*root_pos[f]] + [v for k in order for v in euler[f, k]]
        lines.append(" ".join(f"{v:.6f}" for v in vals))
    return write_text(Path(path), "\n".join(lines) + "\n")
