"""The Taylor model's example database (``recon garment train --model taylor``): the paper's
section 3.6 on our outfits, bodies and mocap.

1. Sensitivity (eq. 7, 11): how far each cloth vertex moves per radian of each joint's rotation,
   measured on the clothing pose model (PBNS, trained on the drape energies) by central finite
   differences at poses of the train mocap on bodies across the phenotype range (a drape solve per
   perturbation would cost 144 drapes a sample); per region the weight of each joint-angle
   difference, per joint its weight in the clustering.
2. Anchors: every 4th frame of the train mocap (heading removed), clustered by k-means on the
   joint rotation vectors scaled by the square roots of the joint weights; each cluster's member
   nearest its centre is an anchor pose.
3. At each anchor the outfit is draped (recon.garment.drape) on the pose model's body and on
   ``shapes`` bodies spanning anny's phenotype box (a Latin hypercube), each body's drape started
   from the first drape moved by the change of the graded, skinned outfit (one fold pattern per
   anchor, what a PCA can model); the drapes are unposed and their departures from the outfit
   graded to each body fitted (``taylor.fit_shape_model``); the first drape minus PBNS's cloth is
   the anchor's pose-model correction.
4. Pose examples: ``pose_examples`` more poses of the train mocap (clustered alike) draped on the
   pose model's body alone; each drape minus PBNS's cloth corrects the pose model there too (the
   pose model's error dominates the shape model's, and an example costs one drape, an anchor
   ``shapes + 1``).
5. The pose model fitted (``fit_pose_model``): PBNS's network and blend shapes trained further on
   the examples' drapes (anchors' first drapes and pose examples), so the pose model learns where
   the drape solver's quasi-static state lies at any pose, not only at an example; the examples'
   corrections are then its residuals there.

Drapes run in ``workers`` processes, one anchor a task, each kept in ``<cache>/taylor-drapes/``
(resumable: a rerun drapes only what is missing).
"""
from __future__ import annotations

import copy
import hashlib
import json
import multiprocessing as mp
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import roma
import torch
from scipy.cluster.vq import kmeans2
from scipy.stats import qmc
from tqdm import tqdm

from recon import paths
from recon.body import default_body, skeleton
from recon.garment import store
from recon.garment.data import posed_bodies
from recon.garment.drape import DrapeSolver, DrapeSolverConfig
from recon.garment.integrate import unpose
from recon.garment.pbns.model import PBNS, pose_features, remove_yaw, trained_outfit
from recon.garment.resize import Transfer
from recon.garment.taylor.model import (
    BlendConfig,
    TaylorGarment,
    fit_shape_model,
    pose_vector,
    region_weights,
    shape_features,
)
from recon.poses.mocap import MocapPoses

# the phenotype box the database's bodies span (anny: gender, age, muscle, weight, height, proportions)
SHAPE_BOX = ((0.0, 1.0), (0.3, 1.0), (0.1, 0.9), (0.05, 0.95), (0.05, 0.95), (0.2, 0.8))


@dataclass
class PoseFitConfig:
    """PBNS trained further on the examples' unposed drapes, its blend weights (its skinning) kept:
    "adam", its network and blend shapes by minibatch Adam on the mean vertex distance; "ridge",
    its blend shapes alone, a least-squares fit on its codes pulled towards PBNS's by ``ridge``."""
    method: str = "adam"
    steps: int = 2000  # adam; 0: PBNS as trained is the pose model
    lr: float = 3e-4
    batch: int = 96
    seed: int = 0
    ridge: float = 1.0  # ridge: the L2 weight on the change of the blend shapes (per code, squared)

    @property
    def trains(self) -> bool:
        """Whether the pose model is fitted at all (else PBNS as trained)."""
        return self.method != "adam" or self.steps > 0


