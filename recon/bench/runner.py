"""Run methods over a synthetic benchmark and write JSON + Markdown tables side by side.

Protocol: MPJPE P1 = mean joint error after aligning pelvises; P2 = after a similarity
Procrustes per sample; Lm = landmark error (pelvis-aligned); PVE = per-vertex error
(pelvis-aligned); IoU = the method's mesh rendered with the sample's camera (or its own
mask) against the ground-truth full-body silhouette. A method that finds no person in an
image counts as a failure; it is scored on the images it handled and failures are reported.
"""
from __future__ import annotations

import json
import re
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from recon import metrics, report
from recon.bench.methods import get_method
from recon.body import default_body
from recon.body.base import BodyModel
from recon.errors import ReconError
from recon.executor import ExecutorConfig, WorkerLost, WorkerSpec, map_tasks
from recon.paths import write_text
from recon.render.raster import Rasterizer, silhouette_iou
from recon.synth.dataset import BENCHMARKS, GrayView, SynthDataset, bench_sampler, open_bench

ABBR = {"head": "Hd", "torso": "Ts", "shoulder": "Sr", "elbow": "Ew", "wrist": "Wt", "hip": "Hp", "knee": "Kn",
        "foot": "Ft"}
COLUMNS = ("MPJPE-P1", "MPJPE-P2 (PA)", "Lm", "PVE", "IoU")
EVAL_CHUNK = 8  # samples a task: a Ray task's overhead is ~1 ms, a sample's scoring 0.1-2 s
CHECK_IMAGES = 8  # the slice tests/test_results.py recomputes: the first images of the benchmark
# how far a checked 8-image mean may move between CPUs: the float kernels' last bits, carried
# through the networks, the 30-step fit and a rasterised silhouette's edge pixels
CHECK_TOLERANCE = {"rtol": 2e-3, "atol": 1e-6}


class MethodScorer:
    """One method's scores per sample (a worker: built once per process or Ray actor)."""

    def __init__(self, name: str, body: BodyModel | None = None):
        self.body = body if body is not None else default_body()
        self.method = get_method(name)(self.body)
        self.faces = self.body.faces.numpy()
        self.raster = None

    def __call__(self, samples: list[dict]) -> list[dict | None]:
        return [self.score(s) for s in samples]

    def score(self, s: dict) -> dict | None:
        """The sample's scores (None: the method found no person)."""
        method, body = self.method, self.body
        extra = {"points2d": s["points2d"], "points3d": s["points3d"]} if getattr(method, "needs_gt", False) else {}
        pred = method(s["rgb"], s["K"], **extra)
        if pred is None:
            return None
        gt_j = torch.tensor(s["points3d"][None, :24])
        pj = torch.tensor(pred.joints[None], dtype=torch.float32)
        je = metrics.per_point_error(pj, gt_j)[0]
        row = {"joint": je.numpy(), "p1": float(je.mean()),
               "p2": float(metrics.per_point_error(metrics.procrustes_align(pj, gt_j), gt_j, None).mean())}
        if pred.landmarks is not None:
            gl = s["points3d"][24:] - s["points3d"][:1]
            row["lm"] = float(np.linalg.norm(pred.landmarks - pred.joints[:1] - gl, axis=1).mean())
        if pred.vertices is not None and "vertices" in s:
            gv = s["vertices"].astype(np.float32) @ s["R"].T  # stored pelvis-relative, body frame
            row["pve"] = float(np.linalg.norm(pred.vertices - pred.joints[:1] - gv, axis=1).mean())
        mask = pred.mask
        if mask is None and pred.vertices is not None:
            self.raster = (self.raster or Rasterizer(*s["rgb"].shape[1::-1])).set_size(*s["rgb"].shape[1::-1])
            mask = self.raster.render(pred.vertices, self.faces, s["K"])[2] > 0
        if mask is not None:
            row["iou"] = silhouette_iou(mask, s["silhouette"])
        if pred.placed:
            row["depth"] = abs(float(pred.joints[0, 2]) - float(s["points3d"][0, 2]))
        if pred.shape is not None:
            (hp, mp), (ht, mt) = body_size(body, pred.shape), body_size(body, s["shape"])
            row["height"], row["mass"] = (hp, ht), (mp, mt)
            row["shape"] = np.abs(np.asarray(pred.shape, float) - s["shape"])
            row["shape_pred"] = np.asarray(pred.shape, float)
        if pred.shape_confidence is not None:
            row["shape_confidence"] = float(pred.shape_confidence)
        return row


