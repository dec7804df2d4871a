"""A source skeleton's motion in world space, the common form of every mocap parser."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SourceMotion:
    """Posed source skeleton. Node k sits at ``positions[:, k]``; ``rotations[:, k]`` is the
    world frame of the segment leaving node k (BVH joint frame / ASF bone frame).

    ``rest_*`` hold the same for the skeleton's zero-motion pose (all channels 0).
    Units and axes are the file's own; recon.poses.retarget normalises them.
    """

    names: list[str]
    parents: list[int]
    positions: np.ndarray  # (F, N, 3)
    rotations: np.ndarray  # (F, N, 3, 3)
    rest_positions: np.ndarray  # (N, 3)
    rest_rotations: np.ndarray  # (N, 3, 3)
    fps: float

    @property
    def num_frames(self) -> int:
        return int(self.positions.shape[0])

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"source skeleton has no joint {name!r}") from None

    def subset(self, frames: np.ndarray) -> SourceMotion:
        return SourceMotion(self.names, self.parents, self.positions[frames], self.rotations[frames],
                            self.rest_positions, self.rest_rotations, self.fps)


def forward_kinematics(parents: list[int], offsets: np.ndarray, local_rot: np.ndarray,
                       root_pos: np.ndarray, local_pos: np.ndarray | None = None):
    """World positions/frames of a skeleton: node k at parent pos + parent frame @ offset.

    local_rot (F, N, 3, 3); offsets (N, 3); root_pos (F, 3); local_pos (F, N, 3) optional
    per-frame offsets (BVH position channels on non-root joints), NaN where absent.
    """
    f, n = local_rot.shape[:2]
    pos = np.zeros((f, n, 3))
    rot = np.zeros((f, n, 3, 3))
    for k, p in enumerate(parents):
        if p < 0:
            pos[:, k] = root_pos
            rot[:, k] = local_rot[:, k]
            continue
        off = np.broadcast_to(offsets[k], (f, 3))
        if local_pos is not None and not np.isnan(local_pos[0, k, 0]):
            off = local_pos[:, k]
        pos[:, k] = pos[:, p] + np.einsum("fij,fj->fi", rot[:, p], off)
        rot[:, k] = rot[:, p] @ local_rot[:, k]
    return pos, rot


def local_rotations(global_rot: np.ndarray, parents) -> np.ndarray:
    """(F, J, 3, 3) global joint frames -> rotations relative to the parent's (the root's kept)."""
    p = np.asarray(parents)
    child = p >= 0
    local = global_rot.copy()
    local[:, child] = np.swapaxes(global_rot[:, p[child]], -1, -2) @ global_rot[:, child]
    return local
