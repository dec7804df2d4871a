"""SMPLR inference: J+ (3D or 2D) -> [DAE] -> Omega/Psi -> body model -> mesh [-> Procrustes]."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn

from recon import paths
from recon.body import BodyOutput
from recon.smplr import features
from recon.smplr.networks import DAEConfig, DenoisingAutoencoder, PoseNet, ShapeNet

WEIGHTS = Path(__file__).resolve().parent / "weights" / "smplr_anny.pt"


@dataclass
class SMPLROutput:
    rotmats: torch.Tensor  # (B, 24, 3, 3) local rotations (root = orientation in the input frame)
    shape: torch.Tensor  # (B, S)
    body: BodyOutput  # mesh, joints, landmarks; pelvis at the input pelvis
    points_in: torch.Tensor  # (B, 42, 3) J+ fed to Omega/Psi (after the DAE if used)


class SMPLR(nn.Module):
    def __init__(self, body, omega: PoseNet, psi: ShapeNet, dae3d: DenoisingAutoencoder | None = None,
                 dae2d: DenoisingAutoencoder | None = None):
        super().__init__()
        self.body, self.omega, self.psi, self.dae3d, self.dae2d = body, omega, psi, dae3d, dae2d
        self.register_buffer("template", features.template_distances(body), persistent=False)

    @classmethod
    def load(cls, body=None, path: str | Path | None = None) -> "SMPLR":
        """Load trained weights (``torch.load(weights_only=True)``)."""
        from recon.body import default_body

        body = body or default_body()
        ck = paths.load_checkpoint(path or WEIGHTS, "recon smplr train")
        if ck["num_shape"] != body.num_shape_params:
            raise ValueError(f"weights expect {ck['num_shape']} shape parameters, body has {body.num_shape_params}")
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
        return self.omega(features.normalized_relative(points)), self.psi(features.relative_distances(points, self.template))

    def forward(self, points: torch.Tensor, mode: str = "3d", denoise: bool = True, procrustes: bool = False,
                points_only: bool = False) -> SMPLROutput:
        """Reconstruct bodies from J+.

        Args:
            points: (B, 42, 3) joints + landmarks in metres, in a viewer frame with +Y up and +Z
                towards the viewer (OpenGL camera axes; OpenCV camera points times (1, -1, -1)),
                as in training. In mode "2d" the third coordinate is ignored and the DAE-2D
                lifts the (orthographic, metric) points to 3D.
            denoise: run the 3D DAE first (mode "3d").
            procrustes: similarity-align the output to the input J+ (ALL_Proc of the thesis).
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
                raise RuntimeError("these weights have no 2D-lifting DAE")
            x = self.dae2d(features.centre(x, planar=True))
            root = root * root.new_tensor([1.0, 1.0, 0.0])
        elif denoise and self.dae3d is not None:
            x = self.dae3d(features.centre(x))
        x = x - x[:, :1]  # the DAE works centroid-centred; SMPLR takes pelvis-centred J+
        rot, shape = self.regress(x)
        out = self.body(rot, shape, transl=root[:, 0], points_only=points_only)
        if procrustes:
            out = _procrustes(out, x + root)
        return SMPLROutput(rot, shape, out, x + root)


def _procrustes(out: BodyOutput, target: torch.Tensor) -> BodyOutput:
    from recon.metrics import similarity_transform

    s, r, t = similarity_transform(out.points, target)
    f = lambda p: s[:, None, None] * (p @ r.transpose(-1, -2)) + t[:, None]  # noqa: E731
    sr = s[:, None, None, None] * r[:, None]
    tf = torch.cat([sr @ out.transforms[..., :3], sr @ out.transforms[..., 3:] + t[:, None, :, None]], -1)
    return BodyOutput(vertices=f(out.vertices), joints=f(out.joints), landmarks=f(out.landmarks),
                      transforms=tf, global_rotmats=r[:, None] @ out.global_rotmats,
                      rest_vertices=out.rest_vertices)
