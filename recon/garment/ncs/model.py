"""Neural Cloth Simulation (thesis ch. 6): PBNS with dynamics, a second garment model beside it.

Body motion descriptors (6.3.2), per joint, hands and feet dropped:
- static (9): the local rotation as 6D (Zhou et al.; the root's with its heading removed, as
  PBNS does) and the gravity direction unposed into the joint's global frame (eq. 6.5);
- dynamic (12): the time derivative of the static descriptor and the second derivative of the
  joint location, unposed the same way (not normalised).
Model (6.3.3): a static encoder (4 FC layers on the current pose) and a dynamic encoder without
any bias (2 per-joint FC layers, 2 FC layers, one GRU), so that no motion gives a zero dynamic
code and the GRU state fades when motion stops; the codes are added and decoded in PBNS's
blend-shape form (z . D, so the .glb export stays morph targets), then skinned. D holds PBNS's
rows and ``NCSConfig.dynamic`` rows after them, the principal fields of the cloth's motion found
in training (recon.garment.ncs.train). The static code on PBNS's rows is PBNS's own (its MLP on
``pbns.pose_features``, fixed), so garments that do not hang stay PBNS's exactly (a distilled
copy drifted: the model card's NCS history); the static encoder gives the code on the new rows.
Training (6.3.4): the PBNS energies plus the inertia term (eq. 6.9, ``losses.InertiaLoss``).
Frames: the body frame, +Y up (gravity along -Y), metres; the network steps at the frame rate it
was trained at (``NCSConfig.fps``).
"""
from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from recon import paths
from recon.body import skeleton
from recon.body.base import BodyModel
from recon.errors import ReconError
from recon.garment.pbns.model import BlendShapeGarment, pose_features, pose_mlp, remove_yaw
from recon.poses.mocap import (
    FPS,  # the pose set's frame rate: NCS learns its dynamics at it
    resample,
)

DROPPED = ("left_foot", "right_foot", "left_hand", "right_hand")
KEPT = tuple(i for i, n in enumerate(skeleton.JOINT_NAMES) if n not in DROPPED)
GRAVITY = (0.0, -1.0, 0.0)  # unit direction in the body frame
SHOULDER_BAND = 0.04  # m: what holds an outfit without pins (a dress) when it swings
WAIST_BAND = 0.02  # m of cloth above the waist held with it, when NCS holds such an outfit there
LEAK = 0.1  # negative slope of the dynamic branch's activations
SMOOTH = 2.0 / FPS  # seconds: Gaussian sigma of the trajectories the dynamic descriptors differentiate


