"""Training of NCS outfits (``recon garment train --model ncs``, thesis 6.3.4): the PBNS energies
(recon.garment.losses, the fabric of the outfit's PBNS) plus the inertia term of eq. 6.9 with the
previous states constants, on motion cut from the retargeted mocap's train split at 30 fps. No
simulator and no cloth data: only the body's motion and the energies.

The thesis trains the network on that loss directly, the previous states being the network's own
earlier predictions, so the swing grows by about one frame's worth each time the network has
converged on the last one: one hour to a day on a GPU. On a CPU budget of 30 minutes that loop
learnt ~1 mm of motion against the simulation's 16-27 cm (docs/garments.md). Here the same loss is
minimised frame after frame by a solver instead (recon.garment.integrate), which gives the loss's
fixed point, the cloth trajectory the thesis' training converges to, and the network learns it:

1. chunks: ``chunk`` frames of the train split's clips (smoothed by ``smooth_motion``); the cloth
   settles ``settle`` frames on each chunk's first pose, then is integrated through the chunk in
   ``workers`` processes (each chunk's posed offsets from PBNS's drape kept in ``<cache>/ncs-chunks/``
   as it is done: ``chunk_folder``); a chunk with an edge strained past ``max_strain`` is dropped,
   the others unposed into rest-pose displacements (``min_singular``);
2. fields: the principal components of the cloth's rest-pose displacement from PBNS over every
   frame (mass-weighted), ``NCSConfig.dynamic`` of them, become the rows of D after PBNS's: PBNS
   is not the energies' equilibrium (settled on a still body, a skirt's cloth moves 4-7 cm from
   PBNS's drape), so the displacement holds a static correction as well as the swing; cloth at
   the ankles stays PBNS's (``ankle_hold``);
3. networks: the static encoder and the bias-free dynamic branch are fitted to the chunks'
   coefficients on the new rows (frames after ``lead``, the swing building up), the two codes
   adding as the thesis' model adds them; the static code on PBNS's rows is PBNS's MLP, fixed.
   The chunks and their left-right mirror images train; chunks of the val performers select the
   checkpoint;
4. physics: ``physics_steps`` more steps add the thesis' loss of the predictions against the
   solved past (``Physics``) to the fitting, and with ``field_lr`` train the fields (D's new
   rows) as well, as the thesis trains its decoder.

Motion augmentation (6.4.6) trains the thesis' decoder on swapped dynamic codes under the static
energies; here the decoder's rows are fields found from the solved cloth (trained further only by
the physics steps), and it is not used.
Motion control (scaling the dynamic code at inference) is the model's (``NCS.deformation``).
"""
from __future__ import annotations

import hashlib
import json
import multiprocessing as mp
import shutil
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import roma
import torch
from scipy.spatial import cKDTree

from recon import paths
from recon.body import default_body, skeleton
from recon.body.lbs import mirror_rotmats
from recon.garment import losses as L
from recon.garment import store
from recon.garment.data import pose_set, posed_bodies, trained_outfit
from recon.garment.integrate import IntegrateConfig, Preconditioner, integrate, settle, unpose
from recon.garment.mesh import faces_within, nearest, nearest_among
from recon.garment.metrics import collision_pct, penetration
from recon.garment.ncs import (
    FPS,
    NCS,
    InertiaConfig,
    InertiaLoss,
    NCSConfig,
    descriptors,
    hanging_part,
    smooth_time,
    static_descriptors,
    vertex_masses,
)
from recon.garment.pbns import PBNS, pose_features
from recon.garment.templates import GarmentSpec, Outfit
from recon.garment.train import GarmentTrainConfig, run_dir_for
from recon.garment.train import candidates as pose_candidates
from recon.poses.mocap import MocapPoses
from recon.training import Trainer

_FABRIC = GarmentTrainConfig()  # NCS trains on the fabric its PBNS was trained with
DYNAMIC_BRANCH = ("per_joint", "dynamic", "gru")  # NCS's modules that read the motion


