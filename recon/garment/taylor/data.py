"""The Taylor model's training data: poses of the train mocap and the outfit's quasi-static drapes
at them (``recon.garment.drape``) on a set of bodies, made in worker processes and kept in
``<cache>/taylor-drapes/`` (a rerun drapes only what is missing).
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import roma
import torch
from tqdm import tqdm

from recon import paths
from recon.body import default_body
from recon.executor import ExecutorConfig, WorkerSpec, map_strict
from recon.garment import store
from recon.garment.data import posed_bodies
from recon.garment.drape import DrapeSolver
from recon.garment.integrate import unpose
from recon.garment.pbns.model import PBNS, remove_yaw, trained_outfit
from recon.garment.resize import Transfer
from recon.garment.taylor.config import TaylorBuildConfig
from recon.poses.mocap import MocapPoses


def sample_poses(step: int) -> torch.Tensor:
    """(M, 24, 3, 3) every ``step``-th frame of the train mocap, heading removed."""
    m = MocapPoses.load("train")
    r = roma.rotvec_to_rotmat(torch.from_numpy(m.rotvec[::step]).float())
    r[:, 0] = remove_yaw(r[:, 0])
    return r


def pose_key(pose: torch.Tensor) -> bytes:
    """A pose's identity (24, 3, 3): its rotations rounded, as the drape cache keys it."""
    return pose.numpy().round(5).tobytes()


def fit_only_poses(train: torch.Tensor, examples: torch.Tensor, n: int, seed: int = 0) -> torch.Tensor:
    """(n, 24, 3, 3) poses drawn at random from ``train`` (M, 24, 3, 3), none of them one of
    ``examples``: more training data for the pose model, spread as the mocap is. The draws for
    ``n`` begin those for any larger ``n`` (a larger fit reuses the drapes of a smaller)."""
    taken = {pose_key(e) for e in examples}
    free = [i for i, r in enumerate(train) if pose_key(r) not in taken]
    if n > len(free):
        raise ValueError(f"PoseFitConfig.poses: {n} asked, {len(free)} train poses are not examples")
    pick = np.random.default_rng(seed).permutation(free)[:n]
    return train[torch.from_numpy(pick)]


def unposed(pbns: PBNS, x: torch.Tensor, transforms: torch.Tensor, min_singular: float = 0.2) -> torch.Tensor:
    """Posed cloth (B, N, 3) -> rest pose through the outfit's skinning at ``transforms`` (B, 24,
    3, 4): the inverse of ``pbns.skin`` (blends clamped like NCS's teacher: ``integrate.unpose``)."""
    t = pbns.blend(transforms)
    return unpose(t[..., :3], x - t[..., 3], min_singular)


class Draper:
    """A build's draping worker (``recon.executor``): the body, PBNS, the two drape solvers and the
    shape transfer, made once per process; ``draper((pose, shapes))`` is ``drape_bodies``."""

    def __init__(self, cfg: TaylorBuildConfig):
        self.body = default_body()
        self.pbns, _ = PBNS.load(store.pbns_path(cfg.outfit))
        outfit, self.shape0, _ = trained_outfit(self.body, store.pbns_path(cfg.outfit))
        self.first = DrapeSolver(outfit, cfg.drape)
        self.other = DrapeSolver(outfit, replace(cfg.drape, rounds=cfg.shape_rounds))
        self.transfer = Transfer(self.body, self.pbns.rest.numpy(), self.pbns.faces.numpy(), self.shape0)

    def __call__(self, task: tuple[torch.Tensor, torch.Tensor]) -> dict:
        return self.drape_bodies(*task)

    @torch.no_grad()
    def drape_bodies(self, pose: torch.Tensor, shapes: torch.Tensor) -> dict:
        """At one pose (24, 3, 3): the drapes on the pose model's body, then on ``shapes`` (K, S),
        each started from the first moved by the change of the graded, skinned outfit. Returns
        {"posed", "unposed": (K + 1, N, 3), "strain": (K + 1,) largest edge strain (m)}."""
        pbns, posed, out, strains = self.pbns, [], [], []
        rests = torch.cat([pbns.rest[None], torch.from_numpy(self.transfer.resize(shapes))]) if len(shapes) \
            else pbns.rest[None]
        first = None
        e = self.first.crit.edge.edges
        for shape, rest in zip(torch.cat([self.shape0[None], shapes]), rests):
            bv, bn, bt = posed_bodies(self.body, pose[None], shape[None])
            skinned = pbns.skin(rest, bt)[0]
            if first is None:
                x = self.first(rest, skinned, bv[0], bn[0])
                first = (x, skinned)
            else:
                x = self.other(rest, first[0] + skinned - first[1], bv[0], bn[0], carried=skinned)
            length = lambda v: (v[e[:, 0]] - v[e[:, 1]]).norm(dim=-1)  # noqa: E731
            strains.append(float((length(x) - length(rest)).abs().max()))
            posed.append(x)
            out.append(unposed(pbns, x[None], bt)[0])
        return {"posed": torch.stack(posed).numpy(), "unposed": torch.stack(out).numpy(), "strain": np.array(strains)}


