"""Keyframe garment animation in a learned intrinsic garment space (Wang, Shao, Fu & Mitra 2019,
"Learning an Intrinsic Garment Space for Interactive Authoring of Garment Animation").

A frame's cloth is a function of the body's motion (the current and past ``window`` frames) and of
*intrinsic* parameters (fabric, gravity, damping, friction, solver). Networks (section 3):

- shape descriptor N_E / N_D (3.3): the hanging part's posed offset from PBNS's drape, in the
  character's heading frame, <-> S (``shape_dims``); linear blocks (Linear, PReLU, BatchNorm) over
  the offsets' first ``pca_dims`` principal components (a fixed first / last layer: the paper's
  3n x 5000 layer would be 74M weights for the 5k-vertex skirt), each side with a linear bypass that
  starts it as PCA; trained with the L2 and mesh-Laplacian (Taubin) reconstruction loss;
- motion encoder M_E (3.4): joint positions of frames t - window .. t in the character space of
  frame t -> linear blocks -> Softplus -> normalised to sum 1: M_D, the blend of ``subnets``
  sub-networks in every U-block;
- motion-invariant autoencoder F_E(S | M) = z, F_D(z | M) = S of U-blocks, trained with
  Var(z) + lambda |S - S*| over batches of frames simulated with one parameter set each.

Authoring (``Session``): z is inferred at the keyframes, interpolated between them (held beyond the
first and last; around the loop with ``loop``), decoded on every frame's motion, and the keyframes'
residuals are blended in over the frames nearest them, so that each keyframe is matched exactly
(``network_share`` < 1: the decoded cloth scaled down, the rest is the keyframes' offsets
interpolated). Offsets are taken from PBNS's drape of the pose, or (``base`` "ncs") from NCS's
cloth on the motion, so that the network learns the fabric's departure from NCS's dynamics.
Frames: body frame, +Y up, metres; 30 frames a second (NCS's rate, the simulations').
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from torch import nn

from recon import paths
from recon.body import skeleton
from recon.body.base import BodyModel
from recon.garment import store
from recon.garment.ncs.model import NCS

PELVIS = skeleton.JOINT_NAMES.index("pelvis")
# the joints that move a skirt: pelvis, hips, knees, ankles, spine, neck (what the signature keeps)
LOWER_BODY = tuple(skeleton.JOINT_NAMES.index(n) for n in (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle", "right_ankle",
    "spine3", "neck"))


@dataclass
class AuthorConfig:
    window: int = 40  # W: past frames in the motion signature
    stride: int = 4  # every stride-th of them
    joints: tuple[int, ...] = LOWER_BODY  # the joints it holds (indices; empty: all 24)
    shape_dims: int = 50  # N_S
    pca_dims: int = 256  # the shape descriptor's fixed outer layer
    shape_hidden: tuple[int, ...] = (256, 128)
    motion_hidden: tuple[int, ...] = (512, 256, 120)
    subnets: int = 30  # N_M: sub-networks blended in each U-block
    latent: int = 100  # K_z
    blocks: int = 5  # U-blocks in F_E (F_D alike)
    laplacian: float = 1.0  # omega: the Laplacian term against the L2 term (each per its data variance)
    lam: float = 0.1  # lambda: reconstruction against Var(z)
    architecture: str = "ublock"  # "ublock" (the paper's), "concat" (motion concatenated: the ablation)
    # the cloth the offsets are taken from: "pbns" (the pose's quasi-static drape) or "ncs" (the
    # outfit's NCS on the motion: its dynamics for the default fabric)
    base: str = "ncs"
    # share of the network's cloth between keyframes kept over the linear interpolation of the
    # keyframes' offsets (1: the paper's propagation; 0: interpolation alone; chosen on val)
    network_share: float = 0.25

    def signature(self, joints: torch.Tensor, yaw: torch.Tensor, loop: bool = False) -> torch.Tensor:
        """``signature`` with this model's window, stride and joints."""
        return signature(joints, yaw, self.window, loop, self.stride, self.joints)


