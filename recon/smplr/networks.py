"""SMPLR networks: the denoising autoencoder and the pose (Omega) / shape (Psi) regressors.

Each network declares its config (HOOD style) so checkpoints carry what built them.
"""
from __future__ import annotations

from dataclasses import dataclass

import roma
import torch
from torch import nn

from recon.body import skeleton


class ResidualBlock(nn.Module):
    """Linear-ReLU-Linear with an identity skip (the MLP skip connection of SMPLR)."""

    def __init__(self, width: int, dropout: float = 0.0):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(width, width), nn.ReLU(), nn.Dropout(dropout), nn.Linear(width, width))
        self.act = nn.ReLU()

    def forward(self, x):
        return self.act(x + self.net(x))


class NormResidualBlock(nn.Module):
    """Two Linear-BatchNorm-ReLU-Dropout layers with an identity skip: the block of Martinez et
    al. (2017), used by the camera-aware lifter and the MediaPipe adapter."""

    def __init__(self, width: int, dropout: float):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(width, width), nn.BatchNorm1d(width), nn.ReLU(), nn.Dropout(dropout),
                                 nn.Linear(width, width), nn.BatchNorm1d(width), nn.ReLU(), nn.Dropout(dropout))

    def forward(self, x):
        return x + self.net(x)


@dataclass
class RegressorConfig:
    in_dim: int
    out_dim: int
    width: int = 512
    blocks: int = 2
    dropout: float = 0.0


class Regressor(nn.Module):
    """Input -> Linear -> residual blocks -> output: the body of Omega and Psi."""

    def __init__(self, cfg: RegressorConfig):
        super().__init__()
        self.cfg = cfg
        self.inp = nn.Sequential(nn.Linear(cfg.in_dim, cfg.width), nn.ReLU())
        self.blocks = nn.Sequential(*[ResidualBlock(cfg.width, cfg.dropout) for _ in range(cfg.blocks)])
        self.out = nn.Linear(cfg.width, cfg.out_dim)

    def forward(self, x):
        return self.out(self.blocks(self.inp(x)))


def global_to_local(g: torch.Tensor) -> torch.Tensor:
    """(B, 24, 3, 3) world rotations -> rotations relative to the parent."""
    par = list(skeleton.JOINT_PARENTS[1:])
    return torch.cat([g[:, :1], g[:, par].transpose(-1, -2) @ g[:, 1:]], dim=1)


def local_to_global(r: torch.Tensor) -> torch.Tensor:
    out = [r[:, 0]]
    for j, p in enumerate(skeleton.JOINT_PARENTS[1:], start=1):
        out.append(out[p] @ r[:, j])
    return torch.stack(out, dim=1)


class PoseNet(Regressor):
    """Omega: N (B, 123) -> 24 rotations via the continuous 6D representation (Zhou et al.).

    With ``global_rot`` the network predicts each bone's world rotation (directly visible in
    N) and converts to parent-relative rotations, so errors do not accumulate down the chains.
    ``forward`` always returns parent-relative rotations (B, 24, 3, 3)."""

    def __init__(self, width: int = 512, blocks: int = 3, global_rot: bool = False):
        super().__init__(RegressorConfig(3 * (skeleton.NUM_POINTS - 1), 6 * skeleton.NUM_JOINTS, width, blocks))
        self.global_rot = global_rot

    def raw(self, n):
        six = super().forward(n).view(-1, skeleton.NUM_JOINTS, 3, 2)
        return roma.special_gramschmidt(six)

    def forward(self, n):
        r = self.raw(n)
        return global_to_local(r) if self.global_rot else r


class ShapeNet(Regressor):
    """Psi: B (B, 41) -> shape parameters; anny phenotypes live in [0, 1] (sigmoid)."""

    def __init__(self, num_shape: int, bounded: bool = True, width: int = 256, blocks: int = 2):
        super().__init__(RegressorConfig(skeleton.NUM_POINTS - 1, num_shape, width, blocks))
        self.bounded = bounded

    def forward(self, b):
        y = super().forward(b)
        return torch.sigmoid(y) if self.bounded else y


@dataclass
class DAEConfig:
    dims: tuple[int, ...] = (1024, 512, 256)
    dropout: float = 0.2  # after the last encoder layer (thesis: keep probability 0.8)
    point_dropout: float = 0.1  # after the input: whole points masked, like occluded joints
    lifting: bool = False  # True: input depth is zeroed (2D -> 3D)


class DenoisingAutoencoder(nn.Module):
    """J+ (B, 42, 3) -> cleaned J+ (centroid-centred in and out).

    Dropout after the input and after the last encoder layer; encoder-decoder skip
    connections; the output is a correction added to the input. The input dropout masks
    whole points without rescaling, and the correction is added to the masked input: a
    plain coordinate dropout would hide from the network the very values it must correct (it
    learnt nothing: the SMPLR model card)."""

    def __init__(self, cfg: DAEConfig | None = None):
        super().__init__()
        cfg = cfg or DAEConfig()
        self.cfg = cfg
        d_in = 3 * skeleton.NUM_POINTS
        dims = (d_in,) + tuple(cfg.dims)
        self.drop_code = nn.Dropout(cfg.dropout)
        self.enc = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:]))
        rev = dims[::-1]
        self.dec = nn.ModuleList(nn.Linear(a, b) for a, b in zip(rev[:-1], rev[1:]))
        self.act = nn.ReLU()

    def forward(self, points):
        b = points.shape[0]
        x = points.reshape(b, -1)
        if self.cfg.lifting:
            x = (points * points.new_tensor([1.0, 1.0, 0.0])).reshape(b, -1)
        if self.training and self.cfg.point_dropout > 0:
            keep = (torch.rand(b, points.shape[1], 1, device=x.device) >= self.cfg.point_dropout).to(x.dtype)
            x = (x.view(b, -1, 3) * keep).reshape(b, -1)
        h = x
        skips = []
        for layer in self.enc:
            h = self.act(layer(h))
            skips.append(h)
        h = self.drop_code(h)
        skips.pop()
        for layer in self.dec:
            h = layer(h)
            if skips:
                h = self.act(h + skips.pop())
        return (x + h).view(b, skeleton.NUM_POINTS, 3)
