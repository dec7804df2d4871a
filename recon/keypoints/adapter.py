"""MediaPipe -> J+ adapter: a small MLP that maps MediaPipe's 33 landmarks (image + metric world)
to our 24 joints + 18 surface landmarks, in 3D (root-relative, metres) and 2D.

Why: MediaPipe's keypoints are not our joints (its hips sit on the surface, it has no spine,
collars or surface landmarks), and its 3D is coarse. The adapter learns the mapping from
synthetic renders where both are known (MediaPipe run on ``recon synth`` images, ground truth
from the generator), so the rest of the pipeline (DAE -> SMPLR) gets the J+ it was trained on.
It sees only keypoints, never pixels, so the synthetic-to-real gap is MediaPipe's, not ours.

Frames: inputs and outputs are in OpenCV camera axes (x right, y down, z forward). 2D values
are normalised camera coordinates (u - cx) / f, centred on MediaPipe's mid-hip and divided by
the 2D scale ``s`` (RMS distance of the landmarks to it), so the adapter is independent of
image size, focal length and distance.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from recon import camera, paths
from recon.body import skeleton
from recon.people.mediapipe import DEFAULT_MODEL, NUM_MP, MPPose
from recon.smplr.networks import NormResidualBlock

WEIGHTS = Path(__file__).resolve().parent / "weights" / "mp_adapter.pt"  # trained on the full model's answers
# The weights trained on each landmark model's answers; lite reads full's.
WEIGHTS_BY_MODEL = {"full": WEIGHTS, "heavy": WEIGHTS.with_name("mp_adapter_heavy.pt")}


def weights_for(model: str) -> Path:
    """The shipped adapter for MediaPipe's ``model`` (``recon.people.mediapipe.MODELS``)."""
    return WEIGHTS_BY_MODEL.get(model, WEIGHTS)

MP_HIPS = (23, 24)
IN_DIM = NUM_MP * 6  # xy (2) + world (3) + visibility (1)
OUT_DIM = skeleton.NUM_POINTS * 5  # 3D (3) + 2D (2)


def normalise_2d(xy: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels (..., P, 2) with intrinsics (..., 3, 3) -> (coords centred on MediaPipe's mid-hip and
    divided by their RMS spread, mid-hip (..., 2) in normalised camera coords, spread (...))."""
    n = camera.normalized(xy, k)
    hip = n[..., MP_HIPS, :].mean(-2)
    rel = n - hip[..., None, :]
    s = np.sqrt((rel ** 2).sum(-1).mean(-1))
    return rel / np.maximum(s, 1e-6)[..., None, None], hip, s


def features(xy: np.ndarray, world: np.ndarray, vis: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(..., 33, 2) pixels, (..., 33, 3) world, (..., 33) visibility, K (..., 3, 3) -> (..., 198) input."""
    return assemble_features(normalise_2d(xy, k)[0], world, vis)


def assemble_features(rel: np.ndarray, world: np.ndarray, vis: np.ndarray) -> np.ndarray:
    x = np.concatenate([rel, world, vis[..., None]], -1)
    return x.reshape(*x.shape[:-2], -1).astype(np.float32)


@dataclass
class AdapterConfig:
    width: int = 1024
    blocks: int = 2
    dropout: float = 0.1


class KeypointAdapter(nn.Module):
    """(B, 198) -> J+ 3D (B, 42, 3) root-relative metres and J+ 2D (B, 42, 2) in the input's
    centred, scaled 2D coordinates (Martinez et al.-style residual MLP)."""

    def __init__(self, cfg: AdapterConfig | None = None):
        super().__init__()
        cfg = cfg or AdapterConfig()
        self.cfg = cfg
        self.inp = nn.Sequential(nn.Linear(IN_DIM, cfg.width), nn.BatchNorm1d(cfg.width), nn.ReLU())
        self.blocks = nn.Sequential(*[NormResidualBlock(cfg.width, cfg.dropout) for _ in range(cfg.blocks)])
        self.out = nn.Linear(cfg.width, OUT_DIM)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        y = self.out(self.blocks(self.inp(x))).view(-1, skeleton.NUM_POINTS, 5)
        return y[..., :3], y[..., 3:]

    @classmethod
    def load(cls, path: str | Path | None = None, model: str = DEFAULT_MODEL) -> KeypointAdapter:
        """A trained file, else the shipped weights for MediaPipe's landmark ``model`` (float16
        files are read as float32)."""
        ck = paths.load_checkpoint(path or weights_for(model), "recon keypoints train")
        m = cls(AdapterConfig(**ck["cfg"]))
        m.load_state_dict(ck["state"])
        return m.eval()

    @torch.no_grad()
    def predict(self, mp: MPPose, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """MediaPipe result + intrinsics -> (J+ 3D root-relative (42,3) metres, J+ 2D (42,2) pixels)."""
        x = torch.from_numpy(features(mp.image_xy, mp.world, mp.visibility, k))[None]
        p3, p2 = self(x)
        _, hip, s = normalise_2d(mp.image_xy, k)
        n = p2[0].numpy() * s + hip  # normalised image coordinates
        return p3[0].numpy().astype(np.float64), camera.project(np.concatenate([n, np.ones((len(n), 1))], 1), k)
