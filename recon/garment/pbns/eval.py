"""``recon garment eval`` and ``recon garment reference``: PBNS on held-out poses (thesis
Tables 5.1/5.2), the resizers on held-out body shapes, and PBNS against a physics drape.

PBNS rows, per outfit: collision %, edge error, bending, gravity (recon.garment.metrics) and
speed (frames per second for batch 1, 64 and 256 of the garment model given joint transforms,
and with the body's forward kinematics; ``recon.timing``). The skinned template without PBNS
(dT = 0) is the baseline, and PBNS followed by the collision resolution the Dresser applies
(recon.garment.collide) is what users get; its FPS b=1 includes that post-process.

Collision % and edge error are also split by how far the posed body passes through itself under
the garment (recon.garment.self_intersection: % of the covered skin inside the body): cloth
squeezed between two interpenetrating body parts cannot be outside both, and the thesis trains
and tests on poses without body self-collisions (5.4.3), whose own table is the third.

Every results file carries a ``check``: a small slice of it that tests/test_results.py
recomputes with the current code and weights.
"""
from __future__ import annotations

import hashlib
import json
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import torch

from recon import paths, report
from recon.body import default_body
from recon.errors import MissingFile, ReconError
from recon.garment import reference, store
from recon.garment.collide import CollisionResolver
from recon.garment.data import pose_set, posed_bodies
from recon.garment.mesh import unique_edges
from recon.garment.metrics import SELF_INTERSECTION_BINS, physical_metrics, rest_metrics
from recon.garment.pbns.data import Conditions, sample_conditions
from recon.garment.pbns.model import PBNS, remove_yaw, trained_outfit
from recon.garment.resize import TIGHTNESS_PHENOTYPES, TIGHTNESS_RANGE, OutfitResizer
from recon.garment.self_intersection import SkinSelfIntersection
from recon.garment.templates import PRESETS, make_outfit
from recon.timing import frames_per_second

# held-out poses differ by >= this (rad) in some joint, whatever spacing a model was trained with
# (thesis 5.4.3's 0.5; the test subjects then offer 290 poses)
TEST_POSE_DISTANCE = 0.5
# the thesis' protocol (5.4.3: "valid poses" do not make the body collide with itself): held-out
# poses balanced at >= 0.3 rad (0.5 rad leaves 290 poses of the test subjects, 54 of them valid),
# kept when at most VALID_MAX_SELF % of the covered skin is inside the body (the first bin)
VALID_POOL = (2000, 0.3)
VALID_MAX_SELF = 1.0
MODELS = ("skinning only (dT = 0)", "PBNS", "PBNS + collision resolution")
POST_STEP = "PBNS + strain step + collision resolution"  # the Dresser's default post-step (garment-pbns only)
CHECK_POSES, CHECK_CONDITIONS = 8, 16  # the slices tests/test_results.py recomputes
# after the post-step a vertex at the body's surface may count in or out on another CPU (one is
# ~0.0014 % of the check's cloth): garment-pbns' collision % are checked to 0.005
CHECK_TOLERANCE = {"rtol": 1e-3, "atol": 0.005}
THESIS = "Thesis PBNS (Table 5.1/5.2): collision 0.45 %, edge 0.66 mm, CPU 213 FPS (b=1) / 1,235 (batched)."


@torch.no_grad()
def speed(model: PBNS, body, rot: torch.Tensor, shape: torch.Tensor) -> dict:
    out = {}
    for b in (1, 64, 256):
        r = rot[:b] if len(rot) >= b else rot[torch.arange(b) % len(rot)]
        t = body(r, shape.expand(b, -1), points_only=True).transforms
        out[f"fps_batch{b}"] = frames_per_second(lambda: model.pose(r, t), b)  # noqa: B023
        if b == 256:
            continue
        out[f"fps_batch{b}_with_fk"] = frames_per_second(  # noqa: B023
            lambda: model.pose(r, body(r, shape.expand(b, -1), points_only=True).transforms), b)  # noqa: B023
    return out


_self_cache: dict = {}


