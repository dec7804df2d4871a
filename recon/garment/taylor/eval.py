"""``recon garment eval --model taylor``: the Taylor model against the quasi-static drape (the
database's own solver, recon.garment.drape) on held-out poses of the test performers x anny
bodies that are not in the database, beside skinning, PBNS (graded outfit) and PBNS + resizer.
Also the error against the number of anchors, the paper's separability check (error against the
distance from an anchor, practical and theoretical), frames a second and the database's size and
build time. Writes eval/results/garment-taylor.{json,md}.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch

from recon import report
from recon.body import default_body
from recon.body.base import BodyModel
from recon.garment import reference, store
from recon.garment.collide import CollisionResolver
from recon.garment.data import pose_set, posed_bodies
from recon.garment.drape import DrapeSolver
from recon.garment.metrics import physical_metrics
from recon.garment.pbns.model import PBNS, remove_yaw, trained_outfit
from recon.garment.resize import OutfitResizer, Transfer
from recon.garment.taylor.config import SHAPE_BOX, TaylorBuildConfig
from recon.garment.taylor.curves import example_subset, separability, speed, subset
from recon.garment.taylor.data import drape_poses
from recon.garment.taylor.garment_model import DRAPE_ITERATIONS
from recon.garment.taylor.model import TaylorGarment
from recon.garment.taylor.reference_eval import newton_comparison
from recon.poses.sampler import ShapeSampler

PHENOTYPES = ("weight", "height")  # "far" bodies: top or bottom quintile of either in anny's prior
POSTED = "Taylor + post-step"
REFINED = "Taylor + drape iterations + post-step"  # what the Dresser returns for a single pose
VAL_ITERATIONS = (10, 20, 40)  # drape-solver iterations after the model, scored on val
VAL_SEED = 2025  # val poses and bodies: other draws than the test's
NEWTON_POSES = (3, 11)  # of the test poses: the drape solver against newton's (minutes each)
CORRECTED_PBNS = "Taylor, PBNS corrected at the examples as pose model"
CORRECTED = "Taylor, fitted pose model with example corrections"
UNCORRECTED = "Taylor, fitted pose model without example corrections"


def test_shapes(body: BodyModel, n_far: int = 6, n_near: int = 2, seed: int = 2024) -> tuple[torch.Tensor, np.ndarray]:
    """Held-out bodies from anny's prior: ``n_far`` with weight or height in its top or bottom
    quintile, ``n_near`` with both in the middle fifth; (K, S) and a bool (K,) far mask."""
    s = ShapeSampler(body, seed=seed).sample(4000).float()
    cols = [list(body.shape_names).index(n) for n in PHENOTYPES]
    q = np.stack([np.searchsorted(np.sort(s[:, c].numpy()), s[:, c].numpy()) / len(s) for c in cols], 1)
    inside = np.all([(s[:, i] >= lo) & (s[:, i] <= hi) for i, (lo, hi) in enumerate(SHAPE_BOX)], 0)
    far = np.nonzero(((q < 0.2) | (q > 0.8)).any(1) & inside)[0]
    near = np.nonzero((np.abs(q - 0.5) < 0.1).all(1) & inside)[0]
    rng = np.random.default_rng(seed)
    # the far ones spread over the four extremes: low/high weight, low/high height in turn
    picks = []
    for k in range(n_far):
        c, high = k % 2, (k // 2) % 2
        pool = [i for i in far if (q[i, c] > 0.8 if high else q[i, c] < 0.2) and i not in picks]
        picks.append(int(rng.choice(pool)))
    picks += [int(i) for i in rng.choice(near, n_near, replace=False)]
    return s[picks], np.array([True] * n_far + [False] * n_near)


def test_poses(n: int, seed: int = 7) -> torch.Tensor:
    """(n, 24, 3, 3) balanced poses of the test performers, heading removed."""
    r = pose_set("test", n, 0.5, seed)
    r[:, 0] = remove_yaw(r[:, 0])
    return r


class Methods:
    """Every model of the table on one outfit, dressing one (pose, body) pair."""

    def __init__(self, body: BodyModel, outfit: str, taylor_path: Path):
        self.body = body
        self.pbns, ck = PBNS.load(store.pbns_path(outfit))
        self.shape0 = ck["shape"]
        self.taylor, self.tck = TaylorGarment.load(taylor_path, self.pbns)
        # with a fitted pose model, the same database on PBNS as trained: what the fit adds
        self.on_pbns = self.taylor.with_pose_model(self.pbns) if self.taylor.fitted else None
        if self.on_pbns is not None:
            self.on_pbns.correct_pose = True  # PBNS as trained is corrected at the examples
        self.transfer = Transfer(body, self.pbns.rest.numpy(), self.pbns.faces.numpy(), self.shape0)
        rp = store.resizer_path(outfit)
        self.resizer = OutfitResizer(body, rp, self.pbns.rest.numpy(), self.pbns.faces.numpy()) if rp.exists() else None
        self.resolver = CollisionResolver(self.pbns.faces.numpy(), ck["layer"].numpy())
        self.outfit = trained_outfit(body, store.pbns_path(outfit))[0]
        self._solvers: dict[int, DrapeSolver] = {}

    def refined(self, x: torch.Tensor, iterations: int, bv, bn, bt) -> tuple[torch.Tensor, float]:
        """Taylor's cloth (1, N, 3) continued by ``iterations`` of the drape solver, then the post-step
        (the Dresser's single-pose path): (N, 3) and its seconds."""
        if iterations not in self._solvers:
            self._solvers[iterations] = DrapeSolver.continuation(self.outfit, iterations)
        t = time.perf_counter()
        v = self.taylor.continued(x, self._solvers[iterations], bv, bn, bt)
        v = self.resolver(v, bv, self.body.faces, rest=self.taylor.graded[None])[0]
        return v, time.perf_counter() - t

    @torch.no_grad()
    def __call__(self, rot: torch.Tensor, shape: torch.Tensor, sim_pose_model: torch.Tensor | None) -> dict:
        """(24, 3, 3), (S,), the unposed drape on the pose model's body at this pose (N, 3) ->
        ({method: (N, 3)}, (body vertices, normals), the graded rest outfit)."""
        bv, bn, bt = posed_bodies(self.body, rot[None], shape[None])
        graded = torch.from_numpy(self.transfer.resize(shape[None]))[0]
        d_t = self.pbns.deformation(rot[None])[0]
        out = {"skinning only": self.pbns.skin(graded, bt)[0], "PBNS (graded)": self.pbns.skin(graded + d_t, bt)[0]}
        if self.resizer is not None:
            resized = self.resizer.rest(shape[None])[0]
            pv = self.pbns.skin(resized + d_t, bt)
            out["PBNS + resizer"] = pv[0]
            out["PBNS + resizer + collision resolution"] = self.resolver(pv, bv, self.body.faces)[0]
        self.taylor.set_shape(self.body, shape)
        out["Taylor, no penetration handling"] = self.taylor.pose(rot[None], bt)[0]
        out["Taylor"] = self.taylor.pose(rot[None], bt, bv)[0]
        out[POSTED] = self.resolver(out["Taylor"][None], bv, self.body.faces, rest=self.taylor.graded[None])[0]
        out[REFINED] = self.refined(out["Taylor"][None], DRAPE_ITERATIONS, bv, bn, bt)[0]
        on_pbns = self.on_pbns or self.taylor
        if self.on_pbns is not None:
            on_pbns.set_shape(self.body, shape)
            out[CORRECTED_PBNS] = on_pbns.pose(rot[None], bt, bv)[0]
            for name, on in ((CORRECTED, True), (UNCORRECTED, False)):
                with self.taylor.corrections(on):
                    out[name] = self.taylor.pose(rot[None], bt, bv)[0]
        with on_pbns.corrections(False):
            out["Taylor, PBNS as pose model"] = on_pbns.pose(rot[None], bt, bv)[0]
        if sim_pose_model is not None:
            sim = sim_pose_model[None]
            out["Taylor, simulation as pose model"] = self.taylor.pose(rot[None], bt, bv, pose_model=sim)[0]
        return out, (bv, bn), graded


def _mean(xs) -> float | None:
    return float(np.mean(xs)) if len(xs) else None


def score(v: torch.Tensor, gt: torch.Tensor, faces: np.ndarray, graded, bv, bn) -> tuple[float, float, float]:
    """A cloth (N, 3) against its drape: mean vertex error (mm), collisions (%), edge error (mm)."""
    phys = physical_metrics(v[None], faces, graded, bv, bn)
    return float((v - gt).norm(dim=-1).mean()) * 1000, phys["collision_pct"], phys["edge_mm"]


@torch.no_grad()
def val_check(cfg: TaylorBuildConfig, m: Methods, body: BodyModel, poses: int, faces: np.ndarray) -> dict:
    """Taylor alone, with the Dresser's post-step and with drape-solver iterations before it, on
    val poses (val performers) x other bodies than the test's: where the Taylor path's choices
    are made."""
    shapes, far = test_shapes(body, seed=VAL_SEED)
    r = pose_set("val", poses, 0.5, VAL_SEED)
    r[:, 0] = remove_yaw(r[:, 0])
    drapes = drape_poses(cfg, r, shapes, desc="val drapes")
    acc: dict = {}
    for p in range(len(r)):
        for k in range(len(shapes)):
            gt = torch.from_numpy(drapes[p]["posed"][k + 1])
            bv, bn, bt = posed_bodies(body, r[p][None], shapes[k][None])
            m.taylor.set_shape(body, shapes[k])
            graded = m.taylor.graded
            t = time.perf_counter()
            x = m.taylor.pose(r[p][None], bt, bv)
            seconds = time.perf_counter() - t
            acc.setdefault("Taylor", []).append((*score(x[0], gt, faces, graded, bv, bn), seconds))
            if m.on_pbns is not None:
                m.on_pbns.set_shape(body, shapes[k])
                for name, model, on in ((CORRECTED_PBNS, m.on_pbns, True), (CORRECTED, m.taylor, True),
                                        (UNCORRECTED, m.taylor, False)):
                    with model.corrections(on):
                        t = time.perf_counter()
                        y = model.pose(r[p][None], bt, bv)
                        sec = time.perf_counter() - t  # before scoring
                    acc.setdefault(name, []).append((*score(y[0], gt, faces, graded, bv, bn), sec))
            t = time.perf_counter()
            v = m.resolver(x, bv, body.faces, rest=graded[None])[0]
            acc.setdefault(POSTED, []).append((*score(v, gt, faces, graded, bv, bn), seconds + time.perf_counter() - t))
            for n in VAL_ITERATIONS:
                v, s = m.refined(x, n, bv, bn, bt)
                acc.setdefault(f"Taylor + {n} drape iterations + post-step", []).append(
                    (*score(v, gt, faces, graded, bv, bn), seconds + s))
    return {"poses": len(r), "bodies": len(shapes), "rows": {
        name: {"error_mm": _mean([a[0] for a in v]), "collision_pct": _mean([a[1] for a in v]),
               "edge_mm": _mean([a[2] for a in v]), "seconds": _mean([a[3] for a in v])} for name, v in acc.items()}}


def evaluate(outfit: str, poses: int = 20, workers: int = 2, anchor_counts=(8, 16, 32, 64),
             example_counts=(128, 256), radii=(0.05, 0.1, 0.2, 0.4), separability_samples: int = 2,
             val_poses: int = 10, log=print) -> dict:
    body = default_body()
    path = store.taylor_path(outfit)
    cfg = TaylorBuildConfig(outfit=outfit, workers=workers)
    m = Methods(body, outfit, path)
    meta = json.loads(m.tck["meta_json"])
    shapes, far = test_shapes(body)
    rot = test_poses(poses)
    drapes = drape_poses(cfg, rot, shapes, desc="ground truth")
    faces = m.pbns.faces.numpy()
    joint_w = torch.tensor(meta["joint_weights"])
    subsets = {n: subset(m.taylor, joint_w, n) for n in anchor_counts if n < len(m.taylor.anchors)}
    n_examples = len(m.taylor.example_poses)
    # on PBNS as trained: a fitted pose model has learned from every example
    example_subsets = {n: example_subset(m.on_pbns or m.taylor, joint_w, n)
                       for n in (len(m.taylor.anchors), *example_counts) if n < n_examples}
    acc: dict = {}
    curve = {n: {"far": [], "all": []} for n in subsets}
    example_curve = {n: {"far": [], "all": []} for n in example_subsets}

    def add(name, v, gt, k, bv, bn, graded):
        err, coll, edge = score(v, gt, faces, graded, bv, bn)
        acc.setdefault(name, []).append((err, bool(far[k]), coll, edge))

    for p in range(len(rot)):
        for k in range(len(shapes)):
            gt = torch.from_numpy(drapes[p]["posed"][k + 1])
            outs, (bv, bn), graded = m(rot[p], shapes[k], torch.from_numpy(drapes[p]["unposed"][0]))
            for name, v in outs.items():
                add(name, v, gt, k, bv, bn, graded)
            add("drape (ground truth)", gt, gt, k, bv, bn, graded)
            _, _, bt = posed_bodies(body, rot[p][None], shapes[k][None])
            for models, c in ((subsets, curve), (example_subsets, example_curve)):
                for n, sub in models.items():
                    sub.set_shape(body, shapes[k])
                    e = float((sub.pose(rot[p][None], bt, bv)[0] - gt).norm(dim=-1).mean()) * 1000
                    c[n]["all"].append(e)
                    if far[k]:
                        c[n]["far"].append(e)
    rows = {name: {"error_mm": _mean([a[0] for a in v]), "error_far_mm": _mean([a[0] for a in v if a[1]]),
                   "error_near_mm": _mean([a[0] for a in v if not a[1]]), "collision_pct": _mean([a[2] for a in v]),
                   "edge_mm": _mean([a[3] for a in v])} for name, v in acc.items()}
    anchors_curve = {str(n): {"error_mm": _mean(c["all"]), "error_far_mm": _mean(c["far"])} for n, c in curve.items()}
    anchors_curve[str(len(m.taylor.anchors))] = {"error_mm": rows["Taylor"]["error_mm"],
                                                "error_far_mm": rows["Taylor"]["error_far_mm"]}
    examples_curve = {str(n): {"error_mm": _mean(c["all"]), "error_far_mm": _mean(c["far"])}
                      for n, c in example_curve.items()}
    full = rows[CORRECTED_PBNS if m.on_pbns is not None else "Taylor"]
    examples_curve[str(n_examples)] = {"error_mm": full["error_mm"], "error_far_mm": full["error_far_mm"]}
    log("scored; separability")
    sep = separability(cfg, m.taylor, body, [0, len(m.taylor.anchors) // 2], radii, separability_samples)
    val = val_check(cfg, m, body, val_poses, faces) if val_poses else None
    return {"outfit": outfit, "poses": len(rot), "shapes": shapes.tolist(), "far": far.tolist(), "rows": rows,
            "drape_iterations": DRAPE_ITERATIONS,
            "val": val,
            "anchors_curve": anchors_curve, "examples_curve": examples_curve, "separability": sep, "database": {
                "anchors": meta["anchors"], "bodies_per_anchor": len(meta["shapes"]),
                "pose_examples": meta.get("pose_examples", meta["anchors"]), "fit_poses": meta.get("fit_poses", 0),
                "size_mb": path.stat().st_size / 1e6,
                "build_min": ((meta["drape_seconds"] or 0.0) + meta["fit_seconds"]) / 60, "ridge": meta["ridge"],
                "explained_variance_pct": 100 * meta["explained_variance"]}}


ROW_ORDER = ("skinning only", "PBNS (graded)", "PBNS + resizer", "PBNS + resizer + collision resolution",
             "Taylor, PBNS as pose model", CORRECTED_PBNS, CORRECTED, UNCORRECTED,
             "Taylor, no penetration handling", "Taylor", POSTED, REFINED, "Taylor, simulation as pose model",
             "drape (ground truth)")


def render(data: dict) -> str:
    out = ["# Example-based Taylor garment model against the quasi-static drape", ""]
    for name, r in data["outfits"].items():
        db = r["database"]
        out += [f"## {name}", "",
                f"{r['poses']} held-out poses (test performers) x {len(r['shapes'])} anny bodies not in the database "
                f"({sum(r['far'])} far: weight or height in the prior's top or bottom quintile); error = mean vertex "
                "distance to the drape of each pair (recon.garment.drape, the database's solver); edge against the "
                "outfit graded to the body. What the Dresser returns: Taylor + post-step for a motion's frames, "
                f"Taylor + drape iterations ({r['drape_iterations']} iterations of that solver from the model's cloth, "
                "one contact search) + post-step for a single pose.", ""]
        rows = [[k, *(r["rows"][k][c] for c in ("error_mm", "error_far_mm", "error_near_mm", "collision_pct",
                                                 "edge_mm"))] for k in ROW_ORDER if k in r["rows"]]
        out += [report.table(rows, ["model", "error mm", "far bodies mm", "near bodies mm", "collision %", "edge mm"],
                             [""] + [".2f"] * 5), ""]
        if r.get("val"):
            v = r["val"]
            out += [f"The choices of the Dresser's Taylor path, made on {v['poses']} val poses (val performers) x "
                    f"{v['bodies']} other bodies: the post-step (strain step and collision resolution, settings "
                    "chosen on DeePSD's val outfits) after the model (motions), and before it, for a single pose "
                    f"(a photo), iterations of the drape solver from the model's cloth (one contact search; the "
                    f"Dresser's `drape_iterations`, {r['drape_iterations']}). Seconds a frame on one thread:", "",
                    report.table([[k, *(v["rows"][k].get(c) for c in ("error_mm", "collision_pct", "edge_mm",
                                                                      "seconds"))]
                                  for k in v["rows"]],
                                 ["model (val)", "error mm", "collision %", "edge mm", "s a frame"],
                                 ["", ".2f", ".2f", ".2f", ".3f"]), ""]
        out += [f"Database: {db['anchors']} anchors x {db['bodies_per_anchor']} bodies and "
                f"{db.get('pose_examples', db['anchors'])} pose examples (the anchors and poses draped on the pose "
                f"model's body alone; the pose model fitted to their drapes and to {db.get('fit_poses', 0)} more "
                f"poses' drapes), {db['size_mb']:.1f} MB, "
                f"{db['build_min']:.0f} min of draping and fitting as its last build run recorded them (the model "
                "card has the build times); the shape models' 5 PCA components keep "
                f"{db['explained_variance_pct']:.1f} % of the variance of each anchor's drapes; ridge {db['ridge']:g} "
                "(least leave-one-body-out error).", ""]
        curve = r["anchors_curve"]
        out += ["Error against the number of anchors (subsets of the database's, clustered alike; every pose "
                "example kept):", "",
                report.table([[int(n), c["error_mm"], c["error_far_mm"]] for n, c in
                              sorted(curve.items(), key=lambda t: int(t[0]))],
                             ["anchors", "error mm", "far bodies mm"], ["", ".2f", ".2f"]), ""]
        if r.get("examples_curve"):
            fitted = CORRECTED_PBNS in r["rows"]
            out += ["Error against the number of pose examples (the anchors alone, then subsets of all examples "
                    "clustered alike; every anchor kept" + ("; with PBNS as trained corrected at them as pose model, "
                                                            "since the fitted one has learned from every example"
                                                            if fitted else "") + "):", "",
                    report.table([[int(n), c["error_mm"], c["error_far_mm"]] for n, c in
                                  sorted(r["examples_curve"].items(), key=lambda t: int(t[0]))],
                                 ["pose examples", "error mm", "far bodies mm"], ["", ".2f", ".2f"]), ""]
        sep: dict = {}
        for s in r["separability"]:
            sep.setdefault(s["r"], []).append(s)
        out += ["Separability (the paper's 4.2): error of eq. 3 at distance r from an anchor (a random direction over "
                "the 72 joint-rotation components in rad and the 6 phenotypes), practical (the Taylor model's pose "
                "model corrected at its pose examples, and the anchor's shape model) and theoretical (every term a "
                "drape):", "",
                report.table([[r_, len(v), _mean([x["practical_mm"] for x in v]),
                               _mean([x["theoretical_mm"] for x in v])] for r_, v in sorted(sep.items())],
                             ["r", "samples", "practical mm", "theoretical mm"], [".2f", "", ".2f", ".2f"]), ""]
    for name, cmp in data.get("newton", {}).items():
        out += [f"## {name}: the drape solver against newton's", "",
                "Held-out poses on PBNS's body, both drapes from the same skinned start (newton 1.8.0 VBD, "
                "quasi-static, `recon garment reference`'s protocol): mean distance to newton's drape.", "",
                report.table([[c["pose"], c["skinning_mm"], c["pbns_mm"], c["ours_mm"], c["ours_s"], c["newton_s"],
                               "yes" if c["newton_settled"] else "no (60 frames)"] for c in cmp],
                             ["pose", "skinning mm", "PBNS mm", "our drape mm", "our s", "newton s", "newton settled"],
                             ["", ".1f", ".1f", ".1f", ".0f", ".0f", ""]), ""]
    sp = data.get("speed", {})
    if sp:
        out += ["## Speed", "", "Batch 1, 1 thread, given the posed body (as PBNS's FPS in garment-pbns.md), the "
                "four timed in 7 interleaved rounds (median); the Taylor model with its penetration handling, with "
                "and without its pose examples' corrections, and as built (see the table's rows) with the post-step "
                "after it (what the Dresser runs). New body: "
                "`set_shape` (shape terms of every anchor and the penetration binding), median of 5.", ""]
        out += [report.table([[o, s["vertices"], s["anchors"], s.get("pose_examples", s["anchors"]),
                               "random" if s["random_database"] else "built",
                               s["pbns_fps"], s["taylor_fps"], s.get("taylor_uncorrected_fps"),
                               s.get("taylor_post_fps"), s["new_shape_ms"]] for o, s in sp.items()],
                             ["outfit", "vertices", "anchors", "pose examples", "database", "PBNS FPS",
                              "Taylor with corrections FPS", "without FPS", "Taylor + post-step FPS", "new body ms"],
                             ["", "", "", "", "", ".0f", ".0f", ".0f", ".1f", ".1f"]), ""]
        out += ["Databases marked random: an outfit whose database was not built here, timed with one of the default "
                "size and random contents (the cost does not depend on the values).", ""]
    return "\n".join(out)


def evaluate_and_report(outfits: list[str], poses: int = 20, workers: int = 2, out_dir: Path = report.RESULTS,
                        speed_outfits: list[str] | None = None, newton: bool = True, log=print) -> Path:
    """The table of ``outfits`` (their databases must be built), the speed of ``speed_outfits`` and,
    with ``newton`` (the ``sim`` extra; minutes a pose), the drape solver against newton's. The
    tables of outfits evaluated before and not now stay (an outfit's database built later adds its
    table to the others')."""
    body = default_body()
    previous = Path(out_dir) / "garment-taylor.json"
    before = json.loads(previous.read_text()) if previous.exists() else {}
    evaluated = {o: evaluate(o, poses, workers, log=log) for o in outfits}
    data = {"outfits": {**{o: r for o, r in before.get("outfits", {}).items() if o not in evaluated}, **evaluated},
            "speed": {}}
    compared = {}  # the comparison does not depend on the database: a previous run's stays
    if newton and reference.available():
        rot = test_poses(poses)
        compared = {o: newton_comparison(o, {i: rot[i] for i in NEWTON_POSES}, workers) for o in outfits}
    if before.get("newton") or compared:
        data["newton"] = {**before.get("newton", {}), **compared}
    for o in speed_outfits or outfits:
        p = store.taylor_path(o)
        pbns, _ = PBNS.load(store.pbns_path(o))
        data["speed"][o] = speed(body, o, TaylorGarment.load(p, pbns)[0] if p.exists() else None,
                                 test_poses(TaylorBuildConfig().anchors + 8))
    return report.write(Path(out_dir) / "garment-taylor", data, render(data))