def rot6d(r: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 6): the first two columns (Zhou et al. 2019)."""
    return torch.cat([r[..., :, 0], r[..., :, 1]], -1)


def static_descriptors(rotmats: torch.Tensor, global_rotmats: torch.Tensor) -> torch.Tensor:
    """(..., 24, 3, 3) local and global joint rotations -> (..., K, 9) for the kept joints."""
    local = rotmats.clone()
    local[..., 0, :, :] = remove_yaw(local[..., 0, :, :])
    g = torch.tensor(GRAVITY, dtype=rotmats.dtype, device=rotmats.device)
    unposed = torch.einsum("...ji,j->...i", global_rotmats, g)  # R_j^T g
    return torch.cat([rot6d(local), unposed], -1)[..., KEPT, :]


def _derivative(x: torch.Tensor, fps: float, order: int) -> torch.Tensor:
    """Backward finite differences along dim 1 (time) of (B, T, ...); the first frames repeat the
    first value (a sequence starts at rest)."""
    pad = torch.cat([x[:, :1].expand(-1, order, *x.shape[2:]), x], 1)
    if order == 1:
        return (pad[:, 1:] - pad[:, :-1]) * fps
    return (pad[:, 2:] - 2 * pad[:, 1:-1] + pad[:, :-2]) * fps * fps


def smooth_time(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """Gaussian smoothing along dim 1 (time) of (B, T, ...), edges repeated (sigma in frames)."""
    if sigma <= 0 or x.shape[1] < 2:
        return x
    r = int(np.ceil(3 * sigma))
    k = torch.exp(-0.5 * (torch.arange(-r, r + 1, dtype=x.dtype) / sigma) ** 2)
    k = (k / k.sum()).to(x.device)
    b, t = x.shape[:2]
    flat = x.reshape(b, t, -1).transpose(1, 2).reshape(-1, 1, t)
    flat = torch.nn.functional.pad(flat, (r, r), mode="replicate")
    out = torch.nn.functional.conv1d(flat, k.view(1, 1, -1))
    return out.view(b, -1, t).transpose(1, 2).reshape(x.shape)


def descriptors(rotmats: torch.Tensor, global_rotmats: torch.Tensor, joints: torch.Tensor,
                fps: float = FPS, smooth: float = SMOOTH) -> tuple[torch.Tensor, torch.Tensor]:
    """Sequences (B, T, 24, 3, 3) local / global rotations and (B, T, 24, 3) joint locations ->
    static (B, T, K, 9) and dynamic (B, T, K, 12) descriptors. The derivatives are taken of
    trajectories smoothed over ``smooth`` seconds (Gaussian sigma): differentiated twice, mocap's
    frame-to-frame noise outweighs the motion (30 fps val clips: the second difference of the
    joint accelerations is larger than their mean) and a dynamic code read from it only jitters."""
    static = static_descriptors(rotmats, global_rotmats)
    sigma = smooth * fps
    accel = _derivative(smooth_time(joints, sigma), fps, 2)
    unposed = torch.einsum("btjik,btji->btjk", global_rotmats, accel)[:, :, KEPT]  # R_j^T a_j
    return static, torch.cat([_derivative(smooth_time(static, sigma), fps, 1), unposed], -1)


@dataclass
class NCSConfig:
    hidden: int = 256  # the dynamic encoder's FC layers
    static_hidden: int | None = None  # the static encoder's FC layers (None: ``hidden``, as files before it)
    joint_features: int = 32  # the dynamic encoder's per-joint layers
    embedding: int = 128  # rows of D that the static code alone reaches: PBNS's
    pbns_hidden: int = 32  # PBNS's MLP (its code on those rows): PBNSConfig.hidden, .layers
    pbns_layers: int = 4
    # rows of D after PBNS's that both codes reach, the GRU's width: the principal fields of the
    # cloth's motion about PBNS (its own drape's correction and the swing), set by training
    dynamic: int = 32
    fps: float = FPS  # the frame rate it was trained at: its recurrent steps are frames at this rate


class NCS(BlendShapeGarment):
    """``NCS(rest, faces, weights)``; ``codes(static, dynamic, pose, h) -> (z_static, z_dynamic,
    h)`` per sequence (B, T, ...), ``forward(static, dynamic, pose, transforms) -> (posed, dT)``,
    ``animate(...)`` for inference; ``pose`` is PBNS's input (``pbns.pose_features``, (B, T,
    216)). Skinning, D's first rows, the blend weights and the static code on them are PBNS's."""

    def __init__(self, rest: torch.Tensor, faces: torch.Tensor, weights: torch.Tensor, cfg: NCSConfig | None = None):
        cfg = cfg or NCSConfig()
        super().__init__(rest, faces, weights, cfg.embedding + cfg.dynamic)
        self.cfg = cfg
        k, h = len(KEPT), cfg.hidden
        hs = cfg.static_hidden or h
        self.pbns_mlp = pose_mlp(cfg.pbns_hidden, cfg.pbns_layers, cfg.embedding)
        self.static = nn.Sequential(nn.Linear(9 * k, hs), nn.ReLU(), nn.Linear(hs, hs), nn.ReLU(), nn.Linear(hs, hs),
                                    nn.ReLU(), nn.Linear(hs, cfg.dynamic))
        f = cfg.joint_features
        # no bias anywhere in the dynamic branch: zero motion -> zero code (6.3.3). Leaky: without
        # biases a ReLU unit fed by ReLU outputs (all >= 0) dies for good once its weights turn
        # negative; with ReLUs the whole branch died within a few hundred steps (every hidden unit off)
        act = nn.LeakyReLU(LEAK)
        self.per_joint = nn.Sequential(nn.Linear(12, f, bias=False), act, nn.Linear(f, f, bias=False), act)
        self.dynamic = nn.Sequential(nn.Linear(k * f, h, bias=False), act, nn.Linear(h, cfg.dynamic, bias=False))
        self.gru = nn.GRU(cfg.dynamic, cfg.dynamic, bias=False, batch_first=True)

    @classmethod
    def from_pbns(cls, pbns: BlendShapeGarment, cfg: NCSConfig | None = None) -> NCS:
        """An NCS with a trained PBNS's template, blend weights, D (its dynamic rows zero) and MLP."""
        cfg = replace(cfg or NCSConfig(), embedding=pbns.D.shape[0], pbns_hidden=pbns.cfg.hidden,
                      pbns_layers=pbns.cfg.layers)
        m = cls(pbns.rest, pbns.faces, pbns.weights.detach(), cfg)
        with torch.no_grad():
            m.D[:len(pbns.D)].copy_(pbns.D)
            m.weight_logits.copy_(pbns.weight_logits)
        m.pbns_mlp.load_state_dict(pbns.mlp.state_dict())
        return m

    def decode(self, x: torch.Tensor) -> torch.Tensor:
        """Codes (..., E) -> rest-pose displacements (..., N, 3). Without gradients the new rows are
        applied only where they move anything (the hanging part; training leaves them zero
        elsewhere): a batch-1 frame reads all of D from memory, and a dress's moves 10,672 of
        its 17,454 vertices."""
        if torch.is_grad_enabled():
            return super().decode(x)
        e = self.cfg.embedding
        cols, rows = self._new_rows()
        out = x[..., :e] @ self.D[:e]
        out.index_add_(-1, cols, x[..., e:] @ rows)
        return out.view(*x.shape[:-1], -1, 3)

    def _new_rows(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The columns of D where its new rows are non-zero and those rows there, cached until D
        changes (like ``weights``)."""
        key = (self.D.data_ptr(), self.D._version)
        if getattr(self, "_new_rows_key", None) != key:
            d = self.D.detach()[self.cfg.embedding:]
            cols = torch.nonzero(d.abs().amax(0) > 0)[:, 0]
            self._new_rows_cache = (cols, d[:, cols].contiguous())
            self._new_rows_key = key
        return self._new_rows_cache

    def static_code(self, static: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
        """(..., K * 9) flat static descriptors and (..., 216) PBNS inputs -> the static code
        (..., E): PBNS's on its rows, the static encoder's on the new ones."""
        return torch.cat([self.pbns_mlp(pose), self.static(static)], -1)

    def codes(self, static: torch.Tensor, dynamic: torch.Tensor, pose: torch.Tensor, h: torch.Tensor | None = None):
        """(B, T, K, 9), (B, T, K, 12), (B, T, 216) -> static code, dynamic code (B, T, E) and the
        GRU state. The dynamic code is zero on PBNS's rows."""
        b, t = static.shape[:2]
        zs = self.static_code(static.reshape(b, t, -1), pose)
        zd, h = self.gru(self.dynamic(self.per_joint(dynamic).reshape(b, t, -1)), h)
        return zs, nn.functional.pad(zd, (self.cfg.embedding, 0)), h

    def deformation(self, static, dynamic, pose, h=None, motion: float = 1.0):
        """Rest-pose displacements (B, T, N, 3) and the GRU state. ``motion`` scales the dynamic
        code (the thesis' motion control, 6.4.6: 0 = the static model, > 1 = livelier)."""
        zs, zd, h = self.codes(static, dynamic, pose, h)
        return self.decode(zs + motion * zd), h

    def skin_frames(self, x: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
        """LBS of rest-pose points (B, T, N, 3) with the body's transforms (B, T, 24, 3, 4)."""
        b, t = transforms.shape[:2]
        return self.skin(x.flatten(0, 1), transforms.flatten(0, 1)).view(b, t, -1, 3)

    def forward(self, static, dynamic, pose, transforms, h=None, motion: float = 1.0):
        dt, h = self.deformation(static, dynamic, pose, h, motion)
        return self.skin_frames(self.rest + dt, transforms), dt

    def animate(self, static: torch.Tensor, dynamic: torch.Tensor, pose: torch.Tensor, transforms: torch.Tensor,
                rest: torch.Tensor | None = None, motion: float = 1.0, h: torch.Tensor | None = None):
        """Inference on one sequence: ``motion_inputs``' descriptors (T, K, 9), (T, K, 12), PBNS
        inputs (T, 216) and transforms (T, 24, 3, 4) -> posed vertices (T, N, 3) and the GRU state
        (pass it back with the next frames to stream). ``rest``: the outfit resized to the body
        (default the template)."""
        with torch.no_grad():
            zs, zd, h = self.codes(static[None], dynamic[None], pose[None], h)
            return self.pose_codes((zs + motion * zd)[0], transforms, rest), h

    def motion_codes(self, body: BodyModel, rotmats: torch.Tensor, shape: torch.Tensor,
                     transl: torch.Tensor | None = None, fps: float = FPS) -> tuple[torch.Tensor, torch.Tensor]:
        """The static and dynamic codes (T, E) of a motion (T, 24, 3, 3) at ``fps``, from rest:
        ``pose_codes(z_static + motion * z_dynamic, ...)`` dresses it (motion control). The
        network steps at the rate it was trained at: the motion is resampled to it and the codes
        interpolated back to the motion's frames."""
        rate = self.cfg.fps
        resampled = abs(rate - fps) > 1e-6
        r, tr = rotmats, transl
        with torch.no_grad():
            if resampled:
                tr0 = torch.zeros(len(rotmats), 3) if transl is None else transl
                r, tr = (torch.from_numpy(x).float() for x in resample(rotmats.numpy(), tr0.numpy(), fps, rate))
            static, dynamic, pose, _ = motion_inputs(body, r, shape, tr, rate)
            zs, zd, _ = self.codes(static[None], dynamic[None], pose[None])
        zs, zd = zs[0], zd[0]
        if resampled:
            t = np.arange(len(rotmats)) / fps * rate  # each frame's time in network steps
            i0 = np.minimum(np.floor(t).astype(int), len(zs) - 1)
            i1 = np.minimum(i0 + 1, len(zs) - 1)
            w = torch.from_numpy(np.clip(t - i0, 0, 1)).float()[:, None]
            zs, zd = ((1 - w) * z[i0] + w * z[i1] for z in (zs, zd))
        return zs, zd

    def save(self, path: Path, extra: dict, pbns_path: Path | None = None) -> None:
        """The weights file. Given the PBNS file it was built from (in the same folder), it keeps
        only what NCS adds (its encoders and D's new rows where they are non-zero) and names that
        file with a digest of the parts it shares; else everything, as ``BlendShapeGarment.save``."""
        if pbns_path is None or Path(pbns_path).resolve().parent != Path(path).resolve().parent:
            return super().save(path, extra)
        pck = paths.load_checkpoint(pbns_path, "recon garment train")
        mine = {k: v for k, v in self.state_dict().items()}
        mine["D"] = mine["D"].half()
        shared = _shared_parts(mine, self.cfg.embedding)
        if any(not torch.equal(v, pck["state"][k]) for k, v in shared.items()):
            return super().save(path, extra)  # trained apart from that PBNS: keep it whole
        cols, rows = self._new_rows()
        own = {k: v for k, v in mine.items() if k != "D" and k not in _shared_keys(mine)}
        own |= {"D_new_cols": cols.int(), "D_new_rows": rows.half()}
        extra = {k: v for k, v in extra.items() if k not in PBNS_EXTRAS or not torch.equal(v, pck[k])}
        state = {"cfg": asdict(self.cfg), "state": own,
                 "pbns": {"file": Path(pbns_path).name, "digest": _digest(pck["state"])}} | extra
        paths.atomic_write(Path(path), lambda t: torch.save(state, t))

    @classmethod
    def load(cls, path: Path) -> tuple[NCS, dict]:
        ck = paths.load_checkpoint(path, "recon garment train --model ncs")
        if "pbns" in ck:
            ck = _with_pbns_parts(Path(path), ck)
        sd = ck["state"]
        m = cls(sd["rest"], sd["faces"], torch.softmax(sd["weight_logits"], -1), NCSConfig(**ck["cfg"]))
        m.load_state_dict(sd)
        return m.eval(), ck


# an NCS file shares these with its PBNS: template, blend weights, D's first rows, the pose MLP
PBNS_EXTRAS = ("layer", "garment_id", "shape")


def _shared_keys(sd: dict) -> list[str]:
    return ["rest", "faces", "weight_logits"] + [k for k in sd if k.startswith("pbns_mlp.")]


def _shared_parts(sd: dict, embedding: int) -> dict[str, torch.Tensor]:
    """NCS's state entries that are its PBNS's, under the PBNS's names."""
    parts = {k.removeprefix("pbns_"): sd[k] for k in _shared_keys(sd)}
    return parts | {"D": sd["D"][:embedding]}


def _digest(pbns_state: dict) -> str:
    """sha256 of a PBNS state's tensors (names, dtypes, shapes, bytes) in name order."""
    h = hashlib.sha256()
    for k in sorted(pbns_state):
        v = pbns_state[k].contiguous()
        h.update(f"{k}:{v.dtype}:{tuple(v.shape)}".encode())
        h.update(v.view(torch.uint8).numpy().tobytes() if v.numel() else b"")
    return h.hexdigest()


def _with_pbns_parts(path: Path, ck: dict) -> dict:
    """A compact NCS checkpoint completed from the PBNS file it names (same folder)."""
    pbns_path = path.parent / ck["pbns"]["file"]
    pck = paths.load_checkpoint(pbns_path, "recon garment train")
    if _digest(pck["state"]) != ck["pbns"]["digest"]:
        raise ReconError(f"{path} was trained on another {pbns_path.name}: retrain it "
                         "(`recon garment train --model ncs`)")
    ps, own = pck["state"], dict(ck["state"])
    cols, rows = own.pop("D_new_cols").long(), own.pop("D_new_rows")
    d = torch.zeros(len(ps["D"]) + len(rows), ps["D"].shape[1], dtype=rows.dtype)
    d[:len(ps["D"])] = ps["D"]
    d[len(ps["D"]):, cols] = rows
    state = own | {"D": d} | {k: ps[k] for k in ("rest", "faces", "weight_logits")}
    state |= {f"pbns_{k}": v for k, v in ps.items() if k.startswith("mlp.")}
    return {k: pck[k] for k in PBNS_EXTRAS} | ck | {"state": state}


def motion_inputs(body: BodyModel, rotmats: torch.Tensor, shape: torch.Tensor, transl: torch.Tensor | None = None,
                  fps: float = FPS):
    """A body motion (T, 24, 3, 3) local rotations (+Y up), shape (S,), translation (T, 3) ->
    static (T, K, 9) and dynamic (T, K, 12) descriptors, PBNS's inputs (T, 216) and the joint
    transforms (T, 24, 3, 4)."""
    with torch.no_grad():
        o = body(rotmats, shape.reshape(1, -1).expand(len(rotmats), -1), transl=transl, points_only=True)
        s, d = descriptors(rotmats[None], o.global_rotmats[None], o.joints[None], fps)
    return s[0], d[0], pose_features(rotmats), o.transforms


def hanging_part(outfit, waist: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(hanging, held): the vertices that swing with the body's motion, and those of them that
    move with the skinned outfit. Garments with pinned vertices (a skirt hangs from its waist)
    hang, held by their pins. An outfit with none (a dress) hangs whole, held by a band of
    ``SHOULDER_BAND`` m at the top of each garment (the dynamic reference, VBD without friction,
    lets a dress that only rests on the shoulders slide off: its hem 1.5 m down within 2 s of a
    turn); or, given the rest body's ``waist`` height (m), only below it, held along
    ``WAIST_BAND`` m above it (NCS: a dress's bodice sits on the torso and stays PBNS's, its skirt
    hangs from the waist as a skirt does). Both (N,) bool."""
    held = np.unique(outfit.garment_id[outfit.pinned])
    if len(held):
        return np.isin(outfit.garment_id, held), outfit.pinned.copy()
    y = outfit.vertices[:, 1]
    if waist is not None:
        hanging = y < waist + WAIST_BAND
        return hanging, hanging & (y >= waist)
    top = np.zeros(len(y), bool)
    for g in np.unique(outfit.garment_id):
        mine = outfit.garment_id == g
        top |= mine & (y >= y[mine].max() - SHOULDER_BAND)
    return np.ones(len(y), bool), top


def vertex_masses(vertices: np.ndarray, faces: np.ndarray, density: float = 0.15) -> np.ndarray:
    """Lumped masses (N,) in kg: a third of each adjacent face's area times ``density`` (kg/m^2;
    0.15: a light cotton)."""
    a = 0.5 * np.linalg.norm(np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                                      vertices[faces[:, 2]] - vertices[faces[:, 0]]), axis=1)
    m = np.zeros(len(vertices))
    np.add.at(m, faces.ravel(), np.repeat(a / 3.0, 3))
    return (density * m).astype(np.float32)