def body_self_intersection(body, shape: torch.Tensor, rot: torch.Tensor, bv: torch.Tensor) -> torch.Tensor:
    """(P,) % of the covered skin inside the posed body ``bv``. Outfits share a shape and the test
    poses, so ``recon garment eval --outfit all`` computes it once instead of per outfit."""
    key = (id(body), shape.numpy().tobytes(), hashlib.sha1(rot.numpy().tobytes()).hexdigest())
    if key not in _self_cache:
        if len(_self_cache) >= 4:  # a few entries: the balanced and the valid test poses of one shape
            _self_cache.clear()
        _self_cache[key] = SkinSelfIntersection(body, shape).percent(bv)
    return _self_cache[key]


def valid_test_poses(body, shape: torch.Tensor) -> tuple[torch.Tensor, tuple]:
    """Held-out poses on which the body of ``shape`` does not pass through itself (VALID_POOL,
    VALID_MAX_SELF), and their posed_bodies()."""
    rot = pose_set("test", *VALID_POOL, seed=123)
    posed = posed_bodies(body, rot, shape)
    keep = body_self_intersection(body, shape, rot, posed[0]) <= VALID_MAX_SELF
    return rot[keep], tuple(p[keep] for p in posed)


@torch.no_grad()
def posed_outfits(model: PBNS, res: CollisionResolver, rot, bt, bv, body_faces) -> dict:
    """The rows of the tables for every pose: the skinned template (dT = 0), PBNS, PBNS followed
    by collision resolution, and by the Dresser's default post-step (the strain step, then collision
    resolution; recon.garment.collide): not part of the network."""
    chunks = range(0, len(rot), 64)
    pv = torch.cat([model.pose(rot[i:i + 64], bt[i:i + 64]) for i in chunks])
    return dict(zip(MODELS + (POST_STEP,), (torch.cat([model.skin(model.rest, bt[i:i + 64]) for i in chunks]), pv,
                                            res(pv, bv, body_faces), res(pv, bv, body_faces, rest=model.rest)),
                    strict=True))


def _load(outfit: str, weights: Path | None) -> tuple[PBNS, dict]:
    path = Path(weights or store.pbns_path(outfit))
    if not path.exists():
        raise MissingFile(f"{path} not found: train it with `recon garment train --outfit {outfit}`")
    return PBNS.load(path)


@dataclass
class _TestPoses:
    """An outfit's model and the first ``n_poses`` balanced test poses of its body."""
    model: PBNS
    checkpoint: dict
    resolver: CollisionResolver
    rot: torch.Tensor
    shape: torch.Tensor
    body_verts: torch.Tensor
    body_normals: torch.Tensor
    body_transforms: torch.Tensor
    body_self: torch.Tensor | None  # per pose, % (None: not scored against)

    @classmethod
    def load(cls, body, outfit: str, n_poses: int, weights: Path | None = None) -> _TestPoses:
        model, ck = _load(outfit, weights)
        shape = ck["shape"][None]
        rot = pose_set("test", n_poses, TEST_POSE_DISTANCE, seed=123)
        bv, bn, bt = posed_bodies(body, rot, shape)
        return cls(model, ck, CollisionResolver(model.faces.numpy(), ck["layer"].numpy()), rot, shape, bv, bn, bt,
                   body_self_intersection(body, shape, rot, bv))

    def rows(self, body) -> dict:
        """The physical metrics of the three models (PBNS, + collision resolution, LBS)."""
        return {k: physical_metrics(v, self.model.faces.numpy(), self.model.rest, self.body_verts, self.body_normals,
                                    self.body_self)
                for k, v in posed_outfits(self.model, self.resolver, self.rot, self.body_transforms, self.body_verts,
                                          body.faces).items()}


def pose_rows(body, outfit: str, n_poses: int, weights: Path | None = None) -> dict:
    """The physical metrics of the three models on the first ``n_poses`` balanced test poses."""
    return _TestPoses.load(body, outfit, n_poses, weights).rows(body)


def pbns_check(outfits: list[str] | None = None, n_poses: int = CHECK_POSES) -> dict:
    """The check slice of garment-pbns.json: ``pose_rows`` on the first ``n_poses`` poses."""
    body = default_body()
    return {o: pose_rows(body, o, n_poses) for o in outfits or PRESETS}