def drape_folder(cfg: TaylorBuildConfig, shapes: torch.Tensor) -> Path:
    """Where an outfit's drapes on a set of bodies live: one folder per PBNS file, bodies and solver."""
    key = json.dumps({"pbns": hashlib.sha256(store.pbns_path(cfg.outfit).read_bytes()).hexdigest(),
                      "shapes": shapes.numpy().round(6).tolist(), "drape": asdict(cfg.drape),
                      "shape_rounds": cfg.shape_rounds}, sort_keys=True)
    return paths.cache_dir() / "taylor-drapes" / f"{cfg.outfit}-{hashlib.sha256(key.encode()).hexdigest()[:12]}"


def drape_poses(cfg: TaylorBuildConfig, poses: torch.Tensor, shapes: torch.Tensor | list[torch.Tensor],
                progress: bool = True, desc: str = "draping") -> list[dict]:
    """``Draper.drape_bodies`` at each of ``poses`` (P, 24, 3, 3) on ``shapes`` (K, S; or one (K, S) per
    pose), kept in ``drape_folder`` as each pose is done (a rerun drapes only what is missing),
    in ``cfg.workers`` worker processes (recon.executor)."""
    per_pose = list(shapes) if isinstance(shapes, list) else [shapes] * len(poses)
    folder = drape_folder(cfg, shapes if torch.is_tensor(shapes) else torch.cat(per_pose))
    folder.mkdir(parents=True, exist_ok=True)
    keys = [hashlib.sha256(pose_key(p) + s.numpy().round(6).tobytes()).hexdigest()[:16]
            if not torch.is_tensor(shapes) else hashlib.sha256(pose_key(p)).hexdigest()[:16]
            for p, s in zip(poses, per_pose)]
    files = [folder / f"{k}.npz" for k in keys]
    todo = [i for i, f in enumerate(files) if not f.exists()]
    t0 = time.time()
    if todo:
        bar = tqdm(total=len(poses), initial=len(poses) - len(todo), desc=f"{desc} {cfg.outfit}", unit="pose",
                   disable=not progress)
        jobs = map_strict(WorkerSpec(Draper, (cfg,)), [(poses[i], per_pose[i]) for i in todo],
                         ExecutorConfig(workers=cfg.workers, threads=1))
        for k, r in jobs:
            paths.atomic_write(files[todo[k]], lambda t, r=r: np.savez(t, **r))
            bar.update()
        bar.close()
        timing = folder / "timing.json"  # wall seconds spent draping into this folder, over all runs
        spent = json.loads(timing.read_text())["seconds"] if timing.exists() else 0.0
        paths.write_text(timing, json.dumps({"seconds": spent + time.time() - t0, "workers": cfg.workers}))
    return [dict(np.load(f)) for f in files]


def pose_model_drapes(cfg: TaylorBuildConfig, poses: torch.Tensor, phenotypes: int, progress: bool = True,
                      desc: str = "draping") -> torch.Tensor:
    """(P, N, 3) the unposed drapes at ``poses`` (P >= 1, 24, 3, 3) on the pose model's body alone
    (``drape_poses`` with no other bodies; ``phenotypes``: the body model's shape size)."""
    drapes = drape_poses(cfg, poses, torch.zeros(0, phenotypes), progress, desc)
    return torch.stack([torch.from_numpy(d["unposed"][0]).float() for d in drapes])


def draping_seconds(cfg: TaylorBuildConfig, shapes: torch.Tensor) -> float | None:
    """Wall seconds spent making the drapes of ``drape_folder`` (None: not recorded)."""
    timing = drape_folder(cfg, shapes) / "timing.json"
    return json.loads(timing.read_text())["seconds"] if timing.exists() else None