def run_method(name: str, ds, body: BodyModel, n: int | None = None, progress: bool = True,
               executor: ExecutorConfig | None = None) -> dict:
    """Scores of one method on the first ``n`` samples of ``ds`` (a SynthDataset or a list of
    samples). ``executor``: where chunks of ``EVAL_CHUNK`` samples are scored (default this
    process); the scores do not depend on it."""
    executor = executor or ExecutorConfig()
    count = min(n or len(ds), len(ds))
    chunks = [range(a, min(a + EVAL_CHUNK, count)) for a in range(0, count, EVAL_CHUNK)]
    spec = WorkerSpec(MethodScorer, (name,), {"body": body} if executor.in_process else {})
    scored: list = [None] * len(chunks)
    t0 = time.time()
    bar = tqdm(total=count, desc=f"eval {name}", unit="img", mininterval=5, disable=not progress)
    results = map_tasks(spec, chunks, executor, lambda idx: [ds[i] for i in idx])
    try:
        for c, chunk in results:
            if isinstance(chunk, WorkerLost):
                raise ReconError(f"eval {name}: images {chunks[c].start}-{chunks[c].stop - 1}: {chunk}")
            scored[c] = chunk
            bar.update(len(chunk))
    finally:
        results.close()
        bar.close()
    scores = [r for chunk in scored for r in chunk]
    rows = {k: [r[k] for r in scores if r is not None and k in r]
            for k in ("p1", "p2", "lm", "pve", "iou", "joint", "depth", "height", "mass", "shape",
                      "shape_pred")}
    done = len(rows["p1"])
    failures = count - done
    joint = np.stack(rows["joint"]) * 1000 if done else np.zeros((0, 24))
    res = {"method": name, "description": get_method(name).description, "images": done + failures,
           "failures": failures, "seconds_per_image": (time.time() - t0) / max(done + failures, 1)}
    for key, label in zip(("p1", "p2", "lm", "pve"), COLUMNS[:4], strict=True):
        res[label] = float(np.mean(rows[key]) * 1000) if rows[key] else None
    res["IoU"] = float(np.mean(rows["iou"])) if rows["iou"] else None
    res["groups"] = {ABBR[g]: float(v) for g, v in metrics.group_errors(torch.tensor(joint)).items()} if done else {}
    truth = _truth(ds, count)
    if rows["depth"]:
        res["root_depth_mm"] = {"median": float(np.median(rows["depth"]) * 1000),
                                "mean": float(np.mean(rows["depth"]) * 1000)}
    if rows["height"]:
        hp, hg = np.array(rows["height"]).T
        names = getattr(body, "shape_names", None) or [f"s{i}" for i in range(len(rows["shape"][0]))]
        res["body_shape"] = {"height_error_cm": float(np.mean(np.abs(hp - hg)) * 100),
                             "height_correlation": float(np.corrcoef(hp, hg)[0, 1]) if len(hp) > 2 else None,
                             "shape_error": dict(zip(names, map(float, np.mean(rows["shape"], 0)), strict=True))}
        if len(rows["mass"]) == len(rows["height"]):
            mp, mg = np.array(rows["mass"]).T
            res["body_shape"] |= {"weight_error_kg": float(np.mean(np.abs(mp - mg))),
                                  "weight_correlation": float(np.corrcoef(mp, mg)[0, 1]) if len(mp) > 2 else None}
        if "gender" in names:  # right side of 0.5 (synth-*: the true gender is 0 or 1)
            g = list(names).index("gender")
            res["body_shape"]["gender_accuracy"] = float(np.mean(np.stack(rows["shape"])[:, g] < 0.5))
            res["body_shape"] |= gender_extremes(truth["shape"], scores, g)
        res["body_shape"]["shape_correlation"] = shape_correlation(truth["shape"], scores, names)
    if truth.get("info") is not None:
        res["found_by_view"] = found_by_view(truth["info"], scores)
    res["per_image"] = per_image(scores)
    return res


def _truth(ds, count: int) -> dict:
    """The true shapes (count, S) and the other domain's ``info`` rows (or None) of the first
    ``count`` samples, without decoding their images."""
    light = SynthDataset(ds.root, keys=("shape", "info")) if isinstance(ds, (SynthDataset, GrayView)) else ds
    items = [light[i] for i in range(count)]
    return {"shape": np.stack([x["shape"] for x in items]) if count else np.zeros((0, 0)),
            "info": np.stack([x["info"] for x in items]) if count and "info" in items[0] else None}


def gender_extremes(true_shapes: np.ndarray, scores: list, g: int) -> dict:
    """On people whose true gender is < 0.2 or > 0.8 (the other domain's gender is anywhere in
    [0, 1]): the share predicted on the right side of 0.5."""
    right, n = 0, 0
    for r, true in zip(scores, true_shapes[:, g], strict=False):
        if r is None or "shape_pred" not in r or 0.2 <= true <= 0.8:
            continue
        n += 1
        right += (r["shape_pred"][g] > 0.5) == (true > 0.5)
    return {"gender_right_extremes": right / n if n else None, "gender_extremes_n": n}