def evaluate(body, outfit: str, n_poses: int = 500, weights: Path | None = None) -> dict:
    """One outfit's rows on the held-out poses, speed, and the valid-pose rows."""
    t = _TestPoses.load(body, outfit, n_poses, weights)
    model, res = t.model, t.resolver
    meta = json.loads(t.checkpoint["meta_json"])
    rows = t.rows(body)
    rows["PBNS"] |= speed(model, body, t.rot, t.shape)
    rows["PBNS + collision resolution"]["fps_batch1"] = frames_per_second(
        lambda: res(model.pose(t.rot[:1], t.body_transforms[:1]), t.body_verts[:1], body.faces), 1)
    rows[POST_STEP]["fps_batch1"] = frames_per_second(
        lambda: res(model.pose(t.rot[:1], t.body_transforms[:1]), t.body_verts[:1], body.faces, rest=model.rest), 1)
    vrot, (vbv, vbn, vbt) = valid_test_poses(body, t.shape)
    valid = _TestPoses(model, t.checkpoint, res, vrot, t.shape, vbv, vbn, vbt, body_self=None)
    return {"outfit": meta.get("outfit", outfit), "vertices": int(model.rest.shape[0]),
            "faces": int(len(model.faces)), "test_poses": int(len(t.rot)), "train_seconds": meta["train_seconds"],
            "rows": rows, "valid_poses": int(len(valid.rot)), "valid_rows": valid.rows(body),
            "threads": torch.get_num_threads(),
            "body_self_intersection_pct": {"median": float(t.body_self.median()), "mean": float(t.body_self.mean())}}


def evaluate_and_report(body, outfits: list[str], n_poses: int = 500, out_dir: Path = report.RESULTS) -> Path:
    """``recon garment eval``: garment-pbns.{json,md} (your own garments: a file of their own)."""
    results = [evaluate(body, o, n_poses) for o in outfits]
    names = [r["outfit"] for r in results]
    presets = set(names) <= set(PRESETS)
    stem = Path(out_dir) / ("garment-pbns" if presets else "garment-pbns-" + "-".join(names))
    data = {"outfits": results}
    if presets:
        data["check"] = {"function": "recon.garment.pbns.eval:pbns_check",
                         "kwargs": {"outfits": names, "n_poses": CHECK_POSES}, "tolerance": CHECK_TOLERANCE,
                         "values": pbns_check(names, CHECK_POSES)}
    return report.write(stem, data, render_pbns(data))


def render_pbns(data: dict) -> str:
    """The Markdown of a garment-pbns.json."""
    results = data["outfits"]
    fps_keys = ("fps_batch1", "fps_batch64", "fps_batch256", "fps_batch1_with_fk", "fps_batch64_with_fk")
    main = [[r["outfit"], r["vertices"], name, m["collision_pct"], m["edge_mm"], m["edge_pct"], m["bend"],
             r["train_seconds"] / 60] + [f"{m[k]:.0f}" if k in m else "" for k in fps_keys]
            for r in results for name, m in r["rows"].items()]
    bins = [[r["outfit"], name] + [f"{b['collision_pct']:.2f} / {b['edge_mm']:.2f} ({b['poses']})" if b["poses"]
                                   else "- (0)" for b in m["by_body_self_intersection"].values()]
            for r in results for name, m in r["rows"].items()]
    valid = [[r["outfit"], name, m["collision_pct"], m["edge_mm"], m["edge_pct"], m["bend"]]
             for r in results for name, m in r["valid_rows"].items()]
    threads = results[0].get("threads", 1)
    return "\n".join([
        "# PBNS on held-out mocap poses (CMU test subjects)", "",
        report.table(main, ["outfit", "vertices", "model", "collision %", "edge mm", "edge %", "bend", "train min",
                            "FPS b=1", "FPS b=64", "FPS b=256", "FPS b=1 +FK", "FPS b=64 +FK"],
                     ["", "", "", ".2f", ".2f", ".2f", ".4f", ".1f", "", "", "", "", ""]),
        "", f"{results[0]['test_poses']} balanced test poses per outfit; CPU, {threads} thread(s). {THESIS}", "",
        "## Collisions by the body's own self-intersection", "",
        "Test poses binned by the % of the skin under garments (torso, hips, legs, arms) that lies inside the "
        "posed body itself (LBS interpenetration: thigh into belly, arm into chest; "
        "`recon.garment.self_intersection`); the thesis trains and tests PBNS on poses without body "
        "self-collisions (5.4.3). Collision % / edge error mm of the cloth per bin (poses in brackets).", "",
        report.table(bins, ["outfit", "model"] + [f"body {lo:g}-{hi:g} %" for lo, hi in SELF_INTERSECTION_BINS]),
        "", f"Body self-intersection on these poses: median {results[0]['body_self_intersection_pct']['median']:.2f} % "
        "of the covered skin (the body at the outfit's shape, 2 mm probe along the normals, rest-pose contacts "
        "excluded).", "", "## Valid poses only (the thesis' protocol)", "",
        f"The thesis trains and tests PBNS on \"valid poses\" (5.4.3: no body self-collisions). Held-out poses "
        f"balanced at >= {VALID_POOL[1]:g} rad instead of 0.5 (more of them), kept when <= {VALID_MAX_SELF:g} % of the "
        f"covered skin is inside the body: {results[0]['valid_poses']} poses. Thesis PBNS: collision 0.45 %, edge "
        "0.66 mm.", "",
        report.table(valid, ["outfit", "model", "collision %", "edge mm", "edge %", "bend"],
                     ["", "", ".2f", ".2f", ".2f", ".4f"])])


