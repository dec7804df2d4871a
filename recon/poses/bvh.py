"""BVH reader: hierarchy + motion -> SourceMotion (world positions and frames); the writer is
``recon.export.bvh``."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from recon.errors import ReconError
from recon.poses.motion import SourceMotion, forward_kinematics


class BVHError(ReconError):
    """The file is not a readable BVH motion; the message says where."""


def _parse_hierarchy(tokens: list[str]):
    names, parents, offsets, channels = [], [], [], []
    stack: list[int] = []
    i = 0
    while i < len(tokens):
        t = tokens[i]
        if t in ("ROOT", "JOINT"):
            names.append(tokens[i + 1])
            parents.append(stack[-1] if stack else -1)
            offsets.append([0.0, 0.0, 0.0])
            channels.append([])
            i += 2
        elif t == "End":  # End Site: a leaf node named after its parent
            names.append(names[stack[-1]] + "_end")
            parents.append(stack[-1])
            offsets.append([0.0, 0.0, 0.0])
            channels.append([])
            i += 2
        elif t == "{":
            stack.append(len(names) - 1)
            i += 1
        elif t == "}":
            stack.pop()
            i += 1
        elif t == "OFFSET":
            offsets[-1] = [float(v) for v in tokens[i + 1:i + 4]]
            i += 4
        elif t == "CHANNELS":
            n = int(tokens[i + 1])
            channels[-1] = tokens[i + 2:i + 2 + n]
            i += 2 + n
        elif t == "MOTION":
            return names, parents, np.array(offsets, dtype=np.float64), channels, i + 1
        else:
            i += 1
    raise BVHError("no MOTION section")


def read_bvh(path: str | Path, fps: float | None = None) -> SourceMotion:
    """Parse a BVH file. ``fps`` overrides the header's frame time (some headers are wrong)."""
    path = Path(path)
    text = path.read_text(errors="replace")
    head, sep, motion = text.partition("MOTION")
    if not sep or "HIERARCHY" not in head:
        raise BVHError(f"{path}: not a BVH file (no HIERARCHY/MOTION)")
    names, parents, offsets, channels, _ = _parse_hierarchy(head.split() + ["MOTION"])
    lines = motion.strip().splitlines()
    try:
        n_frames = int(lines[0].split(":")[1])
        frame_time = float(lines[1].split(":")[1])
        data = np.array([[float(v) for v in ln.split()] for ln in lines[2:2 + n_frames] if ln.strip()])
    except (IndexError, ValueError) as e:
        raise BVHError(f"{path}: malformed MOTION section ({e})") from None
    n_ch = sum(len(c) for c in channels)
    if data.ndim != 2 or data.shape[1] != n_ch:
        raise BVHError(f"{path}: frames have {data.shape[-1]} values, hierarchy declares {n_ch}")

    f, n = data.shape[0], len(names)
    local_rot = np.broadcast_to(np.eye(3), (f, n, 3, 3)).copy()
    local_pos = np.full((f, n, 3), np.nan)
    root_pos = np.zeros((f, 3))
    col = 0
    for k, chans in enumerate(channels):
        rot_axes, rot_cols = "", []
        for c in chans:
            kind = c[1:].lower()
            if kind == "position":
                if np.isnan(local_pos[0, k, 0]):
                    local_pos[:, k] = 0.0
                local_pos[:, k, "XYZ".index(c[0].upper())] = data[:, col]
            elif kind == "rotation":
                rot_axes += c[0].upper()
                rot_cols.append(col)
            col += 1
        if rot_axes:  # BVH: intrinsic rotations in channel order
            local_rot[:, k] = Rotation.from_euler(rot_axes, data[:, rot_cols], degrees=True).as_matrix()
        if parents[k] < 0:
            root_pos = offsets[k] + (0 if np.isnan(local_pos[0, k, 0]) else local_pos[:, k])
    pos, rot = forward_kinematics(parents, offsets, local_rot, root_pos, local_pos)
    rest_pos, rest_rot = forward_kinematics(parents, offsets, np.eye(3)[None, None].repeat(n, 1),
                                            offsets[:1].copy())
    return SourceMotion(names, parents, pos, rot, rest_pos[0], rest_rot[0],
                        fps if fps else 1.0 / frame_time)