def shape_correlation(true_shapes: np.ndarray, scores: list, names: list[str]) -> dict:
    """Pearson r of each predicted phenotype against the true one, on the images with a prediction."""
    pairs = [(r["shape_pred"], t) for r, t in zip(scores, true_shapes, strict=False)
             if r is not None and "shape_pred" in r]
    if len(pairs) < 3:
        return {}
    pred, true = (np.stack(x) for x in zip(*pairs, strict=True))
    return {n: float(np.corrcoef(pred[:, j], true[:, j])[0, 1]) for j, n in enumerate(names)}


VIEWS = {"front": (0, 45), "side": (45, 135), "back": (135, 181)}


def found_by_view(info: np.ndarray, scores: list) -> dict:
    """The share of images with a person found, by view (|yaw| of the body to the camera) and by
    whether a border cuts the person (``info`` of the other domain: yaw, cut share, ...)."""
    found = np.array([r is not None for r in scores])
    yaw, cut = np.abs(info[:, 0]), info[:, 1] > 0.05
    out = {v: float(found[(yaw >= lo) & (yaw < hi)].mean()) for v, (lo, hi) in VIEWS.items()}
    out |= {"cut": float(found[cut].mean()) if cut.any() else None,
            "whole": float(found[~cut].mean()) if (~cut).any() else None}
    return out


def per_image(scores: list) -> dict:
    """Per-image numbers for paired comparisons (eval/compare.py): MPJPE P1 and PA (mm, None where
    nobody was found) and the predicted shape."""
    r1 = lambda v: None if v is None else round(float(v) * 1000, 1)  # noqa: E731
    return {"p1": [None if r is None else r1(r["p1"]) for r in scores],
            "p2": [None if r is None else r1(r["p2"]) for r in scores],
            "shape": [None if r is None or "shape_pred" not in r else [round(float(x), 3) for x in r["shape_pred"]]
                      for r in scores],
            "shape_confidence": [None if r is None else r.get("shape_confidence") for r in scores]}


BODY_DENSITY = 985.0  # kg / m^3, a human body's average


def body_size(body: BodyModel, shape) -> tuple[float, float]:
    """Standing height (m: the vertical extent of the rest mesh) and weight (kg: the closed rest
    mesh's volume times BODY_DENSITY) of a body shape, from one pass of the body model."""
    with torch.no_grad():
        v = body(shape=torch.as_tensor(np.asarray(shape, np.float32))[None]).rest_vertices[0]
    tri = v.double()[body.faces.long()]
    return float(v[:, 1].max() - v[:, 1].min()), float(torch.linalg.det(tri).sum().abs() / 6.0 * BODY_DENSITY)


def check(bench: str, methods: list[str], n: int = CHECK_IMAGES) -> dict:
    """The check slice of a benchmark's results: each of ``methods`` on its first ``n`` images,
    rendered on the fly (sample i depends only on the benchmark's split, seed and i)."""
    body = default_body()
    scenes = bench_sampler(bench, body)
    samples = [scenes.sample(i) for i in range(n)]
    if BENCHMARKS[bench].get("gray"):
        samples = [GrayView([s])[0] for s in samples]
    return {m: {k: r[k] for k in (*COLUMNS, "failures")}
            for m in methods for r in [run_method(m, samples, body, progress=False)]}


def checked(methods: list[str]) -> list[str]:
    """The methods a check slice holds: those with no detector or search before our networks,
    whose numbers move only by float noise between CPUs (``METHODS[m].detects``)."""
    return [m for m in methods if not get_method(m).detects]


def evaluate(bench: str, methods: list[str], n: int | None = None, out_dir: Path = report.RESULTS,
             executor: ExecutorConfig | None = None) -> Path:
    """``recon eval``: run ``methods`` on the benchmark (its first ``n`` images) and merge them into
    ``<out_dir>/<bench>.{json,md}`` (re-run methods replaced in place), with the check slice of the
    methods ``checked`` keeps, computed with ``recon.kernels`` pinned (the command line and the
    tests pin them). ``executor``: where the images are scored (``run_method``)."""
    if bench not in BENCHMARKS:
        raise ReconError(f"unknown benchmark {bench!r}; known: {', '.join(BENCHMARKS)}")
    for m in methods:
        get_method(m)  # an unknown name fails before any work
    ds = open_bench(bench)
    body = default_body()
    new = []
    for m in methods:  # per-image numbers beside the table, for paired comparisons (eval/compare.py)
        new.append(run_method(m, ds, body, n, executor=executor))
        write_text(scores_path(out_dir, bench, m), json.dumps(new[-1].pop("per_image")) + "\n")
    stem = Path(out_dir) / bench
    old = report.read(stem) if stem.with_suffix(".json").exists() else {"rows": []}
    fresh = {r["method"]: r for r in new}
    rows = [fresh.pop(r["method"], r) for r in old["rows"]] + list(fresh.values())
    names = [r["method"] for r in rows]
    values = old.get("check", {}).get("values", {})
    values = {m: values[m] for m in checked(names) if m in values and m not in methods}
    values |= check(bench, [m for m in checked(names) if m not in values], CHECK_IMAGES)
    data = {"benchmark": bench, "images": len(ds), "rows": rows,
            "check": {"function": "recon.bench.runner:check",
                      "kwargs": {"bench": bench, "methods": checked(names), "n": CHECK_IMAGES},
                      "values": values, "tolerance": CHECK_TOLERANCE}}
    return report.write(stem, data, render(data))