# --- resizers (thesis 5.5.6) ----------------------------------------------------------------------

def resize_rows(body, outfit: str, n: int, seed: int = 1234) -> tuple[dict, float, str]:
    """Held-out (shape, tightness) conditions: E_T alone vs E_T + resizer, rest pose on the
    body of that shape, per subset (all, loose, tight); the resizer's ms per outfit; the
    outfit's name."""
    o, _, name = trained_outfit(body, store.pbns_path(outfit))
    rz = OutfitResizer(body, store.resizer_path(name), o.vertices, o.faces)
    data = Conditions(body, rz.transfer, *sample_conditions(body, n, seed), torch.from_numpy(unique_edges(o.faces)), 1)
    t = time.perf_counter()
    with torch.no_grad():
        dv = rz.net(data.shape, data.tight)
    ms = (time.perf_counter() - t) * 1000 / n
    rows = {}
    loose = data.tight[:, 0] >= 0
    subsets = (("all", torch.ones_like(loose)), ("loose (gamma_weight >= 0)", loose),
               ("tight (gamma_weight < 0)", ~loose))
    for subset, m in subsets:
        for model, v in (("transfer only (CLOTH3D E_T)", data.base), ("E_T + resizer (PBNS 5.5.6)", data.base + dv)):
            rows[f"{model}, {subset}"] = rest_metrics(v[m], data.base[m], o.faces, data.bv[m], data.bn[m])
    return rows, ms, name


def resize_check(outfit: str, n: int = CHECK_CONDITIONS) -> dict:
    """The check slice of garment-resize-<outfit>.json: the rows on ``n`` conditions."""
    return resize_rows(default_body(), outfit, n)[0]


def evaluate_resizer(body, outfit: str, n: int = 200, seed: int = 1234, out_dir: Path = report.RESULTS) -> Path:
    """garment-resize-<outfit>.{json,md}."""
    rows, ms, name = resize_rows(body, outfit, n, seed)
    meta = json.loads(paths.load_checkpoint(store.resizer_path(name), "recon garment resize")["meta_json"])
    res = {"outfit": name, "conditions": n, "seed": seed, "rows": rows, "ms_per_outfit_batched": ms,
           "train_seconds": meta["train_seconds"], "threads": meta.get("threads", 2),
           "check": {"function": "recon.garment.pbns.eval:resize_check",
                     "kwargs": {"outfit": name, "n": CHECK_CONDITIONS}, "values": resize_check(name, CHECK_CONDITIONS)}}
    return report.write(Path(out_dir) / f"garment-resize-{name}", res, render_resize(res))


