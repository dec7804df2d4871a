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
