"""The fit after SMPLR: a short Adam refinement of the body to the detected 2D keypoints and,
when the keypoint source gives one, to the person mask.

``fit_body`` moves the joint rotations, the translation and (with a mask) the body shape, with
priors that keep pose and shape near SMPLR's and the 3D J+ near the detected ones (depth is what
2D cannot fix). ``SilhouetteTarget`` is the mask term; ``linear_rest_geometry`` lets the loop
skip the body's shape blendshapes (most of a body call). ``FitConfig``'s defaults are what
``recon run`` and ``recon.Reconstructor`` use; they were chosen on synth-val images 0-149
(docs/pipeline.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import roma
import torch
from scipy.spatial import cKDTree

from recon import camera
from recon.body.base import BodyModel
from recon.keypoints.base import Keypoints


@dataclass
class FitConfig:
    steps: int = 30  # Adam steps (0: no fit)
    silhouette: float = 10.0  # weight of the person-mask term (0: keypoints only)
    silhouette_cover: float = 0.3  # weight of "reach the mask's contour" against "stay inside the mask"
    silhouette_stride: int = 7  # every n-th vertex is projected for the mask term
    shape_lr: float = 0.01  # the body shape moves only with the mask term
    shape_prior: float = 1e-3
    pose_prior: float = 0.05  # towards SMPLR's rotations
    depth_prior: float = 20.0  # towards the detected 3D J+ (root-relative)


@dataclass
class FittedBody:
    rotmats: torch.Tensor  # (24, 3, 3) local rotations; the root's maps the body frame to the camera's
    shape: torch.Tensor  # (S,)
    translation: np.ndarray  # (3,) pelvis, camera frame
    vertices: np.ndarray  # (V, 3) camera frame, metres
    joints: np.ndarray  # (24, 3)
    landmarks: np.ndarray  # (18, 3)
    silhouette: float  # the mask weight the fit used (``mask_weight``)


class SilhouetteTarget:
    """Differentiable silhouette terms against a person mask, for projected body vertices uv
    (N, 2) pixels: mean robust distance of the vertices outside the mask (every surface point
    projects inside the silhouette) + ``cover`` x mean robust distance from the mask's contour
    to the nearest vertex (the body should reach the contour). Distances are in units of the
    person box' longer side (``size``); the robust kernel d^2 / (d^2 + s^2) caps what a wrong
    mask (an occluder, a missed limb) can pull. Contour points on the image border are skipped
    (the body continues outside)."""

    def __init__(self, mask: np.ndarray, box, device="cpu", contour_points: int = 256, scale: float = 0.05,
                 cover: float = 1.0, dtype: torch.dtype = torch.float32):
        m = np.ascontiguousarray(mask, dtype=np.uint8)
        h, w = m.shape
        self.size = float(max(box[2] - box[0], box[3] - box[1], 1.0))
        self.scale, self.cover = scale, cover
        dist = cv2.distanceTransform(1 - m, cv2.DIST_L2, 5) / self.size
        self.dist = torch.tensor(dist, dtype=dtype, device=device)[None, None]
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        c = np.concatenate([x[:, 0] for x in contours]) if contours else np.zeros((0, 2))
        c = c[(c[:, 0] > 0) & (c[:, 0] < w - 1) & (c[:, 1] > 0) & (c[:, 1] < h - 1)]
        if len(c) > contour_points:
            c = c[np.linspace(0, len(c) - 1, contour_points).astype(int)]
        self.contour = torch.tensor(c, dtype=dtype, device=device)
        self.contour_np = c.astype(np.float64)
        self.hw = (h, w)

    def rho(self, d2: torch.Tensor) -> torch.Tensor:
        return d2 / (d2 + self.scale ** 2)

    def outside(self, uv: torch.Tensor) -> torch.Tensor:
        """(N,) robust cost of each point's distance to the mask (0 inside it or off the image)."""
        h, w = self.hw
        grid = torch.stack([(uv[:, 0] + 0.5) / w * 2 - 1, (uv[:, 1] + 0.5) / h * 2 - 1], -1)
        d = torch.nn.functional.grid_sample(self.dist, grid[None, None], align_corners=False, padding_mode="zeros")
        return self.rho(d[0, 0, 0] ** 2)

    def uncovered(self, uv: torch.Tensor) -> torch.Tensor:
        """(C,) robust cost of each contour point's distance to its nearest point of uv."""
        if not len(self.contour):
            return uv.new_zeros(0)
        # the nearest point of each contour point (no gradient through the choice)
        nearest = torch.as_tensor(cKDTree(uv.detach().cpu().numpy()).query(self.contour_np)[1], device=uv.device)
        return self.rho((self.contour - uv[nearest]).pow(2).sum(-1) / self.size ** 2)  # no sqrt: finite gradient at 0

    def __call__(self, uv: torch.Tensor) -> torch.Tensor:
        loss = self.outside(uv).mean()
        if len(self.contour):
            loss = loss + self.cover * self.uncovered(uv).mean()
        return loss * self.scale ** 2  # ~ squared distance for small errors