def render_resize(res: dict) -> str:
    """The Markdown of a garment-resize-<outfit>.json."""
    threads = res.get("threads", 2)  # files from before it was recorded: 2 threads
    return "\n".join([
        f"Outfit resizing, {res['outfit']}: {res['conditions']} held-out (shape, tightness) conditions (seed "
        f"{res['seed']}; shapes from the anny phenotype sampler, tightness gamma = offsets of "
        f"{', '.join(TIGHTNESS_PHENOTYPES)} in {TIGHTNESS_RANGE}), rest pose on the body of each shape. Collision = "
        "cloth vertices inside the body; edge = mean |edge length - E_T edge length|. `recon garment resize` then "
        "`recon garment eval`.", "",
        report.table([[k, r["collision_pct"], r["edge_mm"]] for k, r in res["rows"].items()],
                     ["method", "collision %", "edge error mm"], ["", ".2f", ".2f"]), "",
        f"Resizer: trained in {res['train_seconds'] / 60:.1f} min on {threads} CPU thread{'s' * (threads > 1)}; "
        f"{res['ms_per_outfit_batched']:.3f} ms per outfit (network only, batched)."])


# --- against a physics simulation (thesis Table 5.1) ------------------------------------------

def reference_poses(pool_size: int, min_pose_distance: float, indices) -> torch.Tensor:
    """Poses the reference drapes (and scores against): picks of the balanced test pool, root
    heading removed."""
    rot = pose_set("test", pool_size, min_pose_distance, seed=123)[torch.as_tensor(indices)]
    rot[:, 0] = remove_yaw(rot[:, 0])
    return rot


@torch.no_grad()
def score_rows(model: PBNS, ck: dict, body_faces, rot: torch.Tensor, posed: tuple, sim: torch.Tensor | None
               ) -> tuple[dict, np.ndarray]:
    """Per model (skinning, PBNS with its seconds for the pose, PBNS + collision resolution, the
    drape ``sim`` (1, N, 3) itself when given): physical metrics and Euclidean error to ``sim``;
    and the skinned outfit (N, 3), which is where a drape of this pose starts. ``posed``:
    posed_bodies()."""
    bv, bn, bt = posed
    t = time.perf_counter()
    pv = model.pose(rot, bt)
    pbns_s = time.perf_counter() - t
    sk = model.skin(model.rest, bt)
    pr = CollisionResolver(model.faces.numpy(), ck["layer"].numpy())(pv, bv, body_faces)
    rows = {}
    for name, v in zip(MODELS + ("newton VBD drape",), (sk, pv, pr, sim), strict=True):
        if v is None:
            continue
        rows[name] = physical_metrics(v, model.faces.numpy(), model.rest, bv, bn)
        if sim is not None:
            rows[name]["error_mm"] = float((v[0] - sim[0]).norm(dim=-1).mean()) * 1000
    rows["PBNS"]["seconds"] = pbns_s
    return rows, sk[0].numpy()


@torch.no_grad()
def _drape_one(args) -> dict:
    """One held-out pose: drape with newton (reference.drape), metrics of skinning, PBNS and the
    simulation, Euclidean error of each to the simulation. Runs in a worker process."""
    outfit, index, n_poses, min_dist, frames = args
    body = default_body()
    model, ck = PBNS.load(store.pbns_path(outfit))
    rot = reference_poses(n_poses, min_dist, [index])
    posed = posed_bodies(body, rot, ck["shape"][None])
    bv, _, bt = posed
    sk = model.skin(model.rest, bt)
    pinned = make_outfit(body, outfit, ck["shape"][None]).pinned
    r = reference.drape(bv[0].numpy(), body.faces.numpy(), model.rest.numpy(), sk[0].numpy(), model.faces.numpy(),
                        pinned, reference.DrapeConfig(frames=frames))
    sim = torch.from_numpy(r["vertices"]).float()[None]
    rows, _ = score_rows(model, ck, body.faces, rot, posed, sim)
    rows["newton VBD drape"]["seconds"] = r["seconds"]
    return {"pose": index, "frames": r["frames"], "settled": r["settled"], "last_move_mm": r["last_move_mm"],
            "rows": rows, "vertices": r["vertices"].astype(np.float32), "start": sk[0].numpy().astype(np.float32)}


def drapes_path(outfit: str) -> Path:
    return paths.cache_dir() / "garment-reference" / f"{outfit}.npz"