def heading(root_global: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) root rotations -> (..., 3, 3) their rotation about +Y (the character's heading)."""
    f = root_global[..., :, 2]
    yaw = torch.atan2(f[..., 0], f[..., 2])
    c, s = torch.cos(yaw), torch.sin(yaw)
    z, o = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack([c, z, s, z, o, z, -s, z, c], -1).view(*c.shape, 3, 3)


def signature(joints: torch.Tensor, yaw: torch.Tensor, window: int, loop: bool = False, stride: int = 1,
              keep: tuple[int, ...] = ()) -> torch.Tensor:
    """Motion signatures (T, (window // stride + 1) * K * 3): the joints (T, 24, 3) of frames
    t - window // stride * stride, ..., t - stride, t in the character space of frame t (pelvis at the origin, heading
    ``yaw`` (T, 3, 3) removed), the joints ``keep`` of them (all when empty). Frames before the
    first repeat it (the body was still), or, with ``loop``, come from the end."""
    t = len(joints)
    k = torch.arange(t)[:, None] - torch.arange(0, window + 1, stride).flip(0)[None]  # oldest first
    k = k % t if loop else k.clamp(min=0)
    rel = joints[k] - joints[:, None, PELVIS:PELVIS + 1]  # (T, W / stride + 1, 24, 3)
    if keep:
        rel = rel[:, :, list(keep)]
    return torch.einsum("tji,twkj->twki", yaw, rel).reshape(t, -1)


def base_ncs(outfit: str, cfg: AuthorConfig) -> NCS | None:
    """The outfit's NCS when a model of ``cfg`` takes its offsets from NCS's cloth, else None."""
    if cfg.base not in ("pbns", "ncs"):
        raise ValueError(f"base {cfg.base!r}: 'pbns' or 'ncs'")
    return NCS.load(store.ncs_path(outfit))[0] if cfg.base == "ncs" else None


@torch.no_grad()
def clip_inputs(body: BodyModel, pbns, shape: torch.Tensor, rotmats: torch.Tensor, transl: torch.Tensor, ncs=None,
                chunk: int = 64) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """What a ``Session`` needs of a motion (T, 24, 3, 3), (T, 3) on the body of ``shape``: the
    cloth of the whole outfit the model's offsets are taken from (T, N, 3): PBNS's drape, or with
    ``ncs`` NCS's cloth from rest (no collision post-step; a model of ``base`` "ncs"); the heading
    (T, 3, 3) and the joints (T, 24, 3)."""
    if ncs is not None:  # NCS's codes follow the whole motion; the frames are posed a chunk at a time
        zs, zd = ncs.motion_codes(body, rotmats, shape.reshape(-1), transl, 30.0)
    cloth, joints = [], []
    for s in range(0, len(rotmats), chunk):
        r = rotmats[s:s + chunk]
        o = body(r, shape.reshape(1, -1).expand(len(r), -1), transl=transl[s:s + chunk])
        cloth.append(pbns.pose(r, o.transforms) if ncs is None else
                     ncs.pose_codes(zs[s:s + chunk] + zd[s:s + chunk], o.transforms))
        joints.append(o.joints)
    return torch.cat(cloth), heading(rotmats[:, 0]), torch.cat(joints)


def linear_block(i: int, o: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(i, o), nn.PReLU(), nn.BatchNorm1d(o))


def mlp(dims: list[int]) -> nn.Sequential:
    """Linear blocks between ``dims``, the last layer linear."""
    layers = [linear_block(a, b) for a, b in zip(dims[:-2], dims[1:-1])]
    return nn.Sequential(*layers, nn.Linear(dims[-2], dims[-1]))


class ShapeDescriptor(nn.Module):
    """N_E / N_D over the hanging part's offsets (B, n, 3) in metres. ``basis`` (3n, P) orthonormal,
    ``mean`` (3n,), ``scale`` the coefficients' RMS (m)."""

    def __init__(self, mean: torch.Tensor, basis: torch.Tensor, scale: float, dims: int, hidden: tuple[int, ...]):
        super().__init__()
        self.register_buffer("mean", mean.float())
        self.register_buffer("basis", basis.float())
        self.register_buffer("scale", torch.tensor(float(scale)))
        p = basis.shape[1]
        self.enc = mlp([p, *hidden, dims])
        self.dec = mlp([dims, *reversed(hidden), p])
        self.enc_linear = nn.Linear(p, dims, bias=False)
        self.dec_linear = nn.Linear(dims, p, bias=False)
        with torch.no_grad():  # start as PCA: the linear paths keep the first ``dims`` components
            self.enc_linear.weight.copy_(torch.eye(dims, p))
            self.dec_linear.weight.copy_(torch.eye(p, dims))
            for net in (self.enc, self.dec):
                net[-1].weight.mul_(0.01)
                net[-1].bias.zero_()

    def coefficients(self, offsets: torch.Tensor) -> torch.Tensor:
        return ((offsets.reshape(len(offsets), -1) - self.mean) @ self.basis) / self.scale

    def vertices(self, coeffs: torch.Tensor) -> torch.Tensor:
        return (coeffs * self.scale @ self.basis.T + self.mean).view(len(coeffs), -1, 3)

    def encode_coefficients(self, c: torch.Tensor) -> torch.Tensor:
        return self.enc_linear(c) + self.enc(c)

    def decode_coefficients(self, s: torch.Tensor) -> torch.Tensor:
        return self.dec_linear(s) + self.dec(s)

    def encode(self, offsets: torch.Tensor) -> torch.Tensor:
        return self.encode_coefficients(self.coefficients(offsets))

    def decode(self, s: torch.Tensor) -> torch.Tensor:
        return self.vertices(self.decode_coefficients(s))


class UBlock(nn.Module):
    """U(x | M_D) = Psi(sum_i M_D^i L_i(x)): ``subnets`` linear maps blended per sample (eq. 3.4)."""

    def __init__(self, i: int, o: int, subnets: int, act: bool = True):
        super().__init__()
        self.weight = nn.Parameter(torch.randn(subnets, i, o) * (2.0 / i) ** 0.5 * (1.0 if act else 0.5))
        self.bias = nn.Parameter(torch.zeros(subnets, o))
        self.act = nn.PReLU() if act else nn.Identity()

    def forward(self, x: torch.Tensor, md: torch.Tensor) -> torch.Tensor:
        m, i, o = self.weight.shape
        each = (x @ self.weight.permute(1, 0, 2).reshape(i, m * o)).view(-1, m, o)  # every sub-network's output
        return self.act(torch.einsum("bm,bmo->bo", md, each) + md @ self.bias)


class MotionEncoder(nn.Module):
    """M_E: motion signature -> M_D, non-negative (Softplus) and summing to 1 (a blend)."""

    def __init__(self, inputs: int, hidden: tuple[int, ...], subnets: int):
        super().__init__()
        self.net = mlp([inputs, *hidden, subnets])

    def forward(self, m: torch.Tensor) -> torch.Tensor:
        d = nn.functional.softplus(self.net(m))
        return d / d.sum(-1, keepdim=True)


class UNet(nn.Module):
    """A sequence of U-blocks sharing one motion descriptor; the last block linear."""

    def __init__(self, dims: list[int], subnets: int):
        super().__init__()
        self.blocks = nn.ModuleList(UBlock(a, b, subnets, act=k < len(dims) - 2)
                                    for k, (a, b) in enumerate(zip(dims[:-1], dims[1:])))

    def forward(self, x: torch.Tensor, md: torch.Tensor) -> torch.Tensor:
        for b in self.blocks:
            x = b(x, md)
        return x


class IntrinsicAutoencoder(nn.Module):
    """F_E(S | M) = z and F_D(z | M) = S, with the motion encoder M_E. ``architecture`` "ublock"
    (the paper's), or "concat": standard MLPs on [S or z, motion features] (its first ablation).
    z leaves F_E batch-normalised without scale (over batches of many parameter sets): Var(z)
    alone is zeroed by shrinking z, at no cost to reconstruction."""

    def __init__(self, signature_dims: int, cfg: AuthorConfig):
        super().__init__()
        self.cfg = cfg
        self.motion_mean = nn.Parameter(torch.zeros(signature_dims), requires_grad=False)
        self.motion_std = nn.Parameter(torch.ones(signature_dims), requires_grad=False)
        enc = [cfg.shape_dims] + [cfg.latent] * cfg.blocks
        dec = [cfg.latent] * cfg.blocks + [cfg.shape_dims]
        if cfg.architecture == "ublock":
            self.motion = MotionEncoder(signature_dims, cfg.motion_hidden, cfg.subnets)
            self.f_e, self.f_d = UNet(enc, cfg.subnets), UNet(dec, cfg.subnets)
        else:
            self.motion = mlp([signature_dims, *cfg.motion_hidden, cfg.subnets])
            self.f_e = mlp([enc[0] + cfg.subnets, *enc[1:]])
            self.f_d = mlp([dec[0] + cfg.subnets, *dec[1:]])
        self.z_norm = nn.BatchNorm1d(cfg.latent, affine=False)

    def motion_descriptor(self, sig: torch.Tensor) -> torch.Tensor:
        return self.motion((sig - self.motion_mean) / self.motion_std)

    def _run(self, net, x, md):
        return net(x, md) if self.cfg.architecture == "ublock" else net(torch.cat([x, md], -1))

    def encode(self, s: torch.Tensor, md: torch.Tensor) -> torch.Tensor:
        return self.z_norm(self._run(self.f_e, s, md))

    def decode(self, z: torch.Tensor, md: torch.Tensor) -> torch.Tensor:
        return self._run(self.f_d, z, md)


class AuthorModel(nn.Module):
    """One outfit's authoring networks: the hanging part ``index`` (its vertices in the outfit), the
    shape descriptor and the motion-invariant autoencoder."""

    def __init__(self, index: torch.Tensor, descriptor: ShapeDescriptor, autoencoder: IntrinsicAutoencoder,
                 outfit: str, cfg: AuthorConfig):
        super().__init__()
        self.register_buffer("index", index.long())
        self.descriptor, self.autoencoder = descriptor, autoencoder
        self.outfit, self.cfg = outfit, cfg

    @torch.no_grad()
    def latent(self, offsets: torch.Tensor, sig: torch.Tensor) -> torch.Tensor:
        """Hanging-part offsets (B, n, 3) in the heading frame, signatures (B, D) -> z (B, K_z)."""
        return self.autoencoder.encode(self.descriptor.encode(offsets), self.autoencoder.motion_descriptor(sig))

    @torch.no_grad()
    def offsets(self, z: torch.Tensor, sig: torch.Tensor, chunk: int = 512) -> torch.Tensor:
        """z (B, K_z) on motions (B, D) -> hanging-part offsets (B, n, 3) in the heading frame."""
        out = []
        for s in range(0, len(z), chunk):
            md = self.autoencoder.motion_descriptor(sig[s:s + chunk])
            out.append(self.descriptor.decode(self.autoencoder.decode(z[s:s + chunk], md)))
        return torch.cat(out)

    def save(self, path: Path, meta: dict) -> Path:
        state = {k: v.half() if v.is_floating_point() and v.numel() > 4096 else v
                 for k, v in self.state_dict().items()}
        blob = {"state": state, "config": asdict(self.cfg), "outfit": self.outfit, "n": int(len(self.index)),
                "pca": int(self.descriptor.basis.shape[1]), "signature": int(self.autoencoder.motion_mean.numel()),
                "meta": meta}
        paths.atomic_write(path, lambda t: torch.save(blob, t))
        return Path(path)

    @classmethod
    def load(cls, path: Path) -> tuple[AuthorModel, dict]:
        blob = torch.load(path, map_location="cpu", weights_only=True)
        saved = {"base": "pbns", "network_share": 1.0} | blob["config"]  # files from before these options
        cfg = AuthorConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in saved.items()})
        n, p = blob["n"], blob["pca"]
        desc = ShapeDescriptor(torch.zeros(3 * n), torch.zeros(3 * n, p), 1.0, cfg.shape_dims, cfg.shape_hidden)
        model = cls(torch.zeros(n, dtype=torch.long), desc, IntrinsicAutoencoder(blob["signature"], cfg),
                    blob["outfit"], cfg)
        model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in blob["state"].items()})
        return model.eval(), blob["meta"]


