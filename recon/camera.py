"""Pinhole cameras, the two frames recon's 3D points live in, and placing a body in a camera.

Frames (metres):

* **OpenCV camera**: x right, y down, z forward. Every camera-space output is in it:
  ``Reconstruction``, ``result.json``, ``body.obj``, the synthetic benchmark's ground truth.
* **view frame**: x right, y up, z towards the viewer. It is OpenGL's camera frame, the frame
  SMPLR reads J+ in (it was trained on bodies seen by an upright viewer) and, for a subject
  facing the camera, the body frame of ``recon.body.skeleton``.

The two differ by a half turn about X (``HALF_TURN_X``, its own inverse). This module is the one
place that turns points and rotations between them: ``to_view`` / ``to_opencv`` and
``rotation_to_opencv`` / ``rotation_to_view``. Projection goes through kornia (``kornia.geometry.camera``).
"""
from __future__ import annotations

import numpy as np
import torch
from kornia.geometry.camera import project_points, unproject_points

from recon.body import skeleton

HALF_TURN_X = np.diag([1.0, -1.0, -1.0])
"""OpenCV camera axes <-> view axes (x kept, y and z flipped). Also the rotation from the body
frame to the OpenCV frame of a camera that sees the subject's front."""


_SIGNS = np.diag(HALF_TURN_X).copy()


def _signs(x):
    return torch.tensor(_SIGNS, dtype=x.dtype, device=x.device) if torch.is_tensor(x) else _SIGNS


def to_view(points):
    """OpenCV camera points (..., 3) -> view frame (numpy or torch, same type out)."""
    return points * _signs(points)


def to_opencv(points):
    """View-frame points (..., 3) -> OpenCV camera frame (the same half turn as ``to_view``)."""
    return points * _signs(points)


def rotation_to_opencv(rotation):
    """A rotation into the view frame (..., 3, 3), e.g. a body's root orientation as SMPLR
    predicts it, -> the same rotation into the OpenCV camera frame."""
    if torch.is_tensor(rotation):
        return torch.as_tensor(HALF_TURN_X, dtype=rotation.dtype, device=rotation.device) @ rotation
    return HALF_TURN_X @ rotation


def rotation_to_view(rotation):
    """A rotation into the OpenCV camera frame (..., 3, 3), e.g. a reconstructed body's root
    orientation, -> the same rotation into the view frame (upright: +Y up for an upright camera)."""
    return rotation_to_opencv(rotation)  # the half turn is its own inverse


def default_intrinsics(h: int, w: int, focal_factor: float = 1.0) -> np.ndarray:
    """Pinhole K of an (h, w) image: focal = ``focal_factor`` x the longer side, principal point
    at the centre (what recon assumes when the camera is not given)."""
    f = focal_factor * max(h, w)
    return np.array([[f, 0.0, w / 2.0], [0.0, f, h / 2.0], [0.0, 0.0, 1.0]])


def _as_torch(*arrays):
    dtype = next((a.dtype for a in arrays if torch.is_tensor(a)), torch.float64)
    return [torch.as_tensor(a, dtype=dtype) if not torch.is_tensor(a) else a for a in arrays]


def project(points, k, min_depth: float | None = None):
    """Camera-frame points (..., 3) -> pixels (..., 2) with intrinsics K (3, 3) or (B, 3, 3) for
    points (B, ..., 3).
    ``min_depth`` clamps z from below (a fitting loop must not divide by ~0). numpy in, numpy out."""
    is_numpy = not torch.is_tensor(points)
    p, kk = _as_torch(points, k)
    if min_depth is not None:
        p = torch.cat([p[..., :2], p[..., 2:].clamp_min(min_depth)], -1)
    uv = project_points(p[None] if p.ndim == 1 else p, kk.to(p))
    uv = uv[0] if p.ndim == 1 else uv
    return uv.numpy() if is_numpy else uv


def unproject(uv, depth, k):
    """Pixels (..., 2) at camera depths z (...) -> camera-frame points (..., 3), intrinsics as in
    ``project``. numpy in, numpy out."""
    is_numpy = not torch.is_tensor(uv)
    u, z, kk = _as_torch(uv, depth, k)
    single = u.ndim == 1
    u = u[None] if single else u
    z = z.to(u).expand(u.shape[:-1])[..., None]
    p = unproject_points(u, z, kk.to(u))
    p = p[0] if single else p
    return p.numpy() if is_numpy else p


def normalized(uv, k):
    """Pixels (..., 2) -> normalised image coordinates (x / z, y / z) (..., 2)."""
    p = unproject(uv, 1.0, k)
    return p[..., :2]


def inside_image(uv: np.ndarray, shape) -> np.ndarray:
    """(N,) True for the 2D points (N, 2) that fall inside an image of ``shape`` (H, W, ...)."""
    h, w = shape[:2]
    return (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)


OUTSIDE_WEIGHT = 0.1


def in_image_weights(uv: np.ndarray, shape, outside: float = OUTSIDE_WEIGHT) -> np.ndarray:
    """Placement weights: keypoints outside the image (guessed, e.g. the legs of a half-body
    photo) count ``outside`` as much as those inside."""
    return np.where(inside_image(uv, shape), 1.0, outside)


def place(points: np.ndarray, uv: np.ndarray, k: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Translation t (3,) minimising the (weighted) linearised reprojection error of the
    camera-frame points (N, 3) + t onto the pixels uv (N, 2): linear least squares in t."""
    w = np.ones(len(uv)) if weights is None else np.asarray(weights, float)
    a, b = [], []
    for d in range(2):  # f_d (x_d + t_d) = (u_d - c_d)(z + t_z), linear in t
        f, du = k[d, d], uv[:, d] - k[d, 2]
        row = np.zeros((len(uv), 3))
        row[:, d], row[:, 2] = f, -du
        a.append(row * w[:, None])
        b.append((du * points[:, 2] - f * points[:, d]) * w)
    t, *_ = np.linalg.lstsq(np.concatenate(a), np.concatenate(b), rcond=None)
    return t


def depth_from_bones(uv: np.ndarray, k: np.ndarray, template: np.ndarray, points: np.ndarray | None = None,
                     foreshortening: float = 0.85) -> float:
    """Camera distance at which the template's J+ bone lengths (41,) match the 2D bones of uv
    (42, 2): the median over the 41 links of SMPLR's tree. Each bone's foreshortening (its
    image-plane share of its 3D length) comes from camera-frame J+ ``points`` when given, else
    is the typical 0.85. Metric scale from 2D alone: how big a template body must be to look
    this big."""
    xy = normalized(uv, k)
    parents = list(skeleton.KINTREE_PLUS[1:])
    d2 = np.linalg.norm(xy[1:] - xy[parents], axis=1)
    if points is not None:
        d3 = points[1:] - points[parents]
        foreshortening = np.linalg.norm(d3[:, :2], axis=1) / np.maximum(np.linalg.norm(d3, axis=1), 1e-6)
    return float(np.median(foreshortening * template / np.maximum(d2, 1e-6)))
