"""NCS's teacher (``recon garment train --model ncs``, stage 1): the cloth of an outfit's hanging
part integrated frame by frame through chunks of the retargeted mocap (recon.garment.integrate),
the trajectory NCS then learns. The same loss the thesis trains on (6.3.4) minimised by a solver
instead of a network: its fixed point, what the thesis' training converges to.

A chunk is ``chunk`` frames of a clip (smoothed, optionally stopping dead); the cloth settles on
its first pose, then is integrated through it in ``workers`` processes, each chunk kept in
``<cache>/ncs-chunks/`` (``chunk_folder``) as it is done.
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import roma
import torch
from scipy.spatial import cKDTree

from recon import paths
from recon.body import default_body, skeleton
from recon.body.base import BodyModel
from recon.body.lbs import blend_transforms, mirror_rotmats
from recon.executor import ExecutorConfig, WorkerSpec, map_strict
from recon.garment import losses, store
from recon.garment.data import posed_bodies
from recon.garment.integrate import Preconditioner, integrate, settle, unpose
from recon.garment.mesh import faces_within
from recon.garment.ncs.config import NCSTrainConfig
from recon.garment.ncs.model import FPS, descriptors, hanging_part, smooth_time, vertex_masses
from recon.garment.pbns.model import PBNS, pose_features, trained_outfit
from recon.garment.templates import GarmentSpec, Outfit
from recon.poses.mocap import MocapPoses


def rest_joint_height(body: BodyModel, shape: torch.Tensor, *names: str) -> float:
    """The height (m, +Y) of the highest of the joints ``names`` in the rest body of ``shape``."""
    with torch.no_grad():
        _, joints = body.rest_geometry(shape.reshape(1, -1).to(body.mean_shape))
    return float(joints[0, [skeleton.JOINT_NAMES.index(n) for n in names], 1].max())


def moving_part(body: BodyModel, outfit: Outfit, shape: torch.Tensor, cfg: NCSTrainConfig) -> tuple[np.ndarray,
                np.ndarray]:
    """NCS's (hanging, held) vertices of an outfit (``hanging_part``): an unpinned one held above the
    rest body's waist (its pelvis joint + ``GarmentSpec.waist``, where a skirt is pinned) with
    ``cfg.waist_hold``."""
    if not cfg.waist_hold:
        return hanging_part(outfit)
    return hanging_part(outfit, rest_joint_height(body, shape, "pelvis") + GarmentSpec.waist)


def ankle_taper(body: BodyModel, shape: torch.Tensor, vertices: np.ndarray, hold: float) -> np.ndarray:
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

    def __init__(self, body: BodyModel, shape: torch.Tensor, smooth: float):
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
    frames on the motion's first pose; ``friction`` as ``integrate``'s (none in NCS's teacher)."""

    def __init__(self, body: BodyModel, outfit_name: str, cfg: NCSTrainConfig, friction: float = 0.0):
        self.body, self.cfg, self.friction = body, cfg, friction
        self.pbns, ck = PBNS.load(store.pbns_path(outfit_name))
        self.shape = ck["shape"][None]
        outfit, _, _ = trained_outfit(body, store.pbns_path(outfit_name))
        hanging, held = moving_part(body, outfit, self.shape, cfg)
        self.idx = torch.from_numpy(np.nonzero(hanging)[0])
        cloth = part_outfit(outfit, self.idx.numpy())
        self.crit = losses.Criterion(cloth, self.pbns.rest[self.idx], cfg)
        masses = torch.from_numpy(vertex_masses(cloth.vertices, cloth.faces))
        self.inertia = losses.InertiaLoss(masses, FPS, cfg.inertia)
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
        blend = blend_transforms(w, transforms)[..., :3]
        return static, carried, bv, bn, blend, transforms

    def __call__(self, rot: torch.Tensor, transl: torch.Tensor) -> torch.Tensor:
        static, carried, bv, bn, _, _ = self.drapes(rot, transl)
        args = (self.crit, self.inertia, self.held)
        x0 = settle(*args, static[0], carried[0], bv[0], bn[0], self.cfg.settle, self.cfg.integrate, self.precond)
        x = integrate(*args, static, carried, bv, bn, self.cfg.integrate, self.precond, start=x0,
                      friction=self.friction)
        return x - static

    @torch.no_grad()
    def rest_displacement(self, rot: torch.Tensor, transl: torch.Tensor, offset: torch.Tensor
                          ) -> tuple[torch.Tensor, float]:
        """A solved chunk's posed offsets (T, n, 3) -> its rest-pose displacements from PBNS (T, n,
        3; ``unpose`` with ``cfg.min_singular``) and its largest edge strain (m)."""
        static, _, _, _, blend, _ = self.drapes(rot, transl)
        strain = float(self.crit.edge.strain(static + offset).abs().max())
        return unpose(blend, offset, self.cfg.min_singular), strain


class TeacherWorker:
    """A worker (``recon.executor``) integrating chunks with one outfit's teacher, made once per
    process; ``worker((rotmats, transl))``: the chunk's posed offsets, float16."""

    def __init__(self, outfit_name: str, cfg: NCSTrainConfig):
        self.teacher = Teacher(default_body(), outfit_name, cfg)

    def __call__(self, motion: tuple[torch.Tensor, torch.Tensor]) -> np.ndarray:
        return self.teacher(*motion).numpy().astype(np.float16)


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
        # each chunk's motion made as it is handed out: only the chunks in flight are held
        jobs = map_strict(WorkerSpec(TeacherWorker, (outfit_name, cfg)), todo,
                         ExecutorConfig(workers=cfg.workers, threads=1), prepare=lambda i: motions.motion(chunks[i]))
        for k, (j, du) in enumerate(jobs):
            i = todo[j]
            paths.atomic_write(files[i], lambda t, du=du: _save_npy(t, du))
            log(f"integrated {chunks[i].split} chunk {k + 1}/{len(todo)} ({time.time() - t0:.0f} s)")
    return np.stack([np.load(f) for f in files])


def _save_npy(path, array: np.ndarray) -> None:
    with open(path, "wb") as f:  # a file object: np.save would append ".npy" to a temporary name
        np.save(f, array)


def mirror_map(vertices: np.ndarray) -> np.ndarray:
    """For each vertex, the vertex nearest its mirror image in x (the templates are cut from a
    symmetric body: their mirror images lie close to vertices)."""
    return cKDTree(vertices).query(vertices * np.array([-1.0, 1.0, 1.0]))[1]


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


def sound_chunks(strains: list[float], limit: float) -> list[bool]:
    """Per solved chunk, its largest edge strain (m) within ``limit`` (NaN counts as failed)."""
    return [bool(x <= limit) for x in strains]
