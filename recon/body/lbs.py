"""Forward kinematics and linear blend skinning shared by every body model backend."""
from __future__ import annotations

import functools

import roma
import torch


def as_rotmats(pose: torch.Tensor, num_joints: int) -> torch.Tensor:
    """Accept (B, J, 3) axis-angle, (B, J, 3, 3) matrices or (B, J*3) and return (B, J, 3, 3).

    Raises ValueError with the expected shapes on anything else, and on NaN/inf values.
    """
    if not torch.is_tensor(pose):
        raise TypeError(f"pose must be a torch.Tensor, got {type(pose).__name__}")
    if pose.ndim == 2 and pose.shape[1] == num_joints * 3:
        pose = pose.view(pose.shape[0], num_joints, 3)
    if pose.ndim == 3 and pose.shape[1:] == (num_joints, 3):
        mats = roma.rotvec_to_rotmat(pose)
    elif pose.ndim == 4 and pose.shape[1:] == (num_joints, 3, 3):
        mats = pose
    else:
        raise ValueError(
            f"pose must have shape (B, {num_joints}, 3) axis-angle, (B, {num_joints * 3}) or "
            f"(B, {num_joints}, 3, 3) rotation matrices; got {tuple(pose.shape)}"
        )
    if not torch.isfinite(pose).all():
        raise ValueError("pose contains NaN or infinite values")
    return mats


def forward_kinematics(
    rotmats: torch.Tensor, rest_joints: torch.Tensor, parents: tuple[int, ...]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Pose a skeleton.

    Args:
        rotmats: (B, J, 3, 3) local rotations in world-aligned rest axes.
        rest_joints: (B, J, 3) joint positions in the rest pose.
        parents: parent index per joint, -1 for the root; parents precede children.
    Returns:
        global_rotmats (B, J, 3, 3), posed joints (B, J, 3) with the root at its rest place,
        skinning transforms (B, J, 3, 4) mapping rest-pose points to posed points.

    Joints are posed one tree level at a time (all joints at the same depth in one batched
    matmul): 9 steps instead of 24 for the body skeleton, which is what a fitting loop pays for
    at batch 1. ``forward_kinematics_sequential`` is the joint-by-joint reference.
    """
    levels, slot, order = _levels(tuple(parents))
    offsets = rest_joints - rest_joints[:, [max(p, 0) for p in parents]]
    rot_l: list[torch.Tensor] = [rotmats[:, levels[0]]]
    pos_l: list[torch.Tensor] = [rest_joints[:, levels[0]]]
    for lv in range(1, len(levels)):
        js = levels[lv]
        up = [slot[parents[j]] for j in js]  # the parents' places in the previous level
        prot = rot_l[-1][:, up]
        rot_l.append(prot @ rotmats[:, js])
        pos_l.append(pos_l[-1][:, up] + (prot @ offsets[:, js].unsqueeze(-1)).squeeze(-1))
    g_rot = torch.cat(rot_l, dim=1)[:, order]
    g_pos = torch.cat(pos_l, dim=1)[:, order]
    trans = g_pos - (g_rot @ rest_joints.unsqueeze(-1)).squeeze(-1)
    transforms = torch.cat([g_rot, trans.unsqueeze(-1)], dim=-1)
    return g_rot, g_pos, transforms


@functools.lru_cache(maxsize=16)
def _levels(parents: tuple[int, ...]) -> tuple[list[list[int]], list[int], list[int]]:
    """Joints grouped by depth; each joint's index within its level; and the permutation from
    the levels' concatenation back to joint order."""
    depth: list[int] = []
    for p in parents:
        depth.append(0 if p < 0 else depth[p] + 1)
    levels = [[j for j, d in enumerate(depth) if d == lv] for lv in range(max(depth) + 1)]
    slot = [0] * len(parents)
    for js in levels:
        for i, j in enumerate(js):
            slot[j] = i
    flat = [j for js in levels for j in js]
    order = [flat.index(j) for j in range(len(parents))]
    return levels, slot, order


def forward_kinematics_sequential(
    rotmats: torch.Tensor, rest_joints: torch.Tensor, parents: tuple[int, ...]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``forward_kinematics`` one joint at a time (the textbook recursion; reference for tests)."""
    rots: list[torch.Tensor] = []
    pos: list[torch.Tensor] = []
    for j, p in enumerate(parents):
        if p < 0:
            rots.append(rotmats[:, j])
            pos.append(rest_joints[:, j])
        else:
            rots.append(rots[p] @ rotmats[:, j])
            offset = (rest_joints[:, j] - rest_joints[:, p]).unsqueeze(-1)
            pos.append(pos[p] + (rots[p] @ offset).squeeze(-1))
    g_rot = torch.stack(rots, dim=1)
    g_pos = torch.stack(pos, dim=1)
    trans = g_pos - (g_rot @ rest_joints.unsqueeze(-1)).squeeze(-1)
    transforms = torch.cat([g_rot, trans.unsqueeze(-1)], dim=-1)
    return g_rot, g_pos, transforms


def skin(rest_vertices: torch.Tensor, weights: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
    """Linear blend skinning.

    Args:
        rest_vertices: (B, V, 3) or (V, 3).
        weights: (V, J) skinning weights (rows sum to one).
        transforms: (B, J, 3, 4) rest-to-posed transforms.
    """
    b, j = transforms.shape[:2]
    # Blend the 12 affine coefficients per vertex with one matmul: (V, J) @ (B, J, 12).
    blended = torch.matmul(weights, transforms.reshape(b, j, 12)).view(b, -1, 3, 4)
    if rest_vertices.ndim == 2:
        rest_vertices = rest_vertices.unsqueeze(0)
    return (blended[..., :3] @ rest_vertices.unsqueeze(-1)).squeeze(-1) + blended[..., 3]


def blend_transforms(weights: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
    """Each vertex's blended transform (B, N, 3, 4) from blend weights (N, 24) and the joint
    transforms (B, 24, 3, 4). One matmul: faster than an einsum over joints for batches."""
    b = transforms.shape[0]
    return (weights @ transforms.reshape(b, -1, 12)).view(b, -1, 3, 4)


def mirror_rotmats(rotmats: torch.Tensor, mirror: tuple[int, ...]) -> torch.Tensor:
    """Left/right flip of a pose: swap mirrored joints and reflect each rotation across X=0."""
    m = torch.tensor([-1.0, 1.0, 1.0], dtype=rotmats.dtype, device=rotmats.device)
    flipped = rotmats[:, list(mirror)]
    return flipped * m.view(1, 1, 3, 1) * m.view(1, 1, 1, 3)
