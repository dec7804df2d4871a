"""PBNS (thesis ch. 5): pose -> 4x32 MLP -> embedding X (128) -> PSD matrix D -> rest-pose
deformation -> linear blend skinning with the body (Eq. 5.2):

    V_theta = W(T + f_X(theta) . D, theta, weights)

Blend weights start as those of the nearest rest-body vertex, are Laplacian-diffused over the
garment (10 steps, 20 for skirts) and optimised with the network (thesis 5.3.2 does this for
skirts only; here it is done for every outfit, see eval/results/garment-ablation-top-shorts.md).
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn

from recon import paths
from recon.body.base import BodyModel
from recon.body.lbs import blend_transforms
from recon.errors import ReconError
from recon.garment.mesh import smooth_vertex_values
from recon.garment.templates import Outfit, RestBody, make_outfit


@dataclass
class PBNSConfig:
    hidden: int = 32
    layers: int = 4
    embedding: int = 128  # |X|, rows of D (32 -> 128: fewer collisions and less strain, ablation)
    optimise_weights: bool = True  # blend weights trained with the network (thesis: skirts)
    # Laplacian smoothing steps of the nearest-vertex blend weights: nearest-vertex weights jump
    # between bones (crotch, hips) and stretch the skinned cloth far more than the body's own skin
    # (the garment model card's ablation).
    weight_diffusion: int = 10


def pose_features(rotmats: torch.Tensor) -> torch.Tensor:
    """(B, 24, 3, 3) local rotations -> (B, 216) network input: R - I of every joint, the root
    with its heading (yaw about +Y) removed: gravity depends on tilt, not on heading."""
    r = torch.cat([remove_yaw(rotmats[:, :1]), rotmats[:, 1:]], 1)  # out of place: differentiable in the pose
    eye = torch.eye(3, dtype=r.dtype, device=r.device)
    return (r - eye).flatten(1)


def pose_mlp(hidden: int, layers: int, embedding: int) -> nn.Sequential:
    """PBNS's network: ``layers`` FC layers, each followed by a ReLU, from ``pose_features`` to the
    code X."""
    dims = [24 * 9] + [hidden] * (layers - 1) + [embedding]
    mods: list[nn.Module] = []
    for a, b in zip(dims[:-1], dims[1:]):
        mods += [nn.Linear(a, b), nn.ReLU()]
    return nn.Sequential(*mods)


def mlp_of(state: dict) -> nn.Sequential:
    """The ``pose_mlp`` whose weights ``state`` (a state dict) holds, sized by them."""
    w = [state[k] for k in sorted((k for k in state if k.endswith(".weight")), key=lambda k: int(k.split(".")[0]))]
    mlp = pose_mlp(w[0].shape[0], len(w), w[-1].shape[0])
    mlp.load_state_dict(state)
    return mlp


@torch.no_grad()
def widened(mlp: nn.Sequential, hidden: int) -> nn.Sequential:
    """A ``pose_mlp`` with ``hidden`` units per hidden layer computing what ``mlp`` does: its
    weights copied, the new units' outgoing weights zero (their incoming ones as initialised)."""
    old = [m for m in mlp if isinstance(m, nn.Linear)]
    if hidden < old[0].out_features:
        raise ValueError(f"widened: {hidden} hidden units, fewer than the network's {old[0].out_features}")
    new = pose_mlp(hidden, len(old), old[-1].out_features).to(old[0].weight)
    for a, b in zip(old, (m for m in new if isinstance(m, nn.Linear))):
        o, i = a.weight.shape
        b.weight[:o, :i] = a.weight
        b.weight[:o, i:] = 0.0
        b.bias[:o] = a.bias
    return new


def remove_yaw(r: torch.Tensor) -> torch.Tensor:
    """Left-multiply by the inverse heading so the body's forward axis (+Z) has no X component."""
    f = r[..., :, 2]  # body +Z in the parent (world) frame
    yaw = torch.atan2(f[..., 0], f[..., 2])
    c, s = torch.cos(-yaw), torch.sin(-yaw)
    z, o = torch.zeros_like(c), torch.ones_like(c)
    ry = torch.stack([c, z, s, z, o, z, -s, z, c], -1).view(*c.shape, 3, 3)
    return ry @ r


# On the CPU, inference batches at least this large take the vertex-major path of PBNS.pose
# (benchmarks/bench_garment.py), in chunks of this many floats of blended transforms (1 MB); on a
# GPU the batch-major form is the faster one at every batch (eval/results/bench-garment-gpu-h200.md)
VERTEX_MAJOR_MIN_BATCH = 12
VERTEX_MAJOR_CHUNK_FLOATS = 1 << 18


def vertex_major(x: torch.Tensor) -> bool:
    """Whether inference on codes ``x`` (B, E) takes the vertex-major form: a batch of at least
    ``VERTEX_MAJOR_MIN_BATCH`` frames on the CPU."""
    return x.device.type == "cpu" and x.shape[0] >= VERTEX_MAJOR_MIN_BATCH


