"""A learned motion prior: a temporal network that takes one track's per-frame J+ (noisy, as the
per-frame pass estimates them) and gives the motion a person would make: the J+ cleaned of the
per-frame noise, the root's path, and which foot is planted.

It reads the whole track at once through dilated 1D convolutions over time (each frame sees about
two seconds around it), so it can tell a real motion's jerk, which mocap taught it, from the
per-frame wobble it was trained to remove (``recon.video.prior_train``: mocap's train split, noise
as measured on the validation clips by eval/motion_noise.py). The track optimisation
(``recon.video.smooth``) then pulls the body towards it instead of only damping acceleration.

Inputs and outputs live in one camera frame (the reference frame of ``smooth``): root-relative
J+ in metres, and the root as (x/z, y/z, log z) less the track's mean, so that neither where the
person stands nor how far away changes what the network sees.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from recon import paths
from recon.body import skeleton
from recon.errors import MissingFile

WEIGHTS = Path(__file__).resolve().parent / "weights" / "motion_prior.pt"
POINTS = skeleton.NUM_POINTS
IN = POINTS * 3 + 3 + 1  # root-relative J+, root, seen
OUT = POINTS * 3 + 3 + 2  # their corrections, and two feet planted (logits)
FEET = tuple(skeleton.JOINT_NAMES.index(n) for n in ("left_foot", "right_foot"))


@dataclass
class PriorConfig:
    width: int = 128
    dilations: tuple[int, ...] = (1, 2, 4, 8, 1)
    kernel: int = 5


class Block(nn.Module):
    def __init__(self, width: int, kernel: int, dilation: int):
        super().__init__()
        self.conv = nn.Conv1d(width, width, kernel, padding=dilation * (kernel // 2), dilation=dilation,
                              padding_mode="replicate")
        self.mix = nn.Conv1d(width, width, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.mix(nn.functional.gelu(self.conv(x)))


class MotionPrior(nn.Module):
    """(B, T, IN) features -> (B, T, OUT): corrections to the J+ and root, and planted logits."""

    def __init__(self, cfg: PriorConfig | None = None):
        super().__init__()
        self.cfg = cfg = cfg or PriorConfig()
        self.inp = nn.Conv1d(IN, cfg.width, 1)
        self.blocks = nn.Sequential(*(Block(cfg.width, cfg.kernel, d) for d in cfg.dilations))
        self.out = nn.Conv1d(cfg.width, OUT, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out(nn.functional.gelu(self.blocks(self.inp(x.transpose(1, 2))))).transpose(1, 2)


def features(points: torch.Tensor, seen: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(..., T, 42, 3) J+ in a camera frame and (..., T) seen -> the network's input (..., T, IN)
    and the root's mean (x/z, y/z, log z) over the track (..., 1, 3), to go back."""
    root = points[..., 0, :]
    z = root[..., 2:].clamp_min(0.1)
    r = torch.cat([root[..., :2] / z, z.log()], -1)
    mean = r.mean(-2, keepdim=True)
    rel = (points - points[..., :1, :]).flatten(-2)
    return torch.cat([rel, r - mean, seen[..., None].to(points.dtype)], -1), mean


def from_features(x: torch.Tensor, mean: torch.Tensor) -> torch.Tensor:
    """The J+ (..., T, 42, 3) in the camera frame from root-relative J+ and root features."""
    rel = x[..., :POINTS * 3].unflatten(-1, (POINTS, 3))
    r = x[..., POINTS * 3:POINTS * 3 + 3] + mean
    z = r[..., 2:].exp()
    root = torch.cat([r[..., :2] * z, z], -1)
    return rel + root[..., None, :]


def apply(prior: MotionPrior, points: torch.Tensor, seen: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The prior's motion: J+ (..., T, 42, 3) in the same frame as ``points``, and the feet's
    planted probability (..., T, 2)."""
    x, mean = features(points, seen)
    y = prior(x.reshape(-1, *x.shape[-2:])).reshape(*x.shape[:-1], OUT)
    return from_features(x[..., :-1] + y[..., :-2], mean), torch.sigmoid(y[..., -2:])


def save(prior: MotionPrior, path: Path, meta: dict) -> None:
    """float16 weights with their config and training record, written atomically."""
    state = {k: v.half() for k, v in prior.state_dict().items()}
    blob = {"state": state, "config": asdict(prior.cfg), "meta": meta}
    paths.atomic_write(path, lambda tmp: torch.save(blob, tmp))


def load(path: Path | None = None) -> MotionPrior:
    """The shipped prior (or ``path``), float32, in eval mode."""
    path = Path(path or WEIGHTS)
    if not path.exists():
        raise MissingFile(f"motion prior {path} not found: reinstall recon, or train it with "
                          "scripts/train_motion_prior.py (docs/video.md)")
    blob = torch.load(path, map_location="cpu", weights_only=True)
    cfg = blob["config"]
    prior = MotionPrior(PriorConfig(**(cfg | {"dilations": tuple(cfg["dilations"])})))
    prior.load_state_dict({k: v.float() for k, v in blob["state"].items()})
    return prior.eval()


def denoise(prior: MotionPrior, points: np.ndarray, seen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """numpy in and out: the prior's J+ (T, 42, 3) and planted probabilities (T, 2) of one track."""
    with torch.no_grad():
        p, c = apply(prior, torch.tensor(points, dtype=torch.float32), torch.tensor(seen, dtype=torch.float32))
    return p.numpy().astype(np.float64), c.numpy().astype(np.float64)