def interpolate_latents(z_keys: torch.Tensor, frames: list[int], t: int, loop: bool = False) -> torch.Tensor:
    """z at every frame (T, K_z) from z at the keyframes ``frames`` (sorted) by linear interpolation,
    held before the first and after the last; with ``loop``, interpolated across the clip's end."""
    f = torch.tensor(frames, dtype=torch.float32)
    ts = torch.arange(t, dtype=torch.float32)
    if len(frames) == 1:
        return z_keys[:1].expand(t, -1).clone()
    if loop:  # the first keyframe again after the end, the last before the start
        f = torch.cat([f[-1:] - t, f, f[:1] + t])
        z_keys = torch.cat([z_keys[-1:], z_keys, z_keys[:1]])
    k = torch.searchsorted(f, ts, right=True).clamp(1, len(f) - 1)
    a = ((ts - f[k - 1]) / (f[k] - f[k - 1])).clamp(0, 1)[:, None]
    return (1 - a) * z_keys[k - 1] + a * z_keys[k]


def residual_weights(frames: list[int], t: int, fade: int | None, loop: bool = False) -> torch.Tensor:
    """(T, K) weights of each keyframe's residual per frame: 1 at it, falling linearly to 0 over
    min(``fade``, the gap to its nearest other keyframe) frames, so a keyframe is matched exactly;
    ``fade`` None: interpolated between keyframes as z is (held beyond)."""
    if fade is None:
        return interpolate_latents(torch.eye(len(frames)), frames, t, loop)
    f = torch.tensor(frames, dtype=torch.float32)
    ts = torch.arange(t, dtype=torch.float32)
    d = (ts[:, None] - f[None]).abs()
    if loop:
        d = torch.minimum(d, t - d)
    reach = torch.full((len(frames),), float(fade))
    if len(frames) > 1:
        gap = (f[:, None] - f[None]).abs()
        if loop:
            gap = torch.minimum(gap, t - gap)
        gap.fill_diagonal_(float("inf"))
        reach = torch.minimum(reach, gap.min(1).values)
    return (1 - d / reach.clamp(min=1)).clamp(min=0)


