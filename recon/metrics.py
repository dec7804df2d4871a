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