def rotate(t: torch.Tensor, x: torch.Tensor, add: torch.Tensor | None = None) -> torch.Tensor:
    """``t[..., :3, :3] @ x`` per vertex (+ ``add``) for matrices t (..., 3, >= 3) and vectors x
    (..., 3), as fused multiply-adds of t's columns (in place on a new tensor: differentiable)."""
    o = t[..., 0] * x[..., 0:1] if add is None else torch.addcmul(add, t[..., 0], x[..., 0:1])
    return o.addcmul_(t[..., 1], x[..., 1:2]).addcmul_(t[..., 2], x[..., 2:3])


class BlendShapeGarment(nn.Module):
    """What PBNS and NCS share: a rest outfit, a blend-shape matrix D (code -> rest-pose
    displacement, so an export stays morph targets), learned blend weights and skinning.
    Subclasses map their input to codes (E,) and set ``cfg`` (a dataclass with ``embedding``)."""

    def __init__(self, rest: torch.Tensor, faces: torch.Tensor, weights: torch.Tensor, embedding: int,
                 optimise_weights: bool = True):
        super().__init__()
        self.register_buffer("rest", rest.float())  # (N, 3) outfit in rest pose, body frame
        self.register_buffer("faces", faces.long())
        self.D = nn.Parameter(torch.zeros(embedding, rest.shape[0] * 3))
        logits = torch.log(weights.float().clamp_min(1e-6))
        if optimise_weights:
            self.weight_logits = nn.Parameter(logits)
        else:
            self.register_buffer("weight_logits", logits)

    @property
    def weights(self) -> torch.Tensor:
        """(N, 24) blend weights. Cached unless they are being optimised (the softmax cost as much
        as the rest of a batch-1 frame); the cache follows in-place changes (load, step, .to)."""
        if self.weight_logits.requires_grad and torch.is_grad_enabled():
            return torch.softmax(self.weight_logits, -1)
        key = (self.weight_logits.data_ptr(), self.weight_logits._version)
        if getattr(self, "_weights_key", None) != key:
            with torch.no_grad():
                self._weights = torch.softmax(self.weight_logits, -1)
            self._weights_key = key
        return self._weights

    def blend(self, transforms: torch.Tensor) -> torch.Tensor:
        """Joint transforms (B, 24, 3, 4) (BodyOutput.transforms, rest -> posed) -> each vertex's
        blended transform (B, N, 3, 4) with this garment's weights."""
        return blend_transforms(self.weights, transforms)

    def skin(self, x: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
        """LBS of rest-pose points x ((N, 3) or (B, N, 3)) with the joint transforms (B, 24, 3, 4)."""
        return self.apply_blend(x, self.blend(transforms))

    @staticmethod
    def apply_blend(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Rest-pose points x ((N, 3) or (B, N, 3)) through blended transforms t (B, N, 3, 4): the
        translation plus each column of the 3x3 part times a coordinate, three fused multiply-adds
        (an einsum makes B x N tiny matmuls; broadcasting to (B, N, 3, 3) and summing is
        memory-bound: benchmarks/bench_garment.py)."""
        if x.dim() == 2:
            x = x.expand(t.shape[0], -1, -1)
        return rotate(t, x, t[..., 3])

    def decode(self, x: torch.Tensor) -> torch.Tensor:
        """Codes (..., E) -> rest-pose displacements dT (..., N, 3)."""
        return (x @ self.D).view(*x.shape[:-1], -1, 3)

    @torch.no_grad()
    def pose_codes(self, x: torch.Tensor, transforms: torch.Tensor, rest: torch.Tensor | None = None) -> torch.Tensor:
        """Posed vertices (B, N, 3) of codes (B, E) for inference (no gradients), in the faster form
        for the device and batch (``vertex_major``). ``rest``: (N, 3) or (B, N, 3) rest outfit
        (resized per body; default the template)."""
        rest = self.rest if rest is None else rest
        if not vertex_major(x):
            return self.skin(rest + self.decode(x), transforms)
        return self._pose_vertex_major(x, transforms, rest)

    def _pose_vertex_major(self, x: torch.Tensor, transforms: torch.Tensor, rest: torch.Tensor) -> torch.Tensor:
        """The batch is the fastest axis: per chunk of vertices, dT (c, 3, B) is one GEMM with D,
        the blended transforms (c, 12, B) one GEMM with the blend weights, and the 3x4 products
        are elementwise over B. Chunks keep the blended transforms (the largest intermediate,
        48 bytes per vertex and frame) in cache; batch-major, they stream through memory and the
        3x3 products become B x N tiny matmuls (benchmarks/bench_garment.py)."""
        b, n, e = x.shape[0], self.rest.shape[0], x.shape[1]
        d_t, w = self._d_vertex_major(), self.weights  # both cached
        xt = x.t().contiguous()  # (E, B)
        tb = transforms.reshape(b, 24, 12).permute(1, 2, 0).reshape(24, 12 * b)
        rest_t = rest[:, :, None] if rest.dim() == 2 else rest.permute(1, 2, 0)  # (N, 3, 1 or B)
        out = torch.empty(b, n, 3, dtype=x.dtype, device=x.device)
        c = max(16, VERTEX_MAJOR_CHUNK_FLOATS // (12 * b))
        for a in range(0, n, c):
            z = min(n, a + c)
            p = (d_t[a:z].reshape(-1, e) @ xt).view(z - a, 3, b).add_(rest_t[a:z])
            t = (w[a:z] @ tb).view(z - a, 3, 4, b)
            o = torch.addcmul(t[:, :, 3], t[:, :, 0], p[:, 0:1])
            o.addcmul_(t[:, :, 1], p[:, 1:2]).addcmul_(t[:, :, 2], p[:, 2:3])
            out[:, a:z] = o.permute(2, 0, 1)
        return out

    def _d_vertex_major(self) -> torch.Tensor:
        """D as (N, 3, E), cached until D changes (like ``weights``)."""
        key = (self.D.data_ptr(), self.D._version)
        if getattr(self, "_d_vm_key", None) != key:
            self._d_vm = self.D.detach().t().contiguous().view(self.rest.shape[0], 3, -1)
            self._d_vm_key = key
        return self._d_vm

    # --- persistence ----------------------------------------------------------------------------
    def save(self, path: Path, extra: dict) -> None:
        sd = self.state_dict()
        sd["D"] = sd["D"].half()  # halves the file; dT moves by float noise (eval/results/weights-float16.md)
        state = {"cfg": asdict(self.cfg), "state": sd} | extra
        paths.atomic_write(Path(path), lambda t: torch.save(state, t))


class PBNS(BlendShapeGarment):
    def __init__(self, rest: torch.Tensor, faces: torch.Tensor, weights: torch.Tensor, cfg: PBNSConfig | None = None):
        cfg = cfg or PBNSConfig()
        super().__init__(rest, faces, weights, cfg.embedding, cfg.optimise_weights)
        self.cfg = cfg
        self.mlp = pose_mlp(cfg.hidden, cfg.layers, cfg.embedding)

    def deformation(self, rotmats: torch.Tensor) -> torch.Tensor:
        """(B, 24, 3, 3) -> rest-pose displacements dT (B, N, 3)."""
        return self.decode(self.mlp(pose_features(rotmats)))

    def forward(self, rotmats: torch.Tensor, transforms: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Pose the outfit, differentiably (training). transforms: (B, 24, 3, 4) rest -> posed per
        joint (BodyOutput.transforms). Returns (posed vertices (B, N, 3), dT (B, N, 3))."""
        dt = self.deformation(rotmats)
        return self.skin(self.rest + dt, transforms), dt

    def pose(self, rotmats: torch.Tensor, transforms: torch.Tensor, rest: torch.Tensor | None = None) -> torch.Tensor:
        """``forward``'s posed vertices (B, N, 3) for inference (``pose_codes``)."""
        with torch.no_grad():
            return self.pose_codes(self.mlp(pose_features(rotmats)), transforms, rest)

    @classmethod
    def load(cls, path: Path) -> tuple[PBNS, dict]:
        ck = paths.load_checkpoint(path, "recon garment train")
        sd = ck["state"]
        m = cls(sd["rest"], sd["faces"], torch.softmax(sd["weight_logits"], -1), PBNSConfig(**ck["cfg"]))
        m.load_state_dict(sd)  # copies (and upcasts) the float16 D
        return m.eval(), ck


def initial_weights(rb: RestBody, outfit: Outfit, diffusion: int = 0) -> np.ndarray:
    """Blend weights of the nearest rest-body vertex, optionally diffused over the outfit mesh."""
    _, idx = cKDTree(rb.v).query(outfit.vertices)
    w = rb.weights[idx].astype(np.float64)
    if diffusion > 0:
        w = smooth_vertex_values(w, outfit.faces, diffusion)
    return (w / w.sum(1, keepdims=True)).astype(np.float32)


def trained_outfit(body: BodyModel, pbns_path: Path) -> tuple[Outfit, torch.Tensor, str]:
    """The template a PBNS file was trained on (rebuilt, and checked against the file), its
    body shape and the outfit's name."""
    model, ck = PBNS.load(pbns_path)
    meta = json.loads(ck["meta_json"])
    outfit = make_outfit(body, meta.get("source", meta["outfit"]), ck["shape"][None])  # source: a preset or a mesh
    if not np.allclose(outfit.vertices, model.rest.numpy(), atol=1e-5):
        raise ReconError(f"the {meta['outfit']} template changed since {pbns_path} was trained: retrain it")
    return outfit, ck["shape"], meta["outfit"]