class Session:
    """Authoring one clip: ``Session(model, static, yaw, joints)`` with the cloth the model's
    offsets are taken from (``clip_inputs``: PBNS's drape or NCS's cloth of the whole outfit, T x N x
    3), the character's heading (T, 3, 3) and the joints (T, 24, 3) per frame;
    ``set_key(frame, vertices)`` with the outfit (N, 3) as wanted at that frame, then
    ``propagate()`` -> the outfit on every frame (T, N, 3); ``fps`` the last propagation's rate."""

    def __init__(self, model: AuthorModel, static: torch.Tensor, yaw: torch.Tensor, joints: torch.Tensor,
                 loop: bool = False, fade: int | None = None):
        self.model, self.loop, self.fade = model, loop, fade
        self.keys: dict[int, torch.Tensor] = {}
        self.fps = float("nan")
        self.set_motion(static, yaw, joints)

    def set_motion(self, static: torch.Tensor, yaw: torch.Tensor, joints: torch.Tensor) -> None:
        """A new or edited body motion (the keyframes' meshes stay as they were given)."""
        self.static, self.yaw = static.float(), yaw.float()
        self.sig = self.model.cfg.signature(joints.float(), self.yaw, self.loop)

    def __len__(self) -> int:
        return len(self.static)

    def set_key(self, frame: int, vertices: torch.Tensor) -> None:
        if not 0 <= frame < len(self):
            raise ValueError(f"keyframe {frame} outside the clip's frames 0..{len(self) - 1}")
        if vertices.shape != self.static.shape[1:]:
            raise ValueError(f"a keyframe needs the outfit's {self.static.shape[1]} vertices, "
                             f"got {tuple(vertices.shape)}")
        self.keys[int(frame)] = vertices.float()

    def remove_key(self, frame: int) -> None:
        self.keys.pop(int(frame), None)

    def local(self, frames, world: torch.Tensor) -> torch.Tensor:
        """Outfit vertices (K, N, 3) at ``frames`` -> offsets from PBNS's drape in the heading frame."""
        return torch.einsum("kji,knj->kni", self.yaw[frames], world - self.static[frames])

    def key_offsets(self) -> tuple[list[int], torch.Tensor]:
        """The keyframes in order and their outfits as offsets from PBNS's drape (K, N, 3), heading frame."""
        frames = sorted(self.keys)
        return frames, self.local(frames, torch.stack([self.keys[f] for f in frames]))

    def latents(self, key_offsets: torch.Tensor | None = None) -> torch.Tensor:
        """z at each keyframe (K, K_z), in keyframe order (``key_offsets``: ``key_offsets()``'s, if at hand)."""
        frames, off = self.key_offsets() if key_offsets is None else (sorted(self.keys), key_offsets)
        return self.model.latent(off[:, self.model.index], self.sig[frames])

    @torch.no_grad()
    def propagate(self, latents: torch.Tensor | None = None, residuals: bool = True) -> torch.Tensor:
        """The outfit (T, N, 3) on every frame. ``latents``: z per frame (T, K_z) to decode instead of
        the keyframes' (another clip's material); ``residuals``: match the keyframes exactly."""
        if latents is None and not self.keys:
            raise ValueError("no keyframe: set one with set_key (or pass latents)")
        t0 = time.perf_counter()
        frames, keys = self.key_offsets() if self.keys else ([], None)
        z = latents if latents is not None else interpolate_latents(self.latents(keys), frames, len(self), self.loop)
        local = torch.zeros_like(self.static)
        local[:, self.model.index] = self.model.offsets(z, self.sig)
        if residuals and frames:
            local = local * self.model.cfg.network_share  # the rest: the keyframes' offsets interpolated
            res = keys - local[frames]
            w = residual_weights(frames, len(self), self.fade, self.loop)
            local = local + torch.einsum("tk,kni->tni", w, res)
        out = self.static + torch.einsum("tij,tnj->tni", self.yaw, local)
        self.fps = len(self) / (time.perf_counter() - t0)
        return out
