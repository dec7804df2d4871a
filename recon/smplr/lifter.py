"""Camera-aware lifting: 2D J+ in pixels + intrinsics K -> 3D J+ in the camera, and the root's depth.

The 2D points enter as camera rays (K^-1 [u, v, 1]), so focal length, principal point and the
person's place in the image are explicit. A virtual rotation of the camera turns the pelvis ray
onto the optical axis (a perspective crop): the network sees the person as if centred, whatever
its place in the frame, plus the direction of the real camera's "up" in that virtual camera and
the person's angular size. It predicts the root-relative J+ in the virtual camera (metres) and
the log of (pelvis distance x angular size), which the angular size turns into a distance.
Points the source did not see (outside the image) are masked, not guessed.

The network is the residual MLP of Martinez et al. (2017), trained on generated data
(``recon.smplr.lifter_train``); its J+ feed SMPLR's Omega/Psi (``SMPLR.lift_and_place``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import roma
import torch
from torch import nn

from recon import paths
from recon.body import skeleton
from recon.smplr.networks import NormResidualBlock

WEIGHTS = Path(__file__).resolve().parent / "weights" / "lifter.pt"
PELVIS = 0
IN_DIM = skeleton.NUM_POINTS * 3 + 1 + 3  # xy + visibility per point, log angular size, camera up
OUT_DIM = skeleton.NUM_POINTS * 3 + 1  # root-relative J+ (virtual camera), log(depth x size)


def rays(uv: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """Pixels (B, P, 2), intrinsics (B, 3, 3) -> unit camera rays (B, P, 3), OpenCV axes."""
    h = torch.cat([uv, torch.ones_like(uv[..., :1])], -1)
    r = h @ torch.linalg.inv(k).transpose(-1, -2)
    return r / r.norm(dim=-1, keepdim=True)


def to_axis(ray: torch.Tensor) -> torch.Tensor:
    """(B, 3) unit rays -> (B, 3, 3) the smallest rotation taking each onto the optical axis +Z."""
    z = torch.zeros_like(ray)
    z[:, 2] = 1.0
    axis = torch.cross(ray, z, dim=-1)
    sin = axis.norm(dim=-1, keepdim=True)
    angle = torch.atan2(sin, (ray * z).sum(-1, keepdim=True))
    return roma.rotvec_to_rotmat(axis / sin.clamp_min(1e-12) * angle)


@dataclass
class LiftInput:
    """What the network reads, and what turns its output back into the real camera."""

    features: torch.Tensor  # (B, IN_DIM)
    rotation: torch.Tensor  # (B, 3, 3) real camera -> virtual (pelvis on the axis)
    size: torch.Tensor  # (B,) angular size: RMS virtual image distance of the seen points to the pelvis
    root_ray: torch.Tensor  # (B, 3) unit ray through the pelvis


def prepare(uv: torch.Tensor, k: torch.Tensor, visible: torch.Tensor | None = None) -> LiftInput:
    """Pixels (B, 42, 2), K (B, 3, 3), visibility (B, 42) bool/float (None: all seen)."""
    vis = torch.ones(uv.shape[:2], dtype=uv.dtype, device=uv.device) if visible is None else visible.to(uv.dtype)
    r = rays(uv, k)
    rot = to_axis(r[:, PELVIS])
    q = r @ rot.transpose(-1, -2)
    xy = q[..., :2] / q[..., 2:].clamp_min(1e-3)
    xy = xy - xy[:, PELVIS:PELVIS + 1]
    size = ((xy.square().sum(-1) * vis).sum(1) / vis.sum(1).clamp_min(1)).sqrt().clamp_min(1e-4)
    up = rot @ torch.tensor([0.0, -1.0, 0.0], dtype=uv.dtype, device=uv.device)  # the camera's up, virtual frame
    x = torch.cat([(xy / size[:, None, None] * vis[..., None]).flatten(1), vis, size.log()[:, None], up], 1)
    return LiftInput(x, rot, size, r[:, PELVIS])


@dataclass
class LifterConfig:
    width: int = 1024
    blocks: int = 2
    dropout: float = 0.1


@dataclass
class Lifted:
    points: torch.Tensor  # (B, 42, 3) root-relative J+, real camera (OpenCV axes), metres
    root: torch.Tensor  # (B, 3) the pelvis in the camera, metres


class Lifter(nn.Module):
    """``Lifter()(uv, K, visible) -> Lifted``; ``net(features)`` is the raw MLP."""

    def __init__(self, cfg: LifterConfig | None = None):
        super().__init__()
        self.cfg = cfg = cfg or LifterConfig()
        self.net = nn.Sequential(nn.Linear(IN_DIM, cfg.width), nn.BatchNorm1d(cfg.width), nn.ReLU(),
                                 *[NormResidualBlock(cfg.width, cfg.dropout) for _ in range(cfg.blocks)],
                                 nn.Linear(cfg.width, OUT_DIM))

    def raw(self, inp: LiftInput) -> tuple[torch.Tensor, torch.Tensor]:
        """-> (root-relative J+ in the virtual camera (B, 42, 3), log(depth x size) (B,))."""
        y = self.net(inp.features)
        return y[:, :-1].view(-1, skeleton.NUM_POINTS, 3), y[:, -1]

    def forward(self, uv: torch.Tensor, k: torch.Tensor, visible: torch.Tensor | None = None) -> Lifted:
        inp = prepare(uv, k, visible)
        p, log_zs = self.raw(inp)
        depth = log_zs.exp() / inp.size
        return Lifted(p @ inp.rotation, inp.root_ray * depth[:, None])

    @torch.no_grad()
    def lift(self, uv: np.ndarray, k: np.ndarray, visible: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """numpy (B, 42, 2) pixels, K (3, 3) or (B, 3, 3) -> (J+ root-relative (B, 42, 3), root (B, 3))."""
        uv_t = torch.as_tensor(np.asarray(uv, np.float32))
        k_t = torch.as_tensor(np.broadcast_to(np.asarray(k, np.float32), (len(uv_t), 3, 3)).copy())
        vis = None if visible is None else torch.as_tensor(np.asarray(visible, np.float32))
        out = self(uv_t, k_t, vis)
        return out.points.double().numpy(), out.root.double().numpy()

    @classmethod
    def load(cls, path: str | Path | None = None) -> Lifter:
        """The shipped weights (``torch.load(weights_only=True)``; float16 files are read as float32)."""
        ck = paths.load_checkpoint(path or WEIGHTS, "recon smplr train-lifter")
        m = cls(LifterConfig(**ck["cfg"]))
        m.load_state_dict(ck["state"])
        return m.eval()