@dataclass
class NCSTrainConfig:
    outfit: str = "tshirt-skirt"
    chunk: int = 120  # frames of motion per integrated trajectory (4 s at 30 fps)
    settle: int = 20  # frames on a chunk's first pose held still, before it
    lead: int = 20  # a chunk's first frames, not learnt from: its swing builds up from rest
    chunks: int = 50  # train chunks (x2 with their mirror images)
    # the share of train chunks whose body stops dead (its pose held) halfway: the train split
    # (dance, climbing, walks) has few stops, and a stop is where the cloth swings on most
    stops: float = 0.3
    val_chunks: int = 4  # chunks of the val performers (as many stopping), to select the checkpoint
    workers: int = 2  # processes integrating chunks
    # edges as stiff across as along in the solver's preconditioner: factorised once, not each frame
    integrate: IntegrateConfig = field(default_factory=lambda: IntegrateConfig(iterations=20, across=1.0))
    mirror: bool = True  # the chunks' left-right mirror images train too (pose mirroring, 6.4.4)
    smooth_motion: float = 1.5  # Gaussian sigma (frames) of the motions: mocap jitter is no motion
    steps: int = 3000
    batch: int = 16  # chunks per step
    lr: float = 3e-3
    weight_decay: float = 0.01
    # then the thesis' loss on the predictions (``Physics``: the energies, the inertia against the
    # solved past) joins the fitting: the principal fields, a linear space, stretch and push into
    # the body what the solver's cloth does not (edge error 0.3 mm solved, 0.9 mm in 48 fields)
    physics_steps: int = 200
    physics_chunks: int = 4  # chunks per step
    physics_frames: int = 8  # frames per chunk
    physics_lr: float = 1e-3
    # the new rows of D (the fields) learn in the physics steps too, at this learning rate (Adam: about
    # metres per step), on the hanging part only, as the thesis' decoder learns from its loss: the
    # principal fields are a linear space that puts tight cloth (trousers) into the body where the
    # solver's does not (the val chunks' solved trousers projected on 96 fields: 1.91 % of their
    # vertices inside against 0.11) and stretches it (val clips, fixed -> trained fields: the
    # trousers 1.89 -> 1.66 %, the skirt's edge error 0.82 -> 0.76 mm). 0: the principal fields stay
    field_lr: float = 1e-3
    # the fitting also keeps the predicted hanging part out of the body (``Contact``) at
    # ``contact_frames`` of every 4th frame after the lead of each train chunk a step, its nearest
    # body vertex searched among the 16 nearest the solved cloth; in units of a mean squared
    # displacement per mean squared penetration past the collision energy's eps. 0: off
    contact_weight: float = 0.0
    contact_frames: int = 8
    # the physics steps also score NCS's static part (motion control 0) by PBNS's own loss, the whole
    # outfit's energies, at ``static_poses`` poses of the train split (``StaticPoses``), ``static_batch``
    # a step: the chunks hold few poses, and the static part alone put the skirt inside the body on
    # the val clips 1.6x as often as PBNS (1.68 % of its vertices against 1.04). 0: off
    static_poses: int = 1000
    static_batch: int = 8
    static_weight: float = 1.0
    # and they hold NCS's whole prediction to what any cloth state meets, no vertex inside the body
    # and no edge stretched (``FreeMotion``: the collision, edge and pin energies), at
    # ``free_frames`` frames of ``free_batch`` of ``free_windows`` chunks of the train split's motion
    # that no teacher solved (besides its own): the dynamic branch pushed the skirt into the body on
    # the val clips where its static part did not. 0: off
    free_windows: int = 200
    free_batch: int = 4
    free_frames: int = 8
    free_weight: float = 3.0
    # an outfit without pins (a dress, a jumpsuit) swings below the waist only, its top held to PBNS
    # (``hanging_part`` with the waist): a dress's bodice sits on the torso, and its fields, fitted
    # to few chunks, pushed it into the body (MODEL_CARD's NCS history); a third fewer vertices to solve
    waist_hold: bool = True
    # cloth below the rest body's ankles + this (m) stays PBNS's, D's new rows zero there, rising to
    # the whole solved displacement over as much again above (``ankle_taper``): long trousers' cuffs
    # lie on the feet, whose rotations the descriptors drop (6.3.2), and NCS's static part pushed
    # them into the feet (the val clips: 1.83 % of the outfit inside the body against PBNS's 1.44,
    # the excess all in cloth > 4 cm off the rest body, at the ankles). 0: off. No other outfit
    # reaches that low
    ankle_hold: float = 0.08
    # a solved chunk with an edge this much longer or shorter (m) than at rest, in any frame, went
    # wrong (the cloth caught between the legs, or the solver lost it): dropped from training. Sound
    # chunks of the skirt and the dress stay under 30 mm (most under 17), failed ones reach 38 mm to
    # metres
    max_strain: float = 0.035
    # the solved offsets are unposed with the blended skinning rotations' singular values clamped
    # from below at this (integrate.unpose): blends between the legs are near singular, and their
    # exact inverse put 20 cm of a skirt's posed swing kilometres away in the rest pose
    min_singular: float = 0.2
    seed: int = 0
    # 96 fields and a static encoder of 256: closer to the val chunks' solved cloth than 48 fields and
    # 128, the hem and the strain a little better on the val clips (MODEL_CARD's NCS history)
    model: NCSConfig = field(default_factory=lambda: NCSConfig(hidden=128, static_hidden=256,
                                                                joint_features=16, dynamic=96))
    edge: L.EdgeConfig = field(default_factory=lambda: _FABRIC.edge)
    bend: L.BendConfig = field(default_factory=lambda: _FABRIC.bend)
    collision: L.CollisionConfig = field(default_factory=lambda: _FABRIC.collision)
    gravity: L.GravityConfig = field(default_factory=lambda: _FABRIC.gravity)
    pin: L.PinConfig = field(default_factory=lambda: _FABRIC.pin)
    inertia: InertiaConfig = field(default_factory=lambda: InertiaConfig(weight=_FABRIC.gravity.weight / 9.81))


def rest_joint_height(body, shape: torch.Tensor, *names: str) -> float:
    """The height (m, +Y) of the highest of the joints ``names`` in the rest body of ``shape``."""
    with torch.no_grad():
        _, joints = body.rest_geometry(shape.reshape(1, -1).to(body.mean_shape))
    return float(joints[0, [skeleton.JOINT_NAMES.index(n) for n in names], 1].max())


def moving_part(body, outfit: Outfit, shape: torch.Tensor, cfg: NCSTrainConfig) -> tuple[np.ndarray, np.ndarray]:
    """NCS's (hanging, held) vertices of an outfit (``hanging_part``): an unpinned one held above the
    rest body's waist (its pelvis joint + ``GarmentSpec.waist``, where a skirt is pinned) with
    ``cfg.waist_hold``."""
    if not cfg.waist_hold:
        return hanging_part(outfit)
    return hanging_part(outfit, rest_joint_height(body, shape, "pelvis") + GarmentSpec.waist)


def ankle_taper(body, shape: torch.Tensor, vertices: np.ndarray, hold: float) -> np.ndarray:
    """Per vertex (n,) the share of the solved displacement that D's new rows take on: 0 below
    the rest body's higher ankle joint + ``hold`` (m), rising linearly to 1 over ``hold`` above
    it; all 1 with ``hold`` 0."""
    if not hold:
        return np.ones(len(vertices), np.float32)
    floor = rest_joint_height(body, shape, "left_ankle", "right_ankle") + hold
    return np.clip((vertices[:, 1] - floor) / hold, 0.0, 1.0).astype(np.float32)


class Chunk(NamedTuple):
    """``frames`` frames of clip ``clip`` of a split from its frame ``start`` (within the clip);
    with ``stop`` > 0 the body stops dead at the chunk's frame ``stop``, its pose held after it."""
    split: str
    clip: int
    start: int
    frames: int
    stop: int = 0