@dataclass
class TaylorBuildConfig:
    outfit: str = "tshirt-skirt"
    anchors: int = 64  # the paper: ~150; 64 x 9 drapes fit the 45-min budget on 2 cores
    shapes: int = 8  # bodies per anchor besides the pose model's (the paper: 17)
    pose_examples: int = 512  # poses draped on the pose model's body alone, besides the anchors
    components: int = 5  # PCA components of a shape model (the paper: 5, 98.6 % of the variance)
    # L2 weight of the shape-to-coefficient map on standardised phenotypes; None: the one of RIDGES
    # with the least leave-one-body-out error over the anchors' drapes (the paper: 0.2 on SMPL betas)
    ridge: float | None = None
    frame_step: int = 4  # mocap frames between sampled poses (the paper: every 4th)
    sensitivity_poses: int = 8  # poses x 3 bodies the sensitivity is averaged over
    sensitivity_step: float = 0.05  # rad, central differences
    shape_rounds: int = 2  # drape rounds for the other bodies (they start near their minimum)
    seed: int = 0
    workers: int = 2
    drape: DrapeSolverConfig = field(default_factory=DrapeSolverConfig)
    blend: BlendConfig = field(default_factory=BlendConfig)
    pose_fit: PoseFitConfig = field(default_factory=PoseFitConfig)


RIDGES = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0)


def leave_one_out(shapes: torch.Tensor, u: torch.Tensor, components: int, ridge: float) -> float:
    """Mean vertex error (m) of one anchor's shape model on each of its bodies when fitted without it:
    how well it predicts a body it has not seen."""
    errs = []
    for k in range(len(shapes)):
        keep = torch.arange(len(shapes)) != k
        mean, basis, m = fit_shape_model(shapes[keep], u[keep], components, ridge)
        pred = mean + torch.einsum("c,cnk->nk", m @ shape_features(shapes[k:k + 1])[0], basis)
        errs.append(float((pred - u[k]).norm(dim=-1).mean()))
    return float(np.mean(errs))