def scores_path(out_dir: Path, bench: str, method: str) -> Path:
    """Where ``evaluate`` keeps a method's per-image numbers on a benchmark."""
    return Path(out_dir) / "scores" / bench / (re.sub(r"[^A-Za-z0-9_.=,-]+", "_", method) + ".json")


def camera_and_shape(rows: list[dict]) -> list[str]:
    """The rows' camera and body-shape errors, for the methods that measured them (since 0.3)."""
    measured = [r for r in rows if "root_depth_mm" in r or "body_shape" in r]
    if not measured:
        return []
    names = next((list(r["body_shape"]["shape_error"]) for r in measured if "body_shape" in r), [])
    table = [[r["method"], r.get("root_depth_mm", {}).get("median"), r.get("root_depth_mm", {}).get("mean"),
              r.get("body_shape", {}).get("height_error_cm"), r.get("body_shape", {}).get("height_correlation"),
              r.get("body_shape", {}).get("weight_error_kg"), r.get("body_shape", {}).get("weight_correlation"),
              r.get("body_shape", {}).get("shape_correlation", {}).get("weight"),
              r.get("body_shape", {}).get("gender_accuracy"), r.get("body_shape", {}).get("gender_right_extremes"),
              *(r.get("body_shape", {}).get("shape_error", {}).get(n) for n in names)] for r in measured]
    return ["Camera and body shape: pelvis depth error (mm; the benchmark's K is given), standing height of the "
            "predicted body against the true one (mean |error| cm, Pearson correlation), the same for its weight "
            "(rest mesh volume x 985 kg/m^3: kg, r), build r (Pearson r of anny's weight phenotype), gender "
            "right (share with |error| < 0.5, measured since 0.6; and where the true gender is < 0.2 or > 0.8, "
            "the share on the right side of 0.5), mean |error| per anny phenotype (0-1 scale):", "",
            report.table(table, ["method", "depth median", "depth mean", "height cm", "height r", "weight kg",
                                 "weight r", "build r", "gender right", "gender extremes", *names],
                         ["", ".0f", ".0f", ".1f", ".2f", ".1f", ".2f", ".2f", ".3f", ".3f",
                          *[".3f"] * len(names)]), ""]


def found_table(rows: list[dict]) -> list[str]:
    """People found by view and by border cut, for the benchmarks that record them (other-*)."""
    measured = [r for r in rows if "found_by_view" in r]
    if not measured:
        return []
    keys = ["front", "side", "back", "cut", "whole"]
    table = [[r["method"], 1 - r["failures"] / max(r["images"], 1), *(r["found_by_view"].get(k) for k in keys)]
             for r in measured]
    return ["People found (share of images), by view (|yaw| < 45, 45-135, > 135 degrees) and by whether a "
            "border cuts the person:", "",
            report.table(table, ["method", "all", *keys], ["", ".3f", *[".3f"] * len(keys)]), ""]


def render(data: dict) -> str:
    """The Markdown of a benchmark's results JSON."""
    rows = data["rows"]
    main = [[r["method"], *(r[c] for c in COLUMNS), r["images"], r["failures"], r["seconds_per_image"]] for r in rows]
    groups = [[r["method"], *(r["groups"].get(a, float("nan")) for a in ABBR.values())] for r in rows]
    return "\n".join([
        f"Benchmark {data['benchmark']} ({data['images']} images; a method may be run on the first N). Errors in mm; "
        "failures = images where the method found no person (not scored).", "",
        report.table(main, ["method", *COLUMNS, "images", "failures", "s/img"],
                     ["", ".1f", ".1f", ".1f", ".1f", ".3f", "", "", ".3f"]), "",
        "Per joint group (MPJPE-P1, mm):", "",
        report.table(groups, ["method", *ABBR.values()]), "",
        *camera_and_shape(rows),
        *found_table(rows),
        "Methods: " + "; ".join(f"**{r['method']}**: {r['description']}" for r in rows)])
