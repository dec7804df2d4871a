"""Pose and shape error metrics (millimetres in, millimetres out is up to the caller).

MPJPE protocol 1: mean joint distance after aligning the roots (pelvis);
protocol 2 (PA-MPJPE): after a similarity Procrustes alignment per sample;
PVE: mean per-vertex distance after root alignment. Per-group means follow thesis Table 2.1.
"""
from __future__ import annotations

import roma
import torch

from recon.body import skeleton


def _check(pred: torch.Tensor, gt: torch.Tensor) -> None:
    if pred.shape != gt.shape or pred.ndim != 3 or pred.shape[-1] != 3:
        raise ValueError(f"pred and gt must both be (B, N, 3); got {tuple(pred.shape)} and {tuple(gt.shape)}")


def per_point_error(pred: torch.Tensor, gt: torch.Tensor, root: int | None = 0) -> torch.Tensor:
    """(B, N) distances after subtracting point ``root`` from both (None: no alignment)."""
    _check(pred, gt)
    if root is not None:
        pred, gt = pred - pred[:, root:root + 1], gt - gt[:, root:root + 1]
    return (pred - gt).norm(dim=-1)


def similarity_transform(pred: torch.Tensor, gt: torch.Tensor):
    """Per-sample (scale (B,), rotation (B,3,3), translation (B,3)) best mapping pred onto gt."""
    _check(pred, gt)
    r, t, s = roma.rigid_points_registration(pred, gt, compute_scaling=True)
    return s, r, t


