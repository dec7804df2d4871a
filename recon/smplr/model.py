"""SMPLR inference: J+ (3D or 2D) -> [DAE] -> Omega/Psi -> body model -> mesh [-> Procrustes].

``SMPLR.forward`` reads J+ in the view frame it was trained in; ``SMPLR.lift_and_place`` takes
camera-frame J+ and 2D keypoints and returns bodies placed in the camera: what the image
pipeline and the benchmark methods call.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from recon import camera, paths
from recon.body import BodyOutput, default_body
from recon.body.base import BodyModel
from recon.errors import ReconError
from recon.metrics import similarity_transform
from recon.smplr import features
from recon.smplr.networks import DAEConfig, DenoisingAutoencoder, PoseNet, ShapeNet

WEIGHTS = Path(__file__).resolve().parent / "weights" / "smplr_anny.pt"


@dataclass
class SMPLROutput:
    rotmats: torch.Tensor  # (B, 24, 3, 3) local rotations (root = orientation in the input frame)
    shape: torch.Tensor  # (B, S)
    body: BodyOutput  # mesh, joints, landmarks; pelvis at the input pelvis
    points_in: torch.Tensor  # (B, 42, 3) J+ fed to Omega/Psi (after the DAE if used)


@dataclass
class PlacedBodies:
    """SMPLR's bodies placed in a camera (``SMPLR.lift_and_place``). OpenCV camera frame, metres."""

    vertices: np.ndarray | None  # (B, V, 3); None with points_only
    joints: np.ndarray  # (B, 24, 3)
    landmarks: np.ndarray  # (B, 18, 3)
    rotmats: torch.Tensor  # (B, 24, 3, 3) local rotations; the root's maps the body frame to the camera's
    shape: torch.Tensor  # (B, S)
    translation: np.ndarray  # (B, 3) pelvis position
    points_in: np.ndarray  # (B, 42, 3) the J+ Omega/Psi read (after the DAE), pelvis-relative