@torch.no_grad()
def error_to_drapes(model: PBNS, outfit: str, shape: torch.Tensor, body=None, layer=None) -> dict | None:
    """Mean Euclidean error (mm) of PBNS and of its skinned template to the cached newton drapes
    of `recon garment reference` (None when there are none); with the outfit's ``layer`` also
    of PBNS + collision resolution."""
    path = drapes_path(outfit)
    if not path.exists():
        return None
    d = np.load(path)
    sim = torch.from_numpy(d["vertices"])
    if sim.shape[1] != model.rest.shape[0]:
        return None
    body = body or default_body()
    rot = reference_poses(int(d["pool_size"]), float(d["min_pose_distance"]), torch.from_numpy(d["poses"]))
    bv, _, bt = posed_bodies(body, rot, shape.reshape(1, -1))
    pv, sk = model.pose(rot, bt), model.skin(model.rest, bt)
    pr = CollisionResolver(model.faces.numpy(), layer)(pv, bv, body.faces) if layer is not None else None
    err = lambda v: float((v - sim).norm(dim=-1).mean()) * 1000  # noqa: E731
    # height: mean cloth height above the drape's (> 0: the cloth does not sag as far)
    return {"poses": len(sim), "skinning_mm": err(sk), "pbns_mm": err(pv),
            "skinning_height_mm": float((sk[..., 1] - sim[..., 1]).mean()) * 1000,
            "pbns_height_mm": float((pv[..., 1] - sim[..., 1]).mean()) * 1000} | (
            {} if pr is None else {"pbns_resolved_mm": err(pr)})


def reference_and_report(outfit: str, poses: int = 4, out_dir: Path = report.RESULTS, frames: int = 60,
                         workers: int = 1, pool_size: int = 500) -> Path:
    """PBNS vs a newton SolverVBD drape on the first ``poses`` of the balanced test poses; writes
    garment-reference-<outfit>.{json,md}. Needs the optional ``newton`` package."""
    if not reference.available():
        raise ReconError('the reference simulation needs newton: pip install "recon[sim]" (docs/garments.md)')
    min_dist = TEST_POSE_DISTANCE  # the drapes are picks of the held-out test pool
    jobs = [(outfit, i, pool_size, min_dist, frames) for i in range(poses)]
    if workers > 1:
        # one torch thread per worker process (one process per core)
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=torch.set_num_threads,
                                 initargs=(1,)) as ex:
            per_pose = list(ex.map(_drape_one, jobs))
    else:
        per_pose = [_drape_one(j) for j in jobs]
    # drapes (and the skinned starts they came from) kept in the cache, so other PBNS variants
    # can be scored without re-simulating
    drapes = np.stack([p.pop("vertices") for p in per_pose])
    starts = np.stack([p.pop("start") for p in per_pose])

    def save(tmp):
        with open(tmp, "wb") as f:
            np.savez(f, vertices=drapes, start=starts, poses=np.arange(poses), pool_size=pool_size,
                     min_pose_distance=min_dist)
    paths.atomic_write(drapes_path(outfit), save)
    result = {"outfit": outfit, "poses": per_pose, "frames_cap": frames, "pool_size": pool_size,
              "settled": int(sum(p["settled"] for p in per_pose)), "config": reference.DrapeConfig().__dict__}
    return _write_reference(result, out_dir)


def rescore_reference(outfit: str, out_dir: Path, max_start_shift_mm: float = 2.0) -> Path:
    """Re-score the current weights of ``outfit`` against its cached drapes (no simulation) and
    rewrite garment-reference-<outfit>.{json,md}: for a retrained network whose skinned start
    (the drape's initial state, set by the trained blend weights) is within
    ``max_start_shift_mm`` (mean) of the one the drapes were simulated from."""
    old = report.read(Path(out_dir) / f"garment-reference-{outfit}")
    if not drapes_path(outfit).exists():
        raise MissingFile(f"{drapes_path(outfit)} not found: run `recon garment reference --outfit {outfit}` first")
    d = np.load(drapes_path(outfit))
    if "start" not in d.files:
        raise ReconError(f"{drapes_path(outfit)} predates stored starts: re-run `recon garment reference`")
    body = default_body()
    model, ck = PBNS.load(store.pbns_path(outfit))
    shift = []
    for p, sim, start in zip(old["poses"], d["vertices"], d["start"], strict=True):
        rot = reference_poses(int(d["pool_size"]), float(d["min_pose_distance"]), [p["pose"]])
        posed = posed_bodies(body, rot, ck["shape"][None])
        rows, sk = score_rows(model, ck, body.faces, rot, posed, torch.from_numpy(sim)[None])
        shift.append(float(np.linalg.norm(sk - start, axis=-1).mean()) * 1000)
        rows["newton VBD drape"]["seconds"] = p["rows"]["newton VBD drape"]["seconds"]
        p["rows"] = rows
    if max(shift) > max_start_shift_mm:
        raise ReconError(f"the skinned start moved {max(shift):.2f} mm from the drapes' (> {max_start_shift_mm}): "
                         "re-run `recon garment reference`")
    return _write_reference(old | {"rescored_start_shift_mm": shift}, out_dir)


