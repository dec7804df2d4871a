"""The quasi-static drape solver's speed (recon.garment.drape: the Taylor database's drapes, its
evaluation's references, the Dresser's drape iterations), side by side in one run: the shipped
solver against its earlier forms, on train poses on the outfit's PBNS body:

- "gradient at every trial": the minimiser's line search takes the energy's gradient at each trial
  step, rejected ones included (the shipped one takes it at accepted steps only: the same
  iterates, bit for bit);
- "advanced-indexing gathers": the edge and bending energies gather vertices and face normals
  with ``v[:, idx]`` instead of ``mesh.take`` (index_select): the same values and gradients;
- both earlier forms (the solver of 0.23.0).

Also timed with the same forms: the Dresser's continuation on a photo (``DRAPE_ITERATIONS``
iterations, one contact search, from the garment model's cloth; here PBNS's); and NCS's teacher,
the implicit integration that makes the NCS and the keyframe-authoring data with the same
minimiser and energies (seconds per simulated frame over a clip of the test mocap). Each form
runs every job once a round, rounds interleaved; the time is the median over rounds. Also
reported: how far each form's result lies from the shipped one (mean and largest vertex
distance): zero, the forms compute the same iterates.

    .venv/bin/python benchmarks/bench_drape.py [--outfits tshirt-skirt] [--poses 3] [--frames 10] [--rounds 2]

-> eval/results/bench-drape.{json,md} (one thread).
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch

import recon.garment.drape as drape_module
import recon.garment.integrate as integrate_module
from recon import report
from recon.garment import losses, store
from recon.garment.data import posed_bodies
from recon.garment.drape import DrapeSolver
from recon.garment.dress import DRAPE_ITERATIONS
from recon.garment.integrate import minimise
from recon.garment.ncs.config import NCSTrainConfig
from recon.garment.ncs.data import Teacher
from recon.garment.ncs.reference_eval import clip_motion
from recon.garment.pbns.model import trained_outfit
from recon.garment.taylor import data
from recon.garment.taylor.config import TaylorBuildConfig
from recon.poses.mocap import MocapPoses

OUT = Path(__file__).resolve().parent.parent / "eval" / "results"
CLIP, CLIP_START = "03_03", 975  # a test performer's turn (one of NCS's simulated clips)


class _Precomputed(torch.autograd.Function):
    """``f`` whose gradient with respect to ``x`` is the given ``g`` (no graph behind it)."""

    @staticmethod
    def forward(ctx, x, f, g):
        ctx.save_for_backward(g)
        return f.clone()

    @staticmethod
    def backward(ctx, out):
        g, = ctx.saved_tensors
        return out * g, None, None


def minimise_gradient_every_trial(energy, u, precond, cfg):
    """``integrate.minimise`` as it was before 0.24.0: the energy's gradient taken at every
    line-search trial (here with the energy, so the minimiser's own gradient costs nothing)."""
    def eager(x):
        f = energy(x)
        g, = torch.autograd.grad(f, x)
        return _Precomputed.apply(x, f.detach(), g)

    return minimise(eager, u, precond, cfg)


def face_normals_indexed(v: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """``mesh.face_normals`` before 0.24.0: the corners gathered by advanced indexing."""
    t = v[:, faces]
    n = torch.cross(t[:, :, 1] - t[:, :, 0], t[:, :, 2] - t[:, :, 0], dim=-1)
    return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def strain_indexed(v: torch.Tensor, edges: torch.Tensor, rest_len: torch.Tensor) -> torch.Tensor:
    """``metrics.strain`` before 0.24.0: each end of the edges gathered by advanced indexing."""
    return (v[:, edges[:, 0]] - v[:, edges[:, 1]]).norm(dim=-1) - rest_len


def bending_indexed(v: torch.Tensor, faces: torch.Tensor, adjacency: torch.Tensor,
                    weights: torch.Tensor | None = None) -> torch.Tensor:
    """``metrics.bending`` before 0.24.0: normals and face pairs gathered by advanced indexing."""
    n = face_normals_indexed(v, faces)
    d = ((n[:, adjacency[:, 0]] - n[:, adjacency[:, 1]]) ** 2).sum(-1)
    return (d if weights is None else weights * d).mean(1)


# each form: the minimiser, and the strain and bending the energies call
FORMS = {"shipped": (minimise, losses.strain, losses.bending),
         "gradient at every trial": (minimise_gradient_every_trial, losses.strain, losses.bending),
         "advanced-indexing gathers": (minimise, strain_indexed, bending_indexed),
         "both (0.23.0)": (minimise_gradient_every_trial, strain_indexed, bending_indexed)}


def timed(form: str, fn) -> tuple[float, np.ndarray]:
    """(wall seconds, result) of ``fn()`` with one form's minimiser and energies in place."""
    shipped = drape_module.minimise, integrate_module.minimise, losses.strain, losses.bending
    drape_module.minimise = integrate_module.minimise = FORMS[form][0]
    losses.strain, losses.bending = FORMS[form][1:]
    try:
        t = time.perf_counter()
        out = fn()
        return time.perf_counter() - t, out
    finally:
        drape_module.minimise, integrate_module.minimise, losses.strain, losses.bending = shipped


def continued(draper: data.Draper, solver: DrapeSolver, pose: torch.Tensor) -> np.ndarray:
    """PBNS's cloth at ``pose`` (24, 3, 3) on its body continued by ``solver``, as the Dresser
    continues the Taylor model's on a photo (its rest the outfit, the tether's target it skinned)."""
    bv, bn, bt = posed_bodies(draper.body, pose[None], draper.shape0[None])
    pbns = draper.pbns
    x = pbns.pose(pose[None], bt)[0]
    return solver(pbns.rest, x, bv[0], bn[0], carried=pbns.skin(pbns.rest[None], bt)[0]).numpy()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--outfits", nargs="+", default=["tshirt-skirt"])
    ap.add_argument("--poses", type=int, default=3)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(1)
    rows = []
    for outfit in args.outfits:
        cfg = TaylorBuildConfig(outfit=outfit)
        draper = data.Draper(cfg)  # the build's worker: body, PBNS, solvers
        train = data.sample_poses(cfg.frame_step)
        poses = train[torch.linspace(0, len(train) - 1, args.poses).long()]
        no_bodies = torch.zeros(0, len(draper.shape0))
        teacher = Teacher(draper.body, outfit, NCSTrainConfig())
        settle = teacher.cfg.settle
        rot, transl = clip_motion(MocapPoses.load("test"), CLIP, CLIP_START, args.frames)
        continuation = DrapeSolver.continuation(trained_outfit(draper.body, store.pbns_path(outfit))[0],
                                                DRAPE_ITERATIONS)
        jobs = {"drape": (lambda: np.stack([draper.drape_bodies(p, no_bodies)["posed"][0] for p in poses]),  # noqa: B023
                          len(poses)),
                f"{DRAPE_ITERATIONS} iterations from PBNS (a photo)": (
                    lambda: np.stack([continued(draper, continuation, p) for p in poses]), len(poses)),  # noqa: B023
                "NCS teacher": (lambda: teacher(rot, transl).numpy(), settle + args.frames)}  # noqa: B023
        seconds = {(job, form): [] for job in jobs for form in FORMS}
        out = {}
        for _ in range(args.rounds):
            for job, (fn, count) in jobs.items():
                for form in FORMS:
                    s, out[job, form] = timed(form, fn)
                    seconds[job, form].append(s / count)
        for job in jobs:
            shipped = statistics.median(seconds[job, "shipped"])
            for form in FORMS:
                dist = np.linalg.norm(out[job, form] - out[job, "shipped"], axis=-1) * 1000
                s = statistics.median(seconds[job, form])
                rows.append([outfit, job, out[job, form].shape[-2], form, s, s / shipped, float(dist.mean()),
                             float(dist.max())])
    data_out = {"machine": report.machine(), "poses": args.poses, "frames": args.frames, "clip": [CLIP, CLIP_START],
                "rounds": args.rounds, "rows": rows}
    md = "\n".join([
        "# Quasi-static drape solver speed, 1 thread", "",
        f"`benchmarks/bench_drape.py --poses {args.poses} --frames {args.frames} --rounds {args.rounds}`; "
        f"{report.describe(data_out['machine'])}. Drape: seconds per drape on the outfit's PBNS body (the default "
        "solver: 4 contact rounds of at most 40 L-BFGS iterations) at train poses. A photo: the Dresser's "
        f"continuation ({DRAPE_ITERATIONS} iterations, one contact search) from PBNS's cloth at the same poses. "
        f"NCS teacher: seconds per simulated frame of its hanging part ({settle} settling frames on the first "
        f"pose, then {args.frames} frames of test clip {CLIP} from frame {CLIP_START}). Median over interleaved "
        "rounds; ratio = the form's time / the shipped one's. Distance: the form's result to the shipped one's, "
        "mean and largest over vertices and poses or frames (mm): 0, the forms compute the same iterates.", "",
        report.table(rows, ["outfit", "job", "vertices", "form", "s each", "ratio", "distance mean mm",
                            "distance max mm"], ["", "", "", "", ".2f", ".2f", ".2f", ".1f"])])
    print(Path(report.write(OUT / "bench-drape", data_out, md)).read_text())


if __name__ == "__main__":
    main()