class SMPLR(nn.Module):
    def __init__(self, body: BodyModel, omega: PoseNet, psi: ShapeNet, dae3d: DenoisingAutoencoder | None = None,
                 dae2d: DenoisingAutoencoder | None = None):
        super().__init__()
        self.body, self.omega, self.psi, self.dae3d, self.dae2d = body, omega, psi, dae3d, dae2d
        self.register_buffer("template", features.template_distances(body), persistent=False)

    @classmethod
    def load(cls, body: BodyModel | None = None, path: str | Path | None = None) -> SMPLR:
        """Load trained weights (``torch.load(weights_only=True)``; float16 files are read as float32)."""
        body = body or default_body()
        ck = paths.load_checkpoint(path or WEIGHTS, "recon smplr train")
        if ck["num_shape"] != body.num_shape_params:
            raise ReconError(f"weights expect {ck['num_shape']} shape parameters, body has {body.num_shape_params}")
        omega = PoseNet(**ck["omega_cfg"])
        psi = ShapeNet(ck["num_shape"], **ck["psi_cfg"])
        omega.load_state_dict(ck["omega"])
        psi.load_state_dict(ck["psi"])
        daes = {}
        for k in ("dae3d", "dae2d"):
            if k in ck:
                cfg = ck[k + "_cfg"]
                daes[k] = DenoisingAutoencoder(DAEConfig(tuple(cfg["dims"]), cfg["dropout"], cfg["point_dropout"],
                                                    cfg["lifting"]))
                daes[k].load_state_dict(ck[k])
        return cls(body, omega, psi, **daes).eval()

    def regress(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """J+ (B, 42, 3), pelvis-centred -> (rotmats, shape)."""
        return (self.omega(features.normalized_relative(points)),
                self.psi(features.relative_distances(points, self.template)))

    def forward(self, points: torch.Tensor, mode: str = "3d", denoise: bool = True, procrustes: bool = False,
                points_only: bool = False, shape: torch.Tensor | None = None) -> SMPLROutput:
        """Reconstruct bodies from J+.

        Args:
            points: (B, 42, 3) joints + landmarks in metres, in a viewer frame with +Y up and +Z
                towards the viewer (OpenGL camera axes; OpenCV camera points times (1, -1, -1)),
                as in training. In mode "2d" the third coordinate is ignored and the DAE-2D
                lifts the (orthographic, metric) points to 3D.
            denoise: run the 3D DAE first (mode "3d").
            procrustes: similarity-align the output to the input J+ (ALL_Proc of the thesis).
            shape: (B, S) body shape known from elsewhere (e.g. ``recon.shape.ShapeHead``): used
                instead of Psi's; its NaN entries keep Psi's value.
        """
        if mode not in ("3d", "2d"):
            raise ValueError(f"mode must be '3d' or '2d', got {mode!r}")
        features.relative_vectors(points)  # shape check with a clear message
        if not torch.isfinite(points).all():
            raise ValueError("J+ contains NaN or infinite values")
        root = points[:, :1]
        x = points - root
        if mode == "2d":
            if self.dae2d is None:
                raise ReconError("these weights have no 2D-lifting DAE")
            x = self.dae2d(features.centre(x, planar=True))
            root = root * root.new_tensor([1.0, 1.0, 0.0])
        elif denoise and self.dae3d is not None:
            x = self.dae3d(features.centre(x))
        x = x - x[:, :1]  # the DAE works centroid-centred; SMPLR takes pelvis-centred J+
        rot, psi = self.regress(x)
        if shape is not None:
            psi = torch.where(torch.isnan(shape), psi, shape.to(psi))
        out = self.body(rot, psi, transl=root[:, 0], points_only=points_only)
        if procrustes:
            out = align_body(out, x + root)
        return SMPLROutput(rot, psi, out, x + root)

    @torch.no_grad()
    def lift_and_place(self, points, points2d, k, weights=None, mode: str = "3d", denoise: bool = True,
                       points_only: bool = False, shape: np.ndarray | None = None) -> PlacedBodies:
        """Camera-frame J+ -> SMPLR -> bodies placed in the camera.

        Args:
            points: (B, 42, 3) J+ in the OpenCV camera frame, metres (any translation: only the
                shape of J+ is used). In mode "2d", (x, y) = normalised image coordinates times a
                metric depth and z = 0 (orthographic, metric), lifted by the DAE-2D.
            points2d: (B, 42, 2) the same points in pixels; the body's translation minimises its
                reprojection error onto them (``recon.camera.place``), weighted by ``weights`` (B, 42).
            k: (3, 3) or (B, 3, 3) intrinsics.
            shape: (B, S) body shape to use instead of Psi's where not NaN (``forward``).
        """
        pts = np.asarray(points, dtype=np.float64)
        uv = np.asarray(points2d, dtype=np.float64)
        ks = np.broadcast_to(np.asarray(k, dtype=np.float64), (len(pts), 3, 3))
        x = torch.tensor(camera.to_view(pts - pts[:, :1]), dtype=torch.float32, device=self.template.device)
        known = None if shape is None else torch.tensor(np.asarray(shape), dtype=torch.float32, device=x.device)
        o = self(x, mode=mode, denoise=denoise, points_only=points_only, shape=known)
        j = camera.to_opencv(o.body.joints.cpu().numpy())
        lm = camera.to_opencv(o.body.landmarks.cpu().numpy())
        v = None if points_only else camera.to_opencv(o.body.vertices.cpu().numpy())
        t = np.stack([camera.place(np.concatenate([j[n], lm[n]]) - j[n, :1], uv[n], ks[n],
                                   None if weights is None else weights[n]) for n in range(len(pts))])
        shift = t[:, None] - j[:, :1]  # pelvis to t
        rot = o.rotmats.clone()
        rot[:, 0] = camera.rotation_to_opencv(rot[:, 0])
        return PlacedBodies(vertices=None if v is None else v + shift, joints=j + shift, landmarks=lm + shift,
                            rotmats=rot, shape=o.shape, translation=t,
                            points_in=camera.to_opencv(o.points_in.cpu().numpy()))


def align_body(out: BodyOutput, target: torch.Tensor) -> BodyOutput:
    """The body similarity-aligned (scale, rotation, translation) onto the J+ ``target``
    (ALL_Proc of the thesis)."""
    s, r, t = similarity_transform(out.points, target)
    f = lambda p: s[:, None, None] * (p @ r.transpose(-1, -2)) + t[:, None]  # noqa: E731
    sr = s[:, None, None, None] * r[:, None]
    tf = torch.cat([sr @ out.transforms[..., :3], sr @ out.transforms[..., 3:] + t[:, None, :, None]], -1)
    return BodyOutput(vertices=f(out.vertices), joints=f(out.joints), landmarks=f(out.landmarks),
                      transforms=tf, global_rotmats=r[:, None] @ out.global_rotmats,
                      rest_vertices=out.rest_vertices)