def procrustes_align(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """Similarity-align ``pred`` onto ``gt`` per sample (rotation, uniform scale, translation)."""
    s, r, t = similarity_transform(pred, gt)
    return s[:, None, None] * (pred @ r.transpose(-1, -2)) + t[:, None]


def mpjpe(pred, gt, root: int = 0) -> torch.Tensor:
    return per_point_error(pred, gt, root).mean()


def pa_mpjpe(pred, gt) -> torch.Tensor:
    return per_point_error(procrustes_align(pred, gt), gt, None).mean()


def group_errors(joint_err: torch.Tensor) -> dict[str, float]:
    """Mean error per joint group of Table 2.1 from (B, 24) per-joint errors."""
    idx = {n: i for i, n in enumerate(skeleton.JOINT_NAMES)}
    return {g: float(joint_err[:, [idx[n] for n in names]].mean()) for g, names in skeleton.JOINT_GROUPS.items()}


def bone_length_error(pred: torch.Tensor, gt: torch.Tensor, per_sample: bool = False) -> torch.Tensor:
    """Mean absolute bone-length difference over the 23 bones: a scalar, or (B,) per sample."""
    par = list(skeleton.JOINT_PARENTS[1:])
    lp = (pred[:, 1:24] - pred[:, par]).norm(dim=-1)
    lg = (gt[:, 1:24] - gt[:, par]).norm(dim=-1)
    err = (lp - lg).abs().mean(dim=1)
    return err if per_sample else err.mean()


# Temporal metrics of a sequence (T, N, 3), as VIBE/TCMR report them.

def acceleration(x: torch.Tensor) -> torch.Tensor:
    """(T-2, N, 3) second differences in time (per frame squared)."""
    if x.ndim != 3 or x.shape[0] < 3:
        raise ValueError(f"expected a sequence (T >= 3, N, 3), got {tuple(x.shape)}")
    return x[2:] - 2 * x[1:-1] + x[:-2]


def acceleration_error(pred: torch.Tensor, gt: torch.Tensor, root: int | None = 0) -> torch.Tensor:
    """Mean distance between predicted and true accelerations of the points (VIBE's "accel
    error"), after subtracting point ``root`` in every frame (None: as they are)."""
    _check(pred, gt)
    if root is not None:
        pred, gt = pred - pred[:, root:root + 1], gt - gt[:, root:root + 1]
    return (acceleration(pred) - acceleration(gt)).norm(dim=-1).mean()


def jitter(x: torch.Tensor, root: int | None = 0) -> torch.Tensor:
    """Mean magnitude of the third differences in time (jerk, per frame cubed) of root-relative points."""
    if root is not None:
        x = x - x[:, root:root + 1]
    a = acceleration(x)
    return (a[1:] - a[:-1]).norm(dim=-1).mean()


def foot_skating(pred_feet: torch.Tensor, planted: torch.Tensor) -> torch.Tensor:
    """Mean distance a foot point moves between consecutive frames where it is planted in the
    ground truth: ``pred_feet`` (T, F, 3) in a world frame (a static camera's), ``planted`` (T, F)
    bool; NaN when nothing is planted."""
    both = planted[1:] & planted[:-1]
    step = (pred_feet[1:] - pred_feet[:-1]).norm(dim=-1)
    return step[both].mean() if both.any() else torch.tensor(float("nan"))


def planted_feet(feet: torch.Tensor, height: float = 0.05, speed: float = 0.02) -> torch.Tensor:
    """(..., T, F) bool: foot points of ``feet`` (..., T, F, 3; a world frame, +Y up, metres) within
    ``height`` of their lowest over the T frames and moving under ``speed`` a frame (the first frame
    takes the second's speed): where a foot counts as planted for ``foot_skating``."""
    low = feet[..., 1] - feet[..., 1].amin(-2, keepdim=True) < height
    step = (feet[..., 1:, :, :] - feet[..., :-1, :, :]).norm(dim=-1)
    step = torch.cat([step[..., :1, :], step], -2)
    return low & (step < speed)


# World-grounded metrics of a person's global motion (T, N, 3) in one world (or static-camera)
# frame, as WHAM and GVHMR report them: chunks of ``WORLD_CHUNK`` frames, similarity-aligned to the
# truth on the whole chunk (WA-MPJPE) or on its first two frames only (W-MPJPE, which lets drift
# show); the root trajectory rigidly aligned, its error in % of the distance the truth travelled.

WORLD_CHUNK = 100  # frames per chunk (WHAM's and GVHMR's evaluation)


def _chunks(t: int, size: int) -> list[slice]:
    return [slice(a, min(a + size, t)) for a in range(0, t, size)]


def _sequence_check(pred: torch.Tensor, gt: torch.Tensor) -> None:
    if pred.shape != gt.shape or pred.ndim != 3 or pred.shape[-1] != 3:
        raise ValueError(f"pred and gt must both be sequences (T, N, 3); got {tuple(pred.shape)} and {tuple(gt.shape)}")


def _aligned(pred: torch.Tensor, gt: torch.Tensor, on: slice, scale: bool = True) -> torch.Tensor:
    """``pred`` (T, N, 3) mapped by the similarity (rigid without ``scale``) that best maps its
    frames ``on`` onto the truth's."""
    found = roma.rigid_points_registration(pred[on].reshape(1, -1, 3), gt[on].reshape(1, -1, 3),
                                           compute_scaling=scale)
    r, t, s = found if scale else (*found, torch.ones(1, dtype=pred.dtype))
    return s[0] * pred @ r[0].T + t[0]


def wa_mpjpe(pred: torch.Tensor, gt: torch.Tensor, chunk: int = WORLD_CHUNK) -> torch.Tensor:
    """(T,) per-frame mean joint error after aligning each chunk as a whole (similarity)."""
    _sequence_check(pred, gt)
    return torch.cat([(_aligned(pred[c], gt[c], slice(None)) - gt[c]).norm(dim=-1).mean(1)
                      for c in _chunks(len(pred), chunk)])


def w_mpjpe(pred: torch.Tensor, gt: torch.Tensor, chunk: int = WORLD_CHUNK) -> torch.Tensor:
    """(T,) per-frame mean joint error after aligning each chunk on its first two frames
    (similarity); chunks of fewer than two frames are aligned on what they have."""
    _sequence_check(pred, gt)
    return torch.cat([(_aligned(pred[c], gt[c], slice(0, 2)) - gt[c]).norm(dim=-1).mean(1)
                      for c in _chunks(len(pred), chunk)])


def root_trajectory_error(pred_root: torch.Tensor, gt_root: torch.Tensor) -> torch.Tensor:
    """Mean distance (T, 3) between the rigidly aligned predicted root path and the true one, as
    a fraction of the length of the true path (GVHMR's RTE, x 100 for %)."""
    if pred_root.shape != gt_root.shape or pred_root.ndim != 2:
        raise ValueError(f"expected two root paths (T, 3); got {tuple(pred_root.shape)} and {tuple(gt_root.shape)}")
    aligned = _aligned(pred_root[:, None], gt_root[:, None], slice(None), scale=False)[:, 0]
    length = (gt_root[1:] - gt_root[:-1]).norm(dim=-1).sum()
    return (aligned - gt_root).norm(dim=-1).mean() / length