def fit_pose_model(pbns: PBNS, poses: torch.Tensor, drapes: torch.Tensor, cfg: PoseFitConfig,
                   checkpoint=None) -> PBNS:
    """A copy of ``pbns`` trained so that its rest-pose cloth at ``poses`` (E, 24, 3, 3) nears the
    unposed drapes there (E, N, 3); its blend weights kept. ``cfg.steps`` 0: an untrained copy.
    ``checkpoint(step, model)``, when given, is called after every step (a choice of the steps
    scores one run at several)."""
    model = copy.deepcopy(pbns)
    if cfg.method == "ridge":
        with torch.no_grad():
            x = model.mlp(pose_features(poses)).double()  # (E, C) codes
            d0 = model.D.double()
            r = (drapes - model.rest).reshape(len(poses), -1).double()
            eye = torch.eye(x.shape[1], dtype=x.dtype)
            model.D.data = (d0 + torch.linalg.solve(x.T @ x + cfg.ridge * eye, x.T @ (r - x @ d0))).float()
        return model.requires_grad_(False).eval()
    if cfg.method != "adam":
        raise ValueError(f"PoseFitConfig.method: adam or ridge, not {cfg.method!r}")
    model.weight_logits.requires_grad_(False)
    opt = torch.optim.Adam([*model.mlp.parameters(), model.D], lr=cfg.lr)
    g = torch.Generator().manual_seed(cfg.seed)
    for step in range(1, cfg.steps + 1):
        b = torch.randperm(len(poses), generator=g)[:cfg.batch]
        loss = (model.rest + model.deformation(poses[b]) - drapes[b]).norm(dim=-1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        if checkpoint is not None:
            with torch.no_grad():
                checkpoint(step, model)
    return model.requires_grad_(False).eval()


def database_shapes(n: int, seed: int = 0) -> torch.Tensor:
    """(n, 6) bodies spanning SHAPE_BOX: a scrambled Latin hypercube."""
    u = qmc.LatinHypercube(d=len(SHAPE_BOX), seed=seed).random(n)
    lo, hi = np.array(SHAPE_BOX).T
    return torch.from_numpy(lo + u * (hi - lo)).float()


def perturbed(rotmats: torch.Tensor, step: float) -> torch.Tensor:
    """(72 x 2, 24, 3, 3): each of the 72 joint rotation-vector components of one pose (24, 3, 3)
    moved by +step then -step (in the joint's local frame)."""
    eye = torch.eye(72).view(72, 24, 3)
    d = roma.rotvec_to_rotmat(torch.cat([eye, -eye]) * step)  # (144, 24, 3, 3)
    return rotmats[None] @ d


@torch.no_grad()
def sensitivity(pbns: PBNS, body, rotmats: torch.Tensor, shape: torch.Tensor, rest: torch.Tensor,
                step: float = 0.05) -> torch.Tensor:
    """(N, 72) |d x_y / d theta_m|: how far each cloth vertex of the pose model (its rest ``rest``
    on body ``shape``) moves per radian of each joint rotation component at pose (24, 3, 3)."""
    r = perturbed(rotmats, step)
    _, _, bt = posed_bodies(body, r, shape.reshape(1, -1))
    x = pbns.skin(rest + pbns.deformation(r), bt)
    j = (x[:72] - x[72:]) / (2 * step)  # (72, N, 3)
    return j.norm(dim=-1).T


def unposed(pbns: PBNS, x: torch.Tensor, transforms: torch.Tensor, min_singular: float = 0.2) -> torch.Tensor:
    """Posed cloth (B, N, 3) -> rest pose through the outfit's skinning at ``transforms`` (B, 24,
    3, 4): the inverse of ``pbns.skin`` (blends clamped like NCS's teacher: ``integrate.unpose``)."""
    t = pbns.blend(transforms)
    return unpose(t[..., :3], x - t[..., 3], min_singular)


def region_sensitivity(s: torch.Tensor, regions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean sensitivity (N, 72) -> (Q (G, 72): per region the weight of each squared joint-angle
    difference, eq. 7, normalised to sum to 1; joint weights (24,): eq. 11)."""
    q = regions.T @ s ** 2
    return q / q.sum(1, keepdim=True).clamp_min(1e-12), s.sum(0).view(24, 3).sum(1)


def sample_poses(step: int) -> torch.Tensor:
    """(M, 24, 3, 3) every ``step``-th frame of the train mocap, heading removed."""
    m = MocapPoses.load("train")
    r = roma.rotvec_to_rotmat(torch.from_numpy(m.rotvec[::step]).float())
    r[:, 0] = remove_yaw(r[:, 0])
    return r


def cluster_anchors(poses: torch.Tensor, joint_weights: torch.Tensor, k: int, seed: int = 0) -> np.ndarray:
    """Indices of ``k`` anchor poses among ``poses``: weighted k-means on the joint rotation
    vectors (each joint scaled by the square root of its weight), the member nearest each centre."""
    w = (joint_weights / joint_weights.sum()).sqrt().repeat_interleave(3)
    x = (pose_vector(poses) * w).double().numpy()
    centres, label = kmeans2(x, k, minit="++", seed=seed)
    out = []
    for c in range(k):
        members = np.nonzero(label == c)[0]
        if len(members):
            out.append(members[np.argmin(((x[members] - centres[c]) ** 2).sum(1))])
    return np.array(out)


# --- the drapes (worker processes) ----------------------------------------------------------------
_W: dict = {}


def _worker_init(cfg: TaylorBuildConfig) -> None:
    torch.set_num_threads(1)
    body = default_body()
    pbns, _ = PBNS.load(store.pbns_path(cfg.outfit))
    outfit, shape0, _ = trained_outfit(body, store.pbns_path(cfg.outfit))
    _W.update(body=body, pbns=pbns, shape0=shape0, first=DrapeSolver(outfit, cfg.drape),
              other=DrapeSolver(outfit, replace(cfg.drape, rounds=cfg.shape_rounds)),
              transfer=Transfer(body, pbns.rest.numpy(), pbns.faces.numpy(), shape0))


@torch.no_grad()
def drape_bodies(pose: torch.Tensor, shapes: torch.Tensor) -> dict:
    """At one pose (24, 3, 3): the drapes on the pose model's body, then on ``shapes`` (K, S),
    each started from the first moved by the change of the graded, skinned outfit. Returns
    {"posed", "unposed": (K + 1, N, 3), "strain": (K + 1,) largest edge strain (m)}."""
    w = _W
    pbns, posed, out, strains = w["pbns"], [], [], []
    rests = torch.cat([pbns.rest[None], torch.from_numpy(w["transfer"].resize(shapes))]) if len(shapes) \
        else pbns.rest[None]
    first = None
    e = w["first"].crit.edge.edges
    for shape, rest in zip(torch.cat([w["shape0"][None], shapes]), rests):
        bv, bn, bt = posed_bodies(w["body"], pose[None], shape[None])
        skinned = pbns.skin(rest, bt)[0]
        if first is None:
            x = w["first"](rest, skinned, bv[0], bn[0])
            first = (x, skinned)
        else:
            x = w["other"](rest, first[0] + skinned - first[1], bv[0], bn[0], carried=skinned)
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
    """``drape_bodies`` at each of ``poses`` (P, 24, 3, 3) on ``shapes`` (K, S; or one (K, S) per
    pose), kept in ``drape_folder`` as each pose is done (a rerun drapes only what is missing),
    in ``cfg.workers`` processes."""
    per_pose = list(shapes) if isinstance(shapes, list) else [shapes] * len(poses)
    folder = drape_folder(cfg, shapes if torch.is_tensor(shapes) else torch.cat(per_pose))
    folder.mkdir(parents=True, exist_ok=True)
    keys = [hashlib.sha256(p.numpy().round(5).tobytes() + s.numpy().round(6).tobytes()).hexdigest()[:16]
            if not torch.is_tensor(shapes) else hashlib.sha256(p.numpy().round(5).tobytes()).hexdigest()[:16]
            for p, s in zip(poses, per_pose)]
    files = [folder / f"{k}.npz" for k in keys]
    todo = [i for i, f in enumerate(files) if not f.exists()]
    t0 = time.time()
    if todo:
        bar = tqdm(total=len(poses), initial=len(poses) - len(todo), desc=f"{desc} {cfg.outfit}", unit="pose",
                   disable=not progress)
        ctx = mp.get_context("spawn")  # fresh interpreters: no forked torch state
        with ProcessPoolExecutor(cfg.workers, mp_context=ctx, initializer=_worker_init, initargs=(cfg,)) as pool:
            futures = {pool.submit(drape_bodies, poses[i], per_pose[i]): i for i in todo}
            for fut in as_completed(futures):
                i, r = futures[fut], fut.result()
                paths.atomic_write(files[i], lambda t, r=r: np.savez(t, **r))
                bar.update()
        bar.close()
        timing = folder / "timing.json"  # wall seconds spent draping into this folder, over all runs
        spent = json.loads(timing.read_text())["seconds"] if timing.exists() else 0.0
        paths.write_text(timing, json.dumps({"seconds": spent + time.time() - t0, "workers": cfg.workers}))
    return [dict(np.load(f)) for f in files]


def draping_seconds(cfg: TaylorBuildConfig, shapes: torch.Tensor) -> float | None:
    """Wall seconds spent making the drapes of ``drape_folder`` (None: not recorded)."""
    timing = drape_folder(cfg, shapes) / "timing.json"
    return json.loads(timing.read_text())["seconds"] if timing.exists() else None


def read_meta(path: Path) -> str:
    """The build record (JSON) of a Taylor model file."""
    return paths.load_checkpoint(path, "recon garment train --model taylor")["meta_json"]


# --- the build ------------------------------------------------------------------------------------
def build(cfg: TaylorBuildConfig, out: Path | None = None, log=print, progress: bool = True) -> Path:
    """Build an outfit's Taylor model; returns where it was written (``store.taylor_path``)."""
    t0 = time.time()
    body = default_body()
    pbns, _ = PBNS.load(store.pbns_path(cfg.outfit))
    outfit, shape0, _ = trained_outfit(body, store.pbns_path(cfg.outfit))
    shapes = database_shapes(cfg.shapes, cfg.seed)
    transfer = Transfer(body, pbns.rest.numpy(), pbns.faces.numpy(), shape0)
    train = sample_poses(cfg.frame_step)
    rng = np.random.default_rng(cfg.seed)
    picks = train[torch.from_numpy(rng.choice(len(train), cfg.sensitivity_poses, replace=False))]
    all_shapes = torch.cat([shape0[None], shapes])
    graded = torch.cat([pbns.rest[None], torch.from_numpy(transfer.resize(shapes))])  # the outfit on each body
    bodies = all_shapes[:3]
    s = torch.stack([sensitivity(pbns, body, p, b, r, cfg.sensitivity_step)
                     for p in picks for b, r in zip(bodies, graded)]).mean(0)
    q, joint_w = region_sensitivity(s, region_weights(pbns.weights.detach()))
    log(f"sensitivity from {len(picks) * len(bodies)} samples; joint weights "
        + ", ".join(f"{n} {w:.2f}" for n, w in sorted(zip(skeleton.JOINT_NAMES, (joint_w / joint_w.max()).tolist()),
                                                     key=lambda t: -t[1])[:6]))
    idx = cluster_anchors(train, joint_w, cfg.anchors, cfg.seed)
    anchors = train[torch.from_numpy(idx)]
    log(f"{len(anchors)} anchors from {len(train)} train poses; {cfg.shapes + 1} bodies each")
    t_drape = time.time()
    drapes = drape_poses(cfg, anchors, shapes, progress)
    t_drape = time.time() - t_drape
    first = [torch.from_numpy(d["unposed"][0]).float() for d in drapes]  # on the pose model's body
    examples = anchors
    if cfg.pose_examples:
        extra = train[torch.from_numpy(cluster_anchors(train, joint_w, cfg.pose_examples, cfg.seed))]
        log(f"{len(extra)} pose examples on the pose model's body")
        t = time.time()
        first += [torch.from_numpy(d["unposed"][0]).float()
                  for d in drape_poses(cfg, extra, torch.zeros(0, len(shape0)), progress, desc="pose examples")]
        t_drape += time.time() - t
        examples = torch.cat([anchors, extra])
    first = torch.stack(first)
    t = time.time()
    pose_model = fit_pose_model(pbns, examples, first, cfg.pose_fit) if cfg.pose_fit.trains else pbns
    with torch.no_grad():  # the pose model's miss at each example (unposed)
        pose_residual = first - pose_model.rest - pose_model.deformation(examples)
        miss = float(pose_residual.norm(dim=-1).mean()) * 1000
        pbns_miss = float((first - pbns.rest - pbns.deformation(examples)).norm(dim=-1).mean()) * 1000
    log(f"pose model: mean miss at the {len(examples)} examples {miss:.1f} mm (PBNS as trained {pbns_miss:.1f}; "
        f"fitted in {time.time() - t:.0f} s)")
    for d in drapes:
        d["unposed"] = torch.from_numpy(d["unposed"]).float() - graded
    loo = {}
    if cfg.ridge is None:  # chosen on every 4th anchor's drapes, each body left out in turn
        loo = {r: float(np.mean([leave_one_out(all_shapes, d["unposed"], cfg.components, r)
                                 for d in drapes[::4]])) * 1000 for r in RIDGES}
        log("shape model, leave-one-body-out error by ridge: "
            + ", ".join(f"{r:g}: {e:.1f} mm" for r, e in loo.items()))
    ridge = cfg.ridge if cfg.ridge is not None else min(loo, key=loo.get)
    basis, maps, explained = [], [], []
    for d in drapes:
        u = d["unposed"]
        mean, b, m = fit_shape_model(all_shapes, u, cfg.components, ridge)
        basis.append(b)
        maps.append(m)
        flat = (u - u.mean(0)).reshape(len(u), -1)
        total = float((flat ** 2).sum())
        kept = float(((flat @ b.reshape(len(b), -1).T) ** 2).sum())
        explained.append(kept / max(total, 1e-12))
    model = TaylorGarment(pose_model, anchors, q, torch.stack(basis), torch.stack(maps), shape0, cfg.blend,
                          pose_residual, pose_examples=examples if cfg.pose_examples else None,
                          fitted=pose_model is not pbns)
    strain = np.stack([d["strain"] for d in drapes])
    meta = {"outfit": cfg.outfit, "config": asdict(cfg), "shapes": all_shapes.tolist(),
            "pbns_sha256": hashlib.sha256(store.pbns_path(cfg.outfit).read_bytes()).hexdigest(),
            "joint_weights": joint_w.tolist(), "explained_variance": float(np.mean(explained)),
            "ridge": ridge, "leave_one_out_mm": {str(k): v for k, v in loo.items()},
            "max_strain_mm_p95": float(np.percentile(strain, 95) * 1000),
            "drape_seconds": (draping_seconds(cfg, shapes) or 0.0) + (draping_seconds(cfg, torch.zeros(0, len(shape0)))
                                                                      or 0.0) or None,
            "fit_seconds": time.time() - t0 - t_drape, "anchors": len(anchors),
            "pose_examples": len(pose_residual), "pose_model_miss_mm": miss, "pbns_miss_mm": pbns_miss}
    path = Path(out) if out else store.taylor_path(cfg.outfit)
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path, json.dumps(meta))
    log(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB; PCA keeps {100 * meta['explained_variance']:.1f} % "
        f"of the shape variance; draping {(meta['drape_seconds'] or 0) / 60:.1f} min, the rest "
        f"{meta['fit_seconds'] / 60:.1f} min)")
    return path
