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
5. The pose model fitted (``fit_pose_model``): PBNS's network (widened, ``PoseFitConfig.hidden``)
   and blend shapes trained further on the examples' drapes (anchors' first drapes and pose
   examples) and on ``PoseFitConfig.poses`` more train poses draped on its body for the fit alone,
   so the pose model learns where the drape solver's quasi-static state lies at any pose, not only
   at an example; the examples' corrections are then its residuals there, blended or not
   (``PoseFitConfig.corrections``).

Drapes (``taylor.data``) run in ``workers`` processes, one pose a task, each kept in
``<cache>/taylor-drapes/`` (resumable: a rerun drapes only what is missing).
"""
from __future__ import annotations

import copy
import hashlib
import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import roma
import torch
from scipy.cluster.vq import kmeans2
from scipy.stats import qmc

from recon import paths
from recon.body import default_body, skeleton
from recon.body.base import BodyModel
from recon.garment import store
from recon.garment.data import posed_bodies
from recon.garment.pbns.model import PBNS, pose_features, trained_outfit, widened
from recon.garment.resize import Transfer
from recon.garment.taylor.config import SHAPE_BOX, PoseFitConfig, TaylorBuildConfig
from recon.garment.taylor.data import drape_poses, draping_seconds, fit_only_poses, pose_model_drapes, sample_poses
from recon.garment.taylor.model import (
    TaylorGarment,
    fit_shape_model,
    pose_vector,
    region_weights,
    shape_features,
)

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
    if cfg.hidden:  # the new units' initial weights drawn from cfg.seed: a rebuild makes the same model
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(cfg.seed)
            model.mlp = widened(model.mlp, cfg.hidden)
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
def sensitivity(pbns: PBNS, body: BodyModel, rotmats: torch.Tensor, shape: torch.Tensor, rest: torch.Tensor,
                step: float = 0.05) -> torch.Tensor:
    """(N, 72) |d x_y / d theta_m|: how far each cloth vertex of the pose model (its rest ``rest``
    on body ``shape``) moves per radian of each joint rotation component at pose (24, 3, 3)."""
    r = perturbed(rotmats, step)
    _, _, bt = posed_bodies(body, r, shape.reshape(1, -1))
    x = pbns.skin(rest + pbns.deformation(r), bt)
    j = (x[:72] - x[72:]) / (2 * step)  # (72, N, 3)
    return j.norm(dim=-1).T


def region_sensitivity(s: torch.Tensor, regions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean sensitivity (N, 72) -> (Q (G, 72): per region the weight of each squared joint-angle
    difference, eq. 7, normalised to sum to 1; joint weights (24,): eq. 11)."""
    q = regions.T @ s ** 2
    return q / q.sum(1, keepdim=True).clamp_min(1e-12), s.sum(0).view(24, 3).sum(1)


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
    first = torch.stack([torch.from_numpy(d["unposed"][0]).float() for d in drapes])  # on the pose model's body
    examples = anchors
    if cfg.pose_examples:
        extra = train[torch.from_numpy(cluster_anchors(train, joint_w, cfg.pose_examples, cfg.seed))]
        log(f"{len(extra)} pose examples on the pose model's body")
        t = time.time()
        first = torch.cat([first, pose_model_drapes(cfg, extra, len(shape0), progress, "pose examples")])
        t_drape += time.time() - t
        examples = torch.cat([anchors, extra])
    fit_poses, fit_drapes = examples, first
    if cfg.pose_fit.poses and cfg.pose_fit.trains:
        more = fit_only_poses(train, examples, cfg.pose_fit.poses, cfg.seed)
        log(f"{len(more)} more poses on the pose model's body for its fit")
        t = time.time()
        more_drapes = pose_model_drapes(cfg, more, len(shape0), progress, "fit poses")
        t_drape += time.time() - t
        fit_poses, fit_drapes = torch.cat([examples, more]), torch.cat([first, more_drapes])
    t = time.time()
    pose_model = fit_pose_model(pbns, fit_poses, fit_drapes, cfg.pose_fit) if cfg.pose_fit.trains else pbns
    with torch.no_grad():  # the pose model's miss at each example (unposed)
        pose_residual = first - pose_model.rest - pose_model.deformation(examples)
        miss = float(pose_residual.norm(dim=-1).mean()) * 1000
        pbns_miss = float((first - pbns.rest - pbns.deformation(examples)).norm(dim=-1).mean()) * 1000
    log(f"pose model: mean miss at the {len(examples)} examples {miss:.1f} mm (PBNS as trained {pbns_miss:.1f}; "
        f"fitted on {len(fit_poses)} drapes in {time.time() - t:.0f} s)")
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
                          pose_residual, correct_pose=cfg.pose_fit.corrections or pose_model is pbns,
                          pose_examples=examples if cfg.pose_examples else None, fitted=pose_model is not pbns)
    strain = np.stack([d["strain"] for d in drapes])
    meta = {"outfit": cfg.outfit, "config": asdict(cfg), "shapes": all_shapes.tolist(),
            "pbns_sha256": hashlib.sha256(store.pbns_path(cfg.outfit).read_bytes()).hexdigest(),
            "joint_weights": joint_w.tolist(), "explained_variance": float(np.mean(explained)),
            "ridge": ridge, "leave_one_out_mm": {str(k): v for k, v in loo.items()},
            "max_strain_mm_p95": float(np.percentile(strain, 95) * 1000),
            "drape_seconds": (draping_seconds(cfg, shapes) or 0.0) + (draping_seconds(cfg, torch.zeros(0, len(shape0)))
                                                                      or 0.0) or None,
            "fit_seconds": time.time() - t0 - t_drape, "anchors": len(anchors),
            "pose_examples": len(pose_residual), "fit_poses": len(fit_poses) - len(examples),
            "pose_model_miss_mm": miss, "pbns_miss_mm": pbns_miss}
    path = Path(out) if out else store.taylor_path(cfg.outfit)
    path.parent.mkdir(parents=True, exist_ok=True)
    model.save(path, json.dumps(meta))
    log(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB; PCA keeps {100 * meta['explained_variance']:.1f} % "
        f"of the shape variance; draping {(meta['drape_seconds'] or 0) / 60:.1f} min, the rest "
        f"{meta['fit_seconds'] / 60:.1f} min)")
    return path