def chunks_of(split: str, frames: int, n: int, seed: int, stops: float = 0.0, lead: int = 0) -> list[Chunk]:
    """``n`` non-overlapping chunks of a split's clips, in a random order (clips shorter than a
    chunk give none); a share ``stops`` of them stop dead at a random frame between ``lead`` + 10
    and 30 frames before their end."""
    m = MocapPoses.load(split)
    all_chunks = [Chunk(split, int(c), s, frames) for c in np.unique(m.clip)
                  for s in range(0, int((m.clip == c).sum()) - frames + 1, frames)]
    order = np.random.default_rng(seed).permutation(len(all_chunks))[:n]
    lo = min(lead + 10, frames // 2)  # short chunks (tests) stop halfway
    out = []
    for k, i in enumerate(order):  # each chunk's own draw: the first n chunks of n + 1 are the n's
        rng = np.random.default_rng([seed, k])
        stop = int(rng.integers(lo, max(lo, frames - 30) + 1)) if rng.random() < stops else 0
        out.append(all_chunks[i]._replace(stop=stop))
    return out


class Motions:
    """The smoothed motion of each clip a list of chunks cuts (rotations, translation) and the
    chunks' NCS descriptors, taken of the whole clip (the first frames of a chunk have a past)."""

    def __init__(self, body, shape: torch.Tensor, smooth: float):
        self.body, self.shape, self.smooth = body, shape.reshape(1, -1), smooth
        self._clips: dict[tuple[str, int, bool], tuple] = {}

    def clip(self, split: str, clip: int, mirror: bool = False):
        key = (split, clip, mirror)
        if key not in self._clips:
            m = MocapPoses.load(split)
            idx = np.nonzero(m.clip == clip)[0]
            rot = roma.rotvec_to_rotmat(torch.from_numpy(m.rotvec[idx]).float())
            transl = torch.from_numpy(m.transl[idx]).float()
            if self.smooth > 0:
                rot = roma.special_procrustes(smooth_time(rot[None], self.smooth)[0])
                transl = smooth_time(transl[None], self.smooth)[0]
            if mirror:
                rot, transl = mirror_rotmats(rot, skeleton.JOINT_MIRROR), transl * torch.tensor([-1.0, 1.0, 1.0])
            with torch.no_grad():
                o = self.body(rot, self.shape.expand(len(rot), -1), transl=transl, points_only=True)
                s, d = descriptors(rot[None], o.global_rotmats[None], o.joints[None])
            self._clips[key] = (rot, transl, s[0], d[0], pose_features(rot))
        return self._clips[key]

    def motion(self, c: Chunk, mirror: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """The chunk's rotations (T, 24, 3, 3) and translation (T, 3), its first frame's pelvis
        above the origin."""
        rot, transl = self.clip(c.split, c.clip, mirror)[:2]
        f = self._frames(c)
        r, t = rot[f], transl[f]
        return r, t - t[:1] * torch.tensor([1.0, 0.0, 1.0])

    def inputs(self, c: Chunk, mirror: bool = False) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The chunk's static (T, K, 9) and dynamic (T, K, 12) descriptors and PBNS inputs (T, 216)."""
        rot, transl, s, d, p = self.clip(c.split, c.clip, mirror)
        if not c.stop:
            return s[c.start:c.start + c.frames], d[c.start:c.start + c.frames], p[c.start:c.start + c.frames]
        f = torch.cat([torch.arange(c.start), self._frames(c)])  # the clip's past, then the chunk
        with torch.no_grad():
            o = self.body(rot[f], self.shape.expand(len(f), -1), transl=transl[f], points_only=True)
            s, d = descriptors(rot[f][None], o.global_rotmats[None], o.joints[None])
        return s[0, c.start:], d[0, c.start:], p[f[c.start:]]

    @staticmethod
    def _frames(c: Chunk) -> torch.Tensor:
        """The clip's frame at each frame of the chunk (held after a stop)."""
        t = torch.arange(c.frames)
        return c.start + (t if not c.stop else t.clamp(max=c.stop))


class Teacher:
    """The integrated cloth of one outfit's hanging part: ``Teacher(body, outfit_name, cfg)(rot,
    transl)`` -> its posed offset from PBNS's drape (T, n, 3) over a motion, after ``cfg.settle``
    frames on the motion's first pose."""

    def __init__(self, body, outfit_name: str, cfg: NCSTrainConfig):
        self.body, self.cfg = body, cfg
        self.pbns, ck = PBNS.load(store.pbns_path(outfit_name))
        self.shape = ck["shape"][None]
        outfit, _, _ = trained_outfit(body, store.pbns_path(outfit_name))
        hanging, held = moving_part(body, outfit, self.shape, cfg)
        self.idx = torch.from_numpy(np.nonzero(hanging)[0])
        cloth = part_outfit(outfit, self.idx.numpy())
        self.crit = L.Criterion(cloth, self.pbns.rest[self.idx], cfg)
        self.inertia = InertiaLoss(torch.from_numpy(vertex_masses(cloth.vertices, cloth.faces)), FPS, cfg.inertia)
        self.held = torch.from_numpy(held[hanging])
        self.precond = Preconditioner(self.crit, self.inertia, self.held.numpy(), cfg.integrate.across)

    @torch.no_grad()
    def drapes(self, rot: torch.Tensor, transl: torch.Tensor):
        """PBNS's drape and the skinned outfit of the hanging part, the posed body, the blended
        skinning rotations and the joint transforms, per frame."""
        bv, bn, transforms = posed_bodies(self.body, rot, self.shape, transl=transl)
        static = self.pbns.pose(rot, transforms)[:, self.idx]
        carried = self.pbns.skin(self.pbns.rest, transforms)[:, self.idx]
        w = self.pbns.weights[self.idx]
        blend = (w @ transforms.reshape(len(rot), 24, 12)).view(len(rot), -1, 3, 4)[..., :3]
        return static, carried, bv, bn, blend, transforms

    def __call__(self, rot: torch.Tensor, transl: torch.Tensor) -> torch.Tensor:
        static, carried, bv, bn, _, _ = self.drapes(rot, transl)
        args = (self.crit, self.inertia, self.held)
        x0 = settle(*args, static[0], carried[0], bv[0], bn[0], self.cfg.settle, self.cfg.integrate, self.precond)
        x = integrate(*args, static, carried, bv, bn, self.cfg.integrate, self.precond, start=x0)
        return x - static

    @torch.no_grad()
    def rest_displacement(self, rot: torch.Tensor, transl: torch.Tensor, offset: torch.Tensor
                          ) -> tuple[torch.Tensor, float]:
        """A solved chunk's posed offsets (T, n, 3) -> its rest-pose displacements from PBNS (T, n,
        3; ``unpose`` with ``cfg.min_singular``) and its largest edge strain (m)."""
        static, _, _, _, blend, _ = self.drapes(rot, transl)
        strain = float(self.crit.edge.strain(static + offset).abs().max())
        return unpose(blend, offset, self.cfg.min_singular), strain


_WORKER: dict = {}


def _worker_init(outfit_name: str, cfg: NCSTrainConfig) -> None:
    torch.set_num_threads(1)
    _WORKER["teacher"] = Teacher(default_body(), outfit_name, cfg)


def _worker_run(rot: torch.Tensor, transl: torch.Tensor) -> np.ndarray:
    return _WORKER["teacher"](rot, transl).numpy().astype(np.float16)


def chunk_folder(pbns_path: Path, cfg: NCSTrainConfig) -> Path:
    """Where the integrated chunks of an outfit live (``<cache>/ncs-chunks/``), one folder per
    set of everything they depend on (the PBNS file, the fabric, the solver, the motions'
    smoothing, the settling): another fitting of the same chunks integrates nothing again."""
    key = json.dumps({"pbns": hashlib.sha256(Path(pbns_path).read_bytes()).hexdigest(), "offsets": "posed",
                      **{k: asdict(cfg)[k] for k in ("edge", "bend", "collision", "gravity", "pin", "inertia",
                                                     "integrate", "smooth_motion", "settle", "waist_hold")}},
                     sort_keys=True)
    return paths.cache_dir() / "ncs-chunks" / f"{Path(pbns_path).stem}-{hashlib.sha256(key.encode()).hexdigest()[:12]}"


def integrate_chunks(outfit_name: str, chunks: list[Chunk], motions: Motions, cfg: NCSTrainConfig, folder: Path,
                     log=print) -> np.ndarray:
    """The teacher's posed offsets (C, T, n, 3) float16 of ``chunks``, each kept in ``folder`` as
    it is done (a rerun takes them from there)."""
    folder.mkdir(parents=True, exist_ok=True)
    files = [folder / f"{c.split}-{c.clip}-{c.start}-{c.frames}-{c.stop}.npy" for c in chunks]
    todo = [i for i, f in enumerate(files) if not f.exists()]
    t0 = time.time()
    if todo:
        ctx = mp.get_context("spawn")  # fresh interpreters: no forked torch state
        with ProcessPoolExecutor(cfg.workers, mp_context=ctx, initializer=_worker_init,
                                 initargs=(outfit_name, cfg)) as pool:
            futures = {i: pool.submit(_worker_run, *motions.motion(chunks[i])) for i in todo}
            for k, (i, fut) in enumerate(futures.items()):
                du = fut.result()
                paths.atomic_write(files[i], lambda t, du=du: _save_npy(t, du))
                log(f"integrated {chunks[i].split} chunk {k + 1}/{len(todo)} ({time.time() - t0:.0f} s)")
    return np.stack([np.load(f) for f in files])


def _save_npy(path, array: np.ndarray) -> None:
    with open(path, "wb") as f:  # a file object: np.save would append ".npy" to a temporary name
        np.save(f, array)


def mirror_map(vertices: np.ndarray) -> np.ndarray:
    """For each vertex, the vertex nearest its mirror image in x (the templates are cut from a
    symmetric body: 0.1-1 mm apart on average)."""
    return cKDTree(vertices).query(vertices * np.array([-1.0, 1.0, 1.0]))[1]


def principal_fields(du: torch.Tensor, masses: torch.Tensor, k: int, seed: int = 0) -> torch.Tensor:
    """The ``k`` principal components (k, n, 3) of displacements (..., n, 3) under the mass metric
    (``masses`` (n,)), each scaled so that its coefficients stay within +-0.5 on ``du`` (the GRU's
    codes are bounded by 1)."""
    w = (masses / masses.mean()).sqrt()[:, None]
    x = (du * w).reshape(-1, du.shape[-2] * 3)
    torch.manual_seed(seed)
    _, _, v = torch.svd_lowrank(x, q=k + 16, niter=4)
    fields = v.T[:k].reshape(k, -1, 3) / w
    scale = project(du, fields, masses).reshape(-1, k).abs().amax(0) / 0.5
    return fields * scale[:, None, None]


def project(du: torch.Tensor, fields: torch.Tensor, masses: torch.Tensor) -> torch.Tensor:
    """Least-squares coefficients (..., k) of displacements (..., n, 3) on ``fields`` (k, n, 3) in
    the mass metric."""
    m = masses / masses.mean()
    weighted = (fields * m[:, None]).reshape(len(fields), -1)  # a matmul: einsum would broadcast (..., k, n, 3)
    rhs = (du.reshape(*du.shape[:-2], -1) @ weighted.T) / len(m)
    return torch.linalg.solve(gram(fields.reshape(len(fields), -1), masses), rhs.unsqueeze(-1)).squeeze(-1)


def part_outfit(outfit: Outfit, vertices: np.ndarray) -> Outfit:
    """The outfit cut to ``vertices`` (sorted indices): each garment's vertices among them, in order,
    and its faces with all three corners among them (whole garments stay whole)."""
    keep = np.zeros(len(outfit.vertices), bool)
    keep[vertices] = True
    parts, start = [], 0
    for g in outfit.garments:
        mine = keep[start:start + len(g.vertices)]
        start += len(g.vertices)
        if not mine.any():
            continue
        parts.append(replace(g, vertices=g.vertices[mine], faces=faces_within(g.faces, mine), pinned=g.pinned[mine]))
    return Outfit(parts)


class Contact:
    """How far the predicted hanging part goes into the body, at frames ``frames`` (F,) of the
    train chunks: PBNS's posed drape ``static`` and the blended skinning rotations ``blend`` (C,
    F, n, 3[, 3]), the posed body ``body_v``, ``body_n`` (C, F, V, 3) and per cloth vertex the
    indices of the body vertices nearest the solved cloth, ``candidates`` (C, F, n, K): the
    prediction's nearest body vertex is searched among them, as the solver searches its own. The
    new rows' displacement (``fields()``: (k, n, 3) of the hanging part, read at each call, as the
    physics steps train them) is posed on PBNS's drape (the static code on PBNS's rows is PBNS's)."""

    def __init__(self, frames, static, blend, body_v, body_n, candidates, fields: Callable[[], torch.Tensor],
                 eps: float):
        self.frames, self.static, self.blend = frames, static, blend
        self.body_v, self.body_n, self.candidates = body_v, body_n, candidates
        self.fields, self.eps = fields, eps

    @staticmethod
    @torch.no_grad()
    def build(teacher: Teacher, chunk_motions, offsets: torch.Tensor, frames: torch.Tensor,
              fields: Callable[[], torch.Tensor], eps: float,
              k: int = 16) -> Contact:
        parts = []
        for (rot, tr), off in zip(chunk_motions, offsets):
            static, _, bv, bn, blend, _ = teacher.drapes(rot[frames], tr[frames])
            parts.append((static, blend, bv, bn, nearest(bv, static + off[frames], k).int()))
        return Contact(frames, *(torch.stack(x) for x in zip(*parts)), fields=fields, eps=eps)

    def __call__(self, i: torch.Tensor, j: torch.Tensor, z_new: torch.Tensor):
        """Chunks ``i`` (B,), their frame slots ``j`` (B, F') into ``frames``, the new rows' codes
        at every chunk frame (B, T, k) -> (mean squared penetration past eps (m^2), % inside)."""
        z = torch.gather(z_new, 1, self.frames[j][..., None].expand(-1, -1, z_new.shape[-1]))
        fields = self.fields()
        u = (z @ fields.reshape(len(fields), -1)).view(*z.shape[:2], -1, 3)
        ii = i[:, None].expand_as(j)
        x = (self.static[ii, j] + torch.einsum("bfnij,bfnj->bfni", self.blend[ii, j], u)).flatten(0, 1)
        bv, bn = self.body_v[ii, j].flatten(0, 1), self.body_n[ii, j].flatten(0, 1)
        p = penetration(x, bv, bn, nearest_among(bv, x, self.candidates[ii, j].flatten(0, 1)), self.eps)
        return p.pow(2).mean(), (p < -self.eps).float().mean() * 100  # inside: behind the surface itself


class Fit:
    """The fitting loss on a batch of chunks: the mass-weighted mean squared rest-pose displacement
    (m^2) between NCS's codes on the new rows (static + dynamic) and the teacher's, after the lead.
    ``inputs``: the chunks' static and dynamic descriptors and PBNS inputs (C, T, ...)."""

    def __init__(self, model: NCS, inputs, coef, gram_new, lead: int, contact: Contact | None = None,
                 contact_weight: float = 0.0, contact_frames: int = 8):
        self.model, self.inputs, self.coef, self.gram_new, self.lead = model, inputs, coef, gram_new, lead
        self.contact, self.contact_weight, self.contact_frames = contact, contact_weight, contact_frames

    def teacher_error(self, i: torch.Tensor, codes: torch.Tensor | None = None) -> torch.Tensor:
        """(B,) mean squared displacement error on the new rows, per chunk."""
        e = self.model.cfg.embedding
        if codes is None:
            zs, zd, _ = self.model.codes(*(x[i] for x in self.inputs))
            codes = zs + zd
        miss = codes[:, self.lead:, e:] - self.coef[i][:, self.lead:]
        return torch.einsum("btk,kl,btl->bt", miss, self.gram_new, miss).mean(1)

    def __call__(self, batch):
        """``batch``: train chunks (B,) and with ``contact`` the chunks' slots into its frames (B, F')."""
        i = batch[0]
        zs, zd, _ = self.model.codes(*(x[i] for x in self.inputs))
        teacher = self.teacher_error(i, zs + zd).mean()
        terms = {"teacher_mm": teacher.sqrt() * 1000}
        if self.contact is None or not self.contact_weight:
            return teacher, terms
        slots = batch[1]
        pen, inside = self.contact(i, slots, (zs + zd)[..., self.model.cfg.embedding:])
        return teacher + self.contact_weight * pen, {**terms, "contact_pct": inside}


def frame_codes(model: NCS, inputs, t: torch.Tensor) -> torch.Tensor:
    """NCS's codes (static + dynamic, (B * F, E)) of sequences ``inputs`` (static, dynamic
    descriptors, PBNS inputs (B, T, ...)) at their frames ``t`` (B, F): the network runs through
    every frame, the GRU needs the past."""
    zs, zd, _ = model.codes(*inputs)
    return torch.gather(zs + zd, 1, t[..., None].expand(-1, -1, zs.shape[-1])).flatten(0, 1)


class Physics:
    """The thesis' loss (eq. 6.8) on NCS's predictions at sampled frames of the chunks, with the
    previous states the solved ones: the PBNS energies of the predicted hanging part plus the
    inertia term against the projection of the teacher's two previous states. In units of a mean
    squared displacement (divided by the inertia term's factor), so that it adds to ``Fit``'s."""

    def __init__(self, model: NCS, teacher: Teacher, motions: list[tuple[torch.Tensor, torch.Tensor]],
                 offsets: torch.Tensor, inputs):
        self.model, self.teacher, self.motions, self.offsets, self.inputs = model, teacher, motions, offsets, inputs
        ic = teacher.inertia
        self.unit = ic.cfg.weight * 0.5 * ic.fps ** 2

    def __call__(self, i: torch.Tensor, t: torch.Tensor):
        """Chunks ``i`` (B,) and frames ``t`` (B, F), each >= 2 -> (loss, terms)."""
        z = frame_codes(self.model, [x[i] for x in self.inputs], t)
        return self.energy(i[:, None].expand_as(t).reshape(-1), t.reshape(-1), z)

    def energy(self, c: torch.Tensor, f: torch.Tensor, z: torch.Tensor):
        """The loss of codes ``z`` (n, E) at frames ``f`` (n,) of chunks ``c`` (n,): (mean, terms)."""
        tch = self.teacher
        n = len(f)
        frames = torch.stack([f - 2, f - 1, f], 1)  # (n, 3): the two solved frames, then the predicted one
        rot = torch.stack([self.motions[cc][0][ff] for cc, ff in zip(c.tolist(), frames)])
        tr = torch.stack([self.motions[cc][1][ff] for cc, ff in zip(c.tolist(), frames)])
        with torch.no_grad():  # the body's surface at the predicted frame only (a third of the cost)
            transforms = tch.body(rot.flatten(0, 1), tch.shape.expand(3 * n, -1), transl=tr.flatten(0, 1),
                                  points_only=True).transforms.view(n, 3, 24, 3, 4)
            bv, bn, _ = posed_bodies(tch.body, rot[:, 2], tch.shape, transl=tr[:, 2])
            static = tch.pbns.pose(rot[:, :2].flatten(0, 1), transforms[:, :2].flatten(0, 1))[:, tch.idx]
            carried = tch.pbns.skin(tch.pbns.rest, transforms[:, 1:].flatten(0, 1))[:, tch.idx]
        solved = static.view(n, 2, -1, 3) + self.offsets[c[:, None], frames[:, :2]]  # (n, 2, nh, 3)
        carried = carried.view(n, 2, -1, 3)
        proj = tch.inertia.projection(solved[:, 1], solved[:, 0], carried[:, 1] - carried[:, 0])
        dt = self.model.decode(z)
        x = self.model.skin(self.model.rest + dt, transforms[:, 2])[:, tch.idx]
        near = nearest(bv, x, 8)
        e = tch.crit(x, dt[:, tch.idx], bv, bn, near) + tch.inertia.to_projection(x, proj)
        # the nearest body vertex is the first of the 8 (a second KD-tree was ~30 % of this loss's time)
        with torch.no_grad():
            terms = {"physics_edge_mm": tch.crit.edge.strain(x).abs().mean() * 1000,
                     "physics_collision_pct": collision_pct(x, bv, bn, near[..., 0]).mean()}
        return e.mean() / self.unit, terms


class StaticPoses:
    """PBNS's loss (eq. 5.3: the whole outfit's energies, its fabric) on NCS's static part, the
    prediction at motion control 0, at poses of the train split, in the units of ``Physics``: what
    PBNS minimised over thousands of poses, kept true of the static encoder fitted to a few chunks."""

    def __init__(self, model: NCS, outfit: Outfit, cfg: NCSTrainConfig, body, shape: torch.Tensor,
                 rotmats: torch.Tensor, unit: float, candidates: int = 8):
        self.model, self.unit = model, unit
        self.crit = L.Criterion(outfit, model.rest, cfg)
        self.bv, self.bn, self.bt = posed_bodies(body, rotmats, shape)
        # the joint transforms' rotations are the joints' global rotations
        self.static = static_descriptors(rotmats, self.bt[..., :3]).flatten(1)
        self.pose = pose_features(rotmats)
        with torch.no_grad():  # the contacts' candidates around the static part as it is now (PBNS + the fit's)
            codes = model.static_code(self.static, self.pose)
        self.body_c, self.cloth_c = pose_candidates(model, self.crit, rotmats, self.bt, self.bv, candidates,
                                                    codes=codes)

    def __call__(self, i: torch.Tensor):
        """Poses ``i`` (B,) -> (loss, terms)."""
        dt = self.model.decode(self.model.static_code(self.static[i], self.pose[i]))
        v = self.model.skin(self.model.rest + dt, self.bt[i])
        e = self.crit(v, dt, self.bv[i], self.bn[i], self.body_c[i], [c[i] for c in self.cloth_c]).mean()
        with torch.no_grad():
            terms = {"static_edge_mm": self.crit.edge.strain(v).abs().mean() * 1000,
                     "static_collision_pct": collision_pct(v, self.bv[i], self.bn[i]).mean()}
        return e / self.unit, terms


class FreeMotion:
    """The energies every state of the cloth keeps low whatever its motion, collision, edge and
    pin (not gravity, which only inertia balances), on NCS's whole prediction of the hanging part at
    frames of motions no teacher solved, in the units of ``Physics``."""

    def __init__(self, model: NCS, teacher: Teacher, inputs, motions: list[tuple[torch.Tensor, torch.Tensor]],
                 unit: float):
        self.model, self.teacher, self.inputs, self.motions, self.unit = model, teacher, inputs, motions, unit

    def __call__(self, i: torch.Tensor, t: torch.Tensor):
        """Windows ``i`` (B,) and frames ``t`` (B, F) -> (loss, terms)."""
        tch, crit = self.teacher, self.teacher.crit
        z = frame_codes(self.model, [x[i] for x in self.inputs], t)
        rot = torch.cat([self.motions[w][0][f] for w, f in zip(i.tolist(), t)])
        tr = torch.cat([self.motions[w][1][f] for w, f in zip(i.tolist(), t)])
        bv, bn, transforms = posed_bodies(tch.body, rot, tch.shape, transl=tr)
        dt = self.model.decode(z)
        x = self.model.skin(self.model.rest + dt, transforms)[:, tch.idx]
        near = nearest(bv, x, 8)
        loss = crit.edge(x) + crit.collision(x, bv, bn, crit.faces, near) + crit.pin(dt[:, tch.idx])
        with torch.no_grad():
            terms = {"free_edge_mm": crit.edge.strain(x).abs().mean() * 1000,
                     "free_collision_pct": collision_pct(x, bv, bn, near[..., 0]).mean()}
        return loss.mean() / self.unit, terms


def sound_chunks(strains: list[float], limit: float) -> list[bool]:
    """Per solved chunk, its largest edge strain (m) within ``limit`` (NaN counts as failed)."""
    return [bool(x <= limit) for x in strains]


def gram(rows: torch.Tensor, masses: torch.Tensor) -> torch.Tensor:
    """(E, E) mass-weighted Gram matrix of rest-pose fields (E, n * 3): code^T G code is the mean
    squared displacement."""
    w = (masses / masses.mean()).repeat_interleave(3)
    return (rows * w) @ rows.T / len(masses)


def train(body, cfg: NCSTrainConfig | None = None, out: Path | None = None, log=print, progress: bool = True) -> dict:
    """Train the NCS of ``cfg.outfit`` from its PBNS; writes ``out`` (default ``store.ncs_path``)
    with the training record inside and returns that record."""
    cfg = cfg or NCSTrainConfig()
    torch.manual_seed(cfg.seed)
    t0 = time.time()
    pbns_path = store.pbns_path(cfg.outfit)
    outfit, shape, name = trained_outfit(body, pbns_path)
    out = Path(out or store.ncs_path(name))
    run_dir = run_dir_for(out)
    pbns, _ = PBNS.load(pbns_path)
    model = NCS.from_pbns(pbns, cfg.model)
    teacher = Teacher(body, name, cfg)
    idx = teacher.idx  # the moving part (``moving_part``)
    masses = torch.from_numpy(vertex_masses(outfit.vertices, outfit.faces))

    motions = Motions(body, shape, cfg.smooth_motion)
    train_chunks = chunks_of("train", cfg.chunk, cfg.chunks, cfg.seed, cfg.stops, cfg.lead)
    val_chunks = chunks_of("val", cfg.chunk, cfg.val_chunks, cfg.seed, cfg.stops, cfg.lead)
    off = integrate_chunks(name, train_chunks + val_chunks, motions, cfg, chunk_folder(pbns_path, cfg), log)
    t_integrate = time.time() - t0
    solved = [teacher.rest_displacement(*motions.motion(c), torch.from_numpy(o).float())
              for c, o in zip(train_chunks + val_chunks, off)]
    sound = sound_chunks([strain for _, strain in solved], cfg.max_strain)
    n_t = len(train_chunks)
    dropped = [list(c) for c, ok in zip(train_chunks + val_chunks, sound) if not ok]
    if dropped:
        log(f"ncs {name}: {len(dropped)} solved chunks failed (an edge strained > {cfg.max_strain * 1000:.0f} mm), "
            f"dropped: {dropped}")
    train_chunks = [c for c, ok in zip(train_chunks, sound[:n_t]) if ok]
    val_chunks = [c for c, ok in zip(val_chunks, sound[n_t:]) if ok]
    du = torch.stack([d for (d, _), ok in zip(solved, sound) if ok])
    off = torch.from_numpy(off[np.array(sound)]).float()
    del solved
    n_train = len(train_chunks)
    inputs = [motions.inputs(c) for c in train_chunks + val_chunks]
    if cfg.mirror:  # the train chunks' mirror images: the cloth's displacement (and offset) mirrored in x
        mp_ = torch.from_numpy(mirror_map(outfit.vertices[idx.numpy()]))
        flip = torch.tensor([-1.0, 1.0, 1.0])
        du = torch.cat([du[:n_train, :, mp_] * flip, du])
        off = torch.cat([off[:n_train, :, mp_] * flip, off])
        inputs = [motions.inputs(c, mirror=True) for c in train_chunks] + inputs
        n_train *= 2
    inputs = [torch.stack(x) for x in zip(*inputs)]  # static, dynamic descriptors, PBNS inputs (C, T, ...)

    # the new rows of D: principal fields of the train chunks' displacement, zero off the hanging part
    # and, tapered, at the ankles (``ankle_taper``)
    taper = torch.from_numpy(ankle_taper(body, shape, outfit.vertices[idx.numpy()], cfg.ankle_hold))
    du = du * taper[:, None]
    k = cfg.model.dynamic
    fields = principal_fields(du[:n_train, 5:], masses[idx], k, cfg.seed)
    coef = project(du, fields, masses[idx])
    full = torch.zeros(k, len(outfit.vertices), 3)
    full[:, idx] = fields
    e = pbns.D.shape[0]
    with torch.no_grad():
        model.D[e:] = full.reshape(k, -1)

    chunk_motions = [motions.motion(c, mirror=True) for c in train_chunks] if cfg.mirror else []
    chunk_motions += [motions.motion(c) for c in train_chunks + val_chunks]
    contact = contact_val = None
    if cfg.contact_weight:
        every4 = torch.arange(cfg.lead, cfg.chunk, 4)
        def moving_fields() -> torch.Tensor:  # D's new rows on the hanging part, as they are now
            return model.D[e:].view(k, -1, 3)[:, idx]
        contact, contact_val = (Contact.build(teacher, chunk_motions[a:b], off[a:b], every4, moving_fields,
                                              cfg.collision.eps)
                                for a, b in ((0, n_train), (n_train, len(off))))
    fit = Fit(model, inputs, coef, gram(fields.reshape(k, -1), masses[idx]), cfg.lead, contact, cfg.contact_weight,
              cfg.contact_frames)
    for p in (model.D, model.weight_logits, *model.pbns_mlp.parameters()):  # PBNS's, kept
        p.requires_grad_(False)
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=cfg.weight_decay)
    g = torch.Generator().manual_seed(cfg.seed)
    val_i = torch.arange(n_train, len(du))

    def batches():
        while True:
            b = (torch.randint(n_train, (cfg.batch,), generator=g),)
            if contact is not None:
                b += (torch.randint(len(contact.frames), (cfg.batch, cfg.contact_frames), generator=g),)
            yield b

    @torch.no_grad()
    def validate():
        model.eval()
        zs, zd, _ = model.codes(*(x[val_i] for x in inputs))
        v = {"val_teacher_mm": float(fit.teacher_error(val_i, zs + zd).mean().sqrt() * 1000),
             "train_teacher_mm": float(fit.teacher_error(torch.arange(min(n_train, 32))).mean().sqrt() * 1000),
             "val_zero_mm": float(torch.einsum("btk,kl,btl->bt", coef[val_i][:, cfg.lead:], fit.gram_new,
                                               coef[val_i][:, cfg.lead:]).mean().sqrt() * 1000)}
        if contact_val is not None:
            slots = torch.arange(len(contact_val.frames)).expand(len(val_i), -1)
            v["val_contact_pct"] = float(contact_val(torch.arange(len(val_i)), slots, (zs + zd)[..., e:])[1])
        model.train()
        return v

    trainer = Trainer({"ncs": model}, opt, cfg.steps, eval_every=max(1, cfg.steps // 12), out_dir=run_dir / "fit",
                      select="val_teacher_mm", config=asdict(cfg), desc=f"ncs {name}", generators=[g],
                      progress=progress)
    log(f"ncs {name}: {len(idx)} of {len(outfit.vertices)} vertices move; {len(train_chunks)} train "
        f"(+ mirrored: {cfg.mirror}) / {len(val_chunks)} val chunks of {cfg.chunk} frames integrated in "
        f"{t_integrate:.0f} s (chunks cached in {chunk_folder(pbns_path, cfg)})")
    curve = trainer.fit(batches(), fit, validate)
    trainer.load_best()

    physics = Physics(model, teacher, chunk_motions, off, inputs)
    lo = max(cfg.lead, 2)
    val_t = torch.linspace(lo, cfg.chunk - 1, cfg.physics_frames).long().expand(len(val_i), -1)

    still = val_still = None
    if cfg.static_poses:
        rot_s = pose_set("train", cfg.static_poses, _FABRIC.min_pose_distance, cfg.seed)
        still = StaticPoses(model, outfit, cfg, body, shape, rot_s, physics.unit)
        val_still = StaticPoses(model, outfit, cfg, body, shape,
                                pose_set("val", max(16, cfg.static_poses // 8), _FABRIC.min_pose_distance, cfg.seed),
                                physics.unit)

    free = None
    if cfg.free_windows:
        windows = chunks_of("train", cfg.chunk, cfg.chunks + cfg.free_windows, cfg.seed, cfg.stops,
                            cfg.lead)[cfg.chunks:]  # after the teacher's own
        w_in = [motions.inputs(c) for c in windows]
        free = FreeMotion(model, teacher, [torch.stack(x) for x in zip(*w_in)], [motions.motion(c) for c in windows],
                          physics.unit)

    def physics_batches():
        for b in batches():
            p = torch.randint(n_train, (cfg.physics_chunks,), generator=g)
            t = torch.randint(lo, cfg.chunk, (cfg.physics_chunks, cfg.physics_frames), generator=g)
            s = torch.randint(cfg.static_poses, (cfg.static_batch,), generator=g) if still is not None else None
            w = None
            if free is not None:
                w = (torch.randint(len(free.motions), (cfg.free_batch,), generator=g),
                     torch.randint(cfg.lead, cfg.chunk, (cfg.free_batch, cfg.free_frames), generator=g))
            yield b, p, t, s, w

    def physics_step(batch):
        b, p, t, s, w = batch
        loss, terms = fit(b)
        e, more = physics(p, t)
        loss, terms = loss + e, {**terms, **more, "physics": e}
        if still is not None:
            es, more = still(s)
            loss, terms = loss + cfg.static_weight * es, {**terms, **more, "static": es}
        if free is not None:
            ef, more = free(*w)
            loss, terms = loss + cfg.free_weight * ef, {**terms, **more, "free": ef}
        return loss, terms

    @torch.no_grad()
    def physics_validate():
        model.eval()
        v = validate()
        e, more = physics(val_i, val_t)
        v = {**v, "val_physics": float(e), **{f"val_{k}": float(x) for k, x in more.items()}}
        if val_still is not None:
            es, more = val_still(torch.arange(len(val_still.bt)))
            v = {**v, "val_static": float(es), **{f"val_{k}": float(x) for k, x in more.items()}}
        model.train()
        return v

    groups = [{"params": params}]
    if cfg.field_lr:
        model.D.requires_grad_(True)
        rows = (torch.arange(model.D.shape[0]) >= e).float()[:, None]
        cols = torch.zeros(len(outfit.vertices), 3)
        cols[idx] = (taper > 0).float()[:, None]
        cols = cols.reshape(1, -1)
        model.D.register_hook(lambda grad: grad * rows * cols)  # PBNS's rows and the part that does not move stay
        groups.append({"params": [model.D], "lr": cfg.field_lr, "weight_decay": 0.0})
    opt2 = torch.optim.AdamW(groups, lr=cfg.physics_lr, weight_decay=cfg.weight_decay)
    trainer2 = Trainer({"ncs": model}, opt2, cfg.physics_steps, eval_every=max(1, cfg.physics_steps // 4),
                       out_dir=run_dir / "physics", config=asdict(cfg), desc=f"ncs {name} physics", generators=[g],
                       progress=progress)
    if not trainer2.resumed:
        trainer2.validate_now(physics_validate, "start")
    curve2 = trainer2.fit(physics_batches(), physics_step, physics_validate)
    model.eval()
    with torch.no_grad():  # how far the physics steps moved the fields (rms per unit code, mm)
        moved = (model.D[e:] - full.reshape(k, -1)).view(k, -1, 3)[:, idx].pow(2).sum(-1).mean(-1).sqrt()
    meta = {"outfit": name, "pbns": pbns_path.name, "config": asdict(cfg), "model": asdict(model.cfg),
            "vertices": int(len(outfit.vertices)), "moving_vertices": int(len(idx)),
            "ankle_held_vertices": int((taper == 0).sum()),
            "chunks": [list(c) for c in train_chunks], "val_chunks": [list(c) for c in val_chunks],
            "dropped_chunks": dropped,
            "integrate_seconds": round(t_integrate, 1),
            "train_seconds": round(time.time() - t0, 1), "workers": cfg.workers, "threads": torch.get_num_threads(),
            "best": curve["best"], "field_change_mm": round(float(moved.mean()) * 1000, 3),
            "garments": [gg.name for gg in outfit.garments], "curve": curve["history"],
            "physics_curve": curve2["history"]}
    model.save(out, {"meta_json": json.dumps(meta), "layer": torch.from_numpy(outfit.layer),
                     "garment_id": torch.from_numpy(outfit.garment_id), "shape": shape})
    shutil.rmtree(run_dir, ignore_errors=True)
    return meta
