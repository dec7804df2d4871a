"""Run methods over a synthetic benchmark and write JSON + Markdown tables side by side.

Protocol: MPJPE P1 = mean joint error after aligning pelvises; P2 = after a similarity
Procrustes per sample; Lm = landmark error (pelvis-aligned); PVE = per-vertex error
(pelvis-aligned); IoU = the method's mesh rendered with the sample's camera (or its own
mask) against the ground-truth full-body silhouette. A method that finds no person in an
image counts as a failure; it is scored on the images it handled and failures are reported.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch

from recon import metrics, paths
from recon.bench.methods import METHODS
from recon.synth.dataset import BENCHMARKS, SynthDataset, bench_dir
from recon.synth.raster import Rasterizer, silhouette_iou

ABBR = {"head": "Hd", "torso": "Ts", "shoulder": "Sr", "elbow": "Ew", "wrist": "Wt", "hip": "Hp", "knee": "Kn", "foot": "Ft"}


def run_method(name: str, ds: SynthDataset, body, n: int | None = None) -> dict:
    method = METHODS[name](body)
    raster = None
    faces = body.faces.numpy()
    rows = {"p1": [], "p2": [], "lm": [], "pve": [], "iou": [], "joint": []}
    failures, t0 = 0, time.time()
    from tqdm import tqdm

    for i in tqdm(range(min(n or len(ds), len(ds))), desc=f"eval {name}", unit="img", mininterval=5):
        s = ds[i]
        extra = {"points2d": s["points2d"], "points3d": s["points3d"]} if getattr(method, "needs_gt", False) else {}
        pred = method(s["rgb"], s["K"], **extra)
        if pred is None:
            failures += 1
            continue
        gt_j = torch.tensor(s["points3d"][None, :24])
        pj = torch.tensor(pred.joints[None], dtype=torch.float32)
        je = metrics.per_point_error(pj, gt_j)[0]
        rows["joint"].append(je.numpy())
        rows["p1"].append(float(je.mean()))
        rows["p2"].append(float(metrics.per_point_error(metrics.procrustes_align(pj, gt_j), gt_j, None).mean()))
        if pred.landmarks is not None:
            gl = s["points3d"][24:] - s["points3d"][:1]
            rows["lm"].append(float(np.linalg.norm(pred.landmarks - pred.joints[:1] - gl, axis=1).mean()))
        if pred.vertices is not None and "vertices" in s:
            gv = s["vertices"].astype(np.float32) @ s["R"].T  # stored pelvis-relative, body frame
            rows["pve"].append(float(np.linalg.norm(pred.vertices - pred.joints[:1] - gv, axis=1).mean()))
        mask = pred.mask
        if mask is None and pred.vertices is not None:
            raster = raster or Rasterizer(*s["rgb"].shape[1::-1])
            mask = raster.render(pred.vertices, faces, s["K"])[2] > 0
        if mask is not None:
            rows["iou"].append(silhouette_iou(mask, s["silhouette"]))
    done = len(rows["p1"])
    joint = np.stack(rows["joint"]) * 1000 if done else np.zeros((0, 24))
    res = {"method": name, "description": method.description, "images": done + failures,
           "failures": failures, "seconds_per_image": (time.time() - t0) / max(done + failures, 1)}
    for key, label in (("p1", "MPJPE-P1"), ("p2", "MPJPE-P2 (PA)"), ("lm", "Lm"), ("pve", "PVE")):
        res[label] = float(np.mean(rows[key]) * 1000) if rows[key] else None
    res["IoU"] = float(np.mean(rows["iou"])) if rows["iou"] else None
    res["groups"] = {ABBR[g]: float(v) for g, v in metrics.group_errors(torch.tensor(joint)).items()} if done else {}
    return res


def evaluate(bench: str, methods: list[str], n: int | None = None, out_dir: Path = Path("eval/results")) -> Path:
    from recon.body import default_body

    torch.set_num_threads(1)
    if bench not in BENCHMARKS:
        raise KeyError(f"unknown benchmark {bench!r}; known: {', '.join(BENCHMARKS)}")
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise KeyError(f"unknown method(s) {unknown}; known: {', '.join(METHODS)}")
    ds = SynthDataset(bench_dir(bench))
    body = default_body()
    new = [run_method(m, ds, body, n) for m in methods]
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = out_dir / f"{bench}"
    # merge with earlier runs: one table for all methods, re-run methods replaced in place
    old = json.loads(stem.with_suffix(".json").read_text()) if stem.with_suffix(".json").exists() else []
    fresh = {r["method"]: r for r in new}
    results = [fresh.pop(r["method"], r) for r in old] + list(fresh.values())
    paths.atomic_write(stem.with_suffix(".json"), lambda t: Path(t).write_text(json.dumps(results, indent=1)))
    return write_tables(bench, results, len(ds), out_dir)


def write_tables(bench: str, results: list[dict], images: int, out_dir: Path = Path("eval/results")) -> Path:
    """The Markdown tables of ``results`` (the benchmark's JSON rows) -> ``out_dir/<bench>.md``."""
    stem = Path(out_dir) / bench
    cols = ["MPJPE-P1", "MPJPE-P2 (PA)", "Lm", "PVE", "IoU"]
    fmt = lambda v, c: "-" if v is None else (f"{v:.3f}" if c == "IoU" else f"{v:.1f}")  # noqa: E731
    lines = [f"Benchmark {bench} ({images} images; a method may be run on the first N). Errors in mm; "
             "failures = images where the method found no person (not scored).", "",
             "| method | " + " | ".join(cols) + " | images | failures | s/img |", "|---|" + "---|" * (len(cols) + 3)]
    for r in results:
        lines.append(f"| {r['method']} | " + " | ".join(fmt(r[c], c) for c in cols) +
                     f" | {r['images']} | {r['failures']} | {r['seconds_per_image']:.3f} |")
    lines += ["", "Per joint group (MPJPE-P1, mm):", "", "| method | " + " | ".join(ABBR.values()) + " |",
              "|---|" + "---|" * len(ABBR)]
    for r in results:
        lines.append(f"| {r['method']} | " + " | ".join(f"{r['groups'].get(a, float('nan')):.1f}" for a in ABBR.values()) + " |")
    lines += ["", "Methods: " + "; ".join(f"**{r['method']}**: {r['description']}" for r in results)]
    paths.atomic_write(stem.with_suffix(".md"), lambda t: Path(t).write_text("\n".join(lines) + "\n"))
    print("\n".join(lines))
    return stem.with_suffix(".md")