def reference_check(outfit: str, pose: int, pool_size: int = 500) -> dict:
    """The check slice of garment-reference-<outfit>.json: the physical metrics of skinning, PBNS
    and PBNS + collision resolution on its first pose (the drape itself is not recomputed)."""
    body = default_body()
    model, ck = PBNS.load(store.pbns_path(outfit))
    rot = reference_poses(pool_size, TEST_POSE_DISTANCE, [pose])
    rows, _ = score_rows(model, ck, body.faces, rot, posed_bodies(body, rot, ck["shape"][None]), None)
    return {name: {k: v for k, v in m.items() if k != "seconds"} for name, m in rows.items()}


def _write_reference(result: dict, out_dir: Path) -> Path:
    """garment-reference-<outfit>.{json,md} from per-pose rows (+ their means and a check slice)."""
    outfit, per_pose = result["outfit"], result["poses"]
    names = list(per_pose[0]["rows"])
    keys = list(per_pose[0]["rows"][names[0]])
    mean = {n: {k: float(np.mean([p["rows"][n][k] for p in per_pose if k in p["rows"][n]]))
                for k in keys + ["seconds"] if any(k in p["rows"][n] for p in per_pose)} for n in names}
    first = per_pose[0]
    check = {"function": "recon.garment.pbns.eval:reference_check",
             "kwargs": {"outfit": outfit, "pose": first["pose"], "pool_size": result.get("pool_size", 500)},
             "values": {n: {k: v for k, v in first["rows"][n].items() if k not in ("error_mm", "seconds")}
                        for n in MODELS}}
    result = result | {"mean": mean, "check": check}
    return report.write(Path(out_dir) / f"garment-reference-{outfit}", result, render_reference(result))


def render_reference(result: dict) -> str:
    """The Markdown of a garment-reference-<outfit>.json."""
    poses, mean, frames = len(result["poses"]), result["mean"], result["frames_cap"]
    rows = [[n, m["error_mm"], m["collision_pct"], m["edge_mm"], m["edge_pct"], m["bend"],
             f"{m['seconds']:.3g}" if "seconds" in m else ""] for n, m in mean.items()]
    rescored = ("PBNS rows re-scored against the cached drapes after retraining (the skinned start moved "
                f"{np.mean(result['rescored_start_shift_mm']):.2f} mm on average from the one simulated). "
                if "rescored_start_shift_mm" in result else "")
    cfg = reference.DrapeConfig
    return "\n".join([
        f"# {result['outfit']}: PBNS against a physics drape (newton 1.8.0 SolverVBD), {poses} held-out poses", "",
        report.table(rows, ["model", "error to sim mm", "collision %", "edge mm", "edge %", "bend", "seconds / pose"],
                     ["", ".1f", ".2f", ".2f", ".2f", ".4f", ""]), "",
        f"Drape: quasi-static (velocities zeroed each substep), {cfg.substeps} substeps x {cfg.iterations} iterations "
        f"per 1/30 s frame, settled when the 99th percentile of per-frame particle motion < {cfg.settle_mm} mm, else "
        f"stopped at {frames} frames: {result['settled']} of {poses} settled. Start: the skinned rest outfit; pinned "
        "vertices fixed. PBNS seconds: one pose, 1 thread; sim seconds: CPU, 1 thread each. " + rescored +
        "Thesis Table 5.1 (PBNS vs its simulator): 0.45 % collision, 0.66 mm edge error."])