def linear_rest_geometry(body: BodyModel, shape: torch.Tensor, ids: torch.Tensor | None, with_jacobian: bool,
                         eps: float = 1e-2):
    """The body's rest geometry (landmarks, then ``ids``) at ``shape`` (1, S) and, if asked, its
    Jacobian in the shape parameters by central differences in one batched call: a fitting
    loop then skips the shape blendshapes (most of a body call). anny's phenotype blends are
    piecewise linear, so the linear model holds for the small shape changes a fit makes (a test
    bounds its error).
    Returns ((rest_v, rest_j), (jac_v, jac_j) | None)."""
    sel = body.landmark_indices if ids is None else torch.cat([body.landmark_indices, ids])
    with torch.no_grad():
        if not with_jacobian:
            return body.rest_geometry(shape, sel), None
        s = shape.shape[1]
        step = eps * torch.eye(s, dtype=shape.dtype, device=shape.device)
        batch = torch.cat([shape, shape + step, shape - step])
        if body.shape_range is not None:
            batch = batch.clamp(*body.shape_range)
        v, j = body.rest_geometry(batch, sel)
        h = (batch[1:s + 1] - batch[s + 1:]).diagonal().clamp_min(1e-6)  # actual steps after clamping
        jac = tuple(((x[1:s + 1] - x[s + 1:]) / h[:, None, None]).permute(1, 2, 0)[None] for x in (v, j))
        return (v[:1], j[:1]), jac


def mask_weight(cfg: FitConfig, kp: Keypoints) -> float:
    """The silhouette weight the fit uses for these keypoints: 0 without a mask, or when the
    mask covers under 10 % of the keypoints' box (a failed segmentation)."""
    if cfg.silhouette <= 0 or kp.mask is None:
        return 0.0
    h, w = kp.mask.shape
    x0, y0, x1, y1 = (int(round(v)) for v in kp.box)
    x0, x1, y0, y1 = max(x0, 0), min(max(x1, x0 + 1), w), max(y0, 0), min(max(y1, y0 + 1), h)
    area = max((x1 - x0) * (y1 - y0), 1)
    return cfg.silhouette if kp.mask[y0:y1, x0:x1].sum() >= 0.1 * area else 0.0


def fit_body(body: BodyModel, cfg: FitConfig, rot: torch.Tensor, shape: torch.Tensor, t: np.ndarray, kp: Keypoints,
             k: np.ndarray, image_shape, device="cpu", fixed: np.ndarray | None = None) -> FittedBody:
    """Fit the body (local rotations ``rot`` (24, 3, 3) with the root in the camera frame,
    ``shape`` (S,), pelvis ``t``) to the detected 2D J+ that lie inside the image and, when the
    keypoints carry a usable mask (``mask_weight``), to the mask; camera-frame result. ``fixed``
    (S,) bool: shape parameters that stay as given (a gender or height the user knows)."""
    dev = torch.device(device)
    w = torch.tensor(camera.inside_image(kp.points2d, image_shape), dtype=torch.float32, device=dev)
    uv = torch.tensor(kp.points2d, dtype=torch.float32, device=dev)
    kk = torch.tensor(k, dtype=torch.float32, device=dev)
    p3 = torch.tensor(kp.points3d, dtype=torch.float32, device=dev)
    delta = torch.zeros(24, 3, device=dev, requires_grad=True)
    tt = torch.tensor(t, dtype=torch.float32, device=dev).requires_grad_(True)
    shape0 = shape[None].to(dev)
    dshape = torch.zeros_like(shape0, requires_grad=True)
    params = [{"params": [delta], "lr": 0.02}, {"params": [tt], "lr": 0.01}]
    sil, ids = None, None
    weight = mask_weight(cfg, kp)
    if weight > 0:
        sil = SilhouetteTarget(kp.mask, kp.box, dev, cover=cfg.silhouette_cover)
        params.append({"params": [dshape], "lr": cfg.shape_lr})
        ids = torch.arange(0, body.num_vertices, cfg.silhouette_stride, device=dev)
    rest0, rest_jac = linear_rest_geometry(body, shape0, ids, with_jacobian=sil is not None)
    opt = torch.optim.Adam(params)
    lo_hi = body.shape_range

    def project(x):
        return camera.project(x, kk, min_depth=1e-3)

    free = None if fixed is None else torch.tensor(~np.asarray(fixed), dtype=shape0.dtype, device=dev)

    def shaped(d):  # shape offset inside the model's range, none on the fixed parameters
        d = d if free is None else d * free
        return d if lo_hi is None else (shape0 + d).clamp(*lo_hi) - shape0

    for _ in range(cfg.steps):
        r = rot.to(dev) @ roma.rotvec_to_rotmat(delta)
        rest = rest0 if rest_jac is None else tuple(x + torch.einsum("bnks,bs->bnk", jx, shaped(dshape))
                                                   for x, jx in zip(rest0, rest_jac, strict=True))
        if sil is None:
            o = body(r[None], transl=tt[None], points_only=True, rest=rest)
            pts = o.points[0]
        else:
            o = body(r[None], transl=tt[None], vertex_ids=ids, rest=rest)
            pts = torch.cat([o.joints[0], o.landmarks[0]])
        e2d = (((project(pts) - uv) / kk[0, 0]) ** 2).sum(-1)
        e3d = ((pts - pts[:1]) - p3).pow(2).sum(-1)
        loss = ((w * e2d).sum() / w.sum().clamp_min(1) + cfg.depth_prior * 1e-3 * e3d.mean()
                + cfg.pose_prior * 1e-3 * delta.pow(2).sum())
        if sil is not None:
            loss = loss + weight * sil(project(o.vertices[0])) * (kk[0, 0] / sil.size) ** -2 \
                + cfg.shape_prior * dshape.pow(2).sum()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        r = rot.to(dev) @ roma.rotvec_to_rotmat(delta)
        shp = shape0 + shaped(dshape)
        o = body(r[None], shp, transl=tt[None])
    v, j, lm = (x[0].cpu().numpy().astype(np.float64) for x in (o.vertices, o.joints, o.landmarks))
    return FittedBody(r.cpu(), shp[0].cpu(), tt.detach().cpu().numpy().astype(np.float64), v, j, lm, weight)
