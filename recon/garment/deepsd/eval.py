"""``recon garment eval --model deepsd`` -> eval/results/garment-deepsd.{json,md}: DeePSD on held-out
outfits (``recon.garment.outfits``' held-out family and parameter bands) at poses of the test
performers, against their drapes (``deepsd.data``; the supervision's solver):

1. vertex error to the drape (mm), edge error (mm, against the template), bending and collision %
   (vertices inside the body), for DeePSD with and without its physics branch, the ablations that
   matter (no global descriptor, deformations instead of blend shapes, physics without extra
   poses; thesis tables 4.1 and 4.3) and LBS with the nearest body vertex's (diffused) weights;
2. per outfit family (table 4.4), held-out family apart;
3. the five presets at the same poses, where per-outfit PBNS exists: DeePSD against PBNS;
4. time to make a new outfit ready (a 12k-vertex mesh file to W and D) and frames a second.
"""
from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np
import roma
import torch
import trimesh
from torch.utils import benchmark

from recon import report
from recon.body import default_body
from recon.garment import store
from recon.garment.deepsd.data import DeePSDDataConfig, folder
from recon.garment.deepsd.model import DeePSD, OutfitGraph
from recon.garment.deepsd.train import VARIANTS, Sample, load_samples, variant_config
from recon.garment.metrics import physical_metrics
from recon.garment.outfits import HELD_OUT_FAMILIES
from recon.garment.pbns.model import PBNS, BlendShapeGarment, blend_transforms, pose_features
from recon.garment.templates import PRESETS, RestBody, make_outfit

METRICS = ("error_mm", "edge_mm", "bend", "collision_pct")
SPEED_OUTFIT = "tshirt-skirt"  # 12,292 vertices


@torch.no_grad()
def scores(v: torch.Tensor, s: Sample) -> dict:
    """The four metrics of predictions ``v`` (K, N, 3) on sample ``s``."""
    m = physical_metrics(v, s.graph.faces, s.graph.rest, s.body_v, s.body_n)
    return {"error_mm": float((v - s.drapes).norm(dim=-1).mean()) * 1000, "edge_mm": m["edge_mm"],
            "bend": m["bend"], "collision_pct": m["collision_pct"]}


@torch.no_grad()
def predict(method: str, s: Sample, models: dict[str, DeePSD], pbns: dict[str, PBNS]) -> torch.Tensor | None:
    g = s.graph
    if method == "drape":
        return s.drapes
    if method == "lbs":
        return BlendShapeGarment.apply_blend(g.rest, blend_transforms(g.lbs_weights, s.transforms))
    if method == "pbns":
        return pbns[s.family].pose(s.rotmats, s.transforms) if s.family in pbns else None
    name, physics = (method[:-len("-no-physics")], False) if method.endswith("-no-physics") else (method, True)
    if name not in models:
        return None
    m = models[name]
    if not m.cfg.blend_shapes:  # the deformation ablation: the network itself
        return m(g, s.rotmats, s.transforms, physics=physics)
    return m.outfit(g, physics).pose(s.rotmats, s.transforms)  # what a user gets: the exported W and D


def mean_rows(per: dict[str, list[dict]]) -> dict[str, dict]:
    return {m: {k: float(np.mean([r[k] for r in rows])) for k in METRICS} for m, rows in per.items() if rows}


def evaluate(data: DeePSDDataConfig | None = None, log=print) -> dict:
    data = data or DeePSDDataConfig()
    torch.set_num_threads(1)
    body = default_body()
    models = {}
    for name in VARIANTS:
        path = store.deepsd_path(variant_config(name).name)
        if path.exists():
            models[name] = DeePSD.load(path)[0]
    if "ours" not in models:
        raise FileNotFoundError(f"no DeePSD weights {store.deepsd_path()}: run `recon garment train --model deepsd`")
    methods = ["drape", "lbs", "ours-no-physics", "ours"] + [v for v in VARIANTS if v != "ours" and v in models]
    out: dict = {"methods": methods}
    for split in ("test", "preset"):
        samples = load_samples(body, split, data)
        pbns = {}
        if split == "preset":
            pbns = {p: PBNS.load(store.pbns_path(p))[0] for p in PRESETS if store.pbns_path(p).exists()}
        ms = methods + (["pbns"] if pbns else [])
        per: dict[str, list[dict]] = {m: [] for m in ms}
        fam: dict[str, dict[str, list[dict]]] = {}
        for s in samples:
            for m in ms:
                v = predict(m, s, models, pbns)
                if v is None:
                    continue
                sc = scores(v, s) | {"family": s.family, "vertices": len(s.graph.rest)}
                per[m].append(sc)
                if m in ("lbs", "ours", "pbns"):
                    fam.setdefault(s.family, {}).setdefault(m, []).append(sc)
        out[split] = {"outfits": len(samples), "poses": int(len(samples[0].rotmats)) if samples else 0,
                      "rows": mean_rows(per), "families": {f: mean_rows(v) for f, v in sorted(fam.items())},
                      "per_outfit": {m: per[m] for m in ("ours", "lbs", "pbns") if m in per}}
        log(f"{split}: " + json.dumps(out[split]["rows"].get("ours")))
    out["speed"] = speed(body, models["ours"])
    timing = folder(data) / "timing.json"
    out["data"] = {"train_outfits": len(list(folder(data).glob("train-*.pt"))),
                   "val_outfits": len(list(folder(data).glob("val-*.pt"))),
                   "seconds": json.loads(timing.read_text())["seconds"] if timing.exists() else None}
    out["check"] = {"function": "recon.garment.deepsd.eval:check", "kwargs": {"outfit": "top-shorts"},
                    "values": check("top-shorts")}
    return out


def check_pose() -> torch.Tensor:
    """A fixed pose (24, 3, 3): arms down, one knee and one elbow bent."""
    rv = torch.zeros(24, 3)
    rv[16, 2], rv[17, 2] = -1.1, 1.1  # shoulders (SMPL order)
    rv[4, 0], rv[19, 1] = 0.6, -0.8  # left knee, right elbow
    return roma.rotvec_to_rotmat(rv)


@torch.no_grad()
def check(outfit: str) -> dict:
    """The shipped DeePSD on a preset's template at ``check_pose``: how far its blend weights move
    from the nearest-body ones and its blend shapes move the cloth (recomputed by the tests)."""
    torch.set_num_threads(1)
    body = default_body()
    model = DeePSD.load(store.deepsd_path())[0]
    o = make_outfit(body, outfit)
    g = OutfitGraph.of(RestBody(body), o)
    pb = model.outfit(g)
    d = pb.decode(pb.mlp(pose_features(check_pose()[None])))[0]
    return {"vertices": len(o.vertices), "weights_moved": float((pb.weights - g.lbs_weights).abs().sum(1).mean()),
            "displacement_mm": float(d.norm(dim=-1).mean() * 1000)}


def speed(body, model: DeePSD, repeats: int = 3) -> dict:
    """Seconds from a garment mesh file (the dress template, one piece) to W and D (loading,
    clean-up, push-out, nearest-body weights, graph, network; median of ``repeats``), and frames a
    second of a 12k-vertex outfit's result (LBS + blend shapes, given the posed body's joint
    transforms, batch 1; the best of ``repeats`` timings: this machine's speed varies run to run),
    on 1 and 2 threads."""
    rb = RestBody(body)
    dress = make_outfit(body, "dress")
    o = make_outfit(body, SPEED_OUTFIT)
    pb = model.outfit(OutfitGraph.of(rb, o))
    rot = torch.eye(3).expand(1, 24, 3, 3).clone()
    tr = body(rot, body.mean_shape[None]).transforms
    out = {"file_vertices": len(dress.vertices), "outfit": SPEED_OUTFIT, "vertices": len(o.vertices),
           "ready_s": {}, "fps": {}}
    threads_before = torch.get_num_threads()
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "garment.obj"
        trimesh.Trimesh(dress.vertices, dress.faces, process=False).export(path)
        for threads in (1, 2):
            torch.set_num_threads(threads)
            times = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                model.outfit(OutfitGraph.of(rb, make_outfit(body, str(path))))
                times.append(time.perf_counter() - t0)
            out["ready_s"][f"{threads}t"] = float(np.median(times))
            t = benchmark.Timer("m.pose(r, t)", globals={"m": pb, "r": rot, "t": tr}, num_threads=threads)
            out["fps"][f"{threads}t"] = max(1.0 / t.blocked_autorange(min_run_time=1.0).median for _ in range(repeats))
    torch.set_num_threads(threads_before)
    return out


LABELS = {"drape": "drape (ground truth)", "lbs": "LBS, nearest-body weights", "ours-no-physics":
          "DeePSD without physics (D_data)", "ours": "DeePSD", "no-global": "no global descriptor (no phys.)",
          "deformations": "deformations, not blend shapes (no phys.)",
          "physics-no-extra-poses": "DeePSD, physics without extra poses", "pbns": "per-outfit PBNS"}


def _rows(rows: dict, order: list[str]) -> list[list]:
    return [[LABELS.get(m, m)] + [rows[m][k] for k in METRICS] for m in order if m in rows]


def render(data: dict) -> str:
    heads = ["method", "error mm", "edge mm", "bend", "collision %"]
    fmt = ["", ".1f", ".2f", ".4f", ".2f"]
    t, p = data["test"], data["preset"]
    lines = ["# DeePSD: any outfit without training (thesis ch. 4)", "",
             f"{t['outfits']} held-out outfits (families {', '.join(HELD_OUT_FAMILIES)} and the held-out parameter "
             f"bands, recon.garment.outfits) x {t['poses']} poses of the test performers, on the mean body; error = "
             "mean vertex distance to the drape (recon.garment.drape, the training data's solver); edge against the "
             "template; collision = vertices inside the body. Mean over outfits.", "",
             report.table(_rows(t["rows"], ["lbs"] + data["methods"][2:] + ["drape"]), heads, fmt), "",
             "Per family (DeePSD / LBS):", ""]
    fam_rows = [[f + (" (held-out family)" if f in HELD_OUT_FAMILIES else ""), r["ours"]["error_mm"],
                 r["lbs"]["error_mm"], r["ours"]["edge_mm"], r["ours"]["collision_pct"]]
                for f, r in t["families"].items()]
    lines += [report.table(fam_rows, ["family", "DeePSD mm", "LBS mm", "DeePSD edge mm", "DeePSD collision %"],
                           ["", ".1f", ".1f", ".2f", ".2f"]), ""]
    lines += [f"The five presets at the same poses ({p['outfits']} outfits; per-outfit PBNS trained on each, "
              "DeePSD never saw them):", "",
              report.table(_rows(p["rows"], ["lbs", "ours-no-physics", "ours", "pbns", "drape"]), heads, fmt), ""]
    sp = data["speed"]
    lines += [f"Speed: a {sp['file_vertices']:,}-vertex garment mesh file (the dress template) to W and D in "
              f"{sp['ready_s']['1t']:.2f} s on 1 thread, {sp['ready_s']['2t']:.2f} s on 2 (loading, clean-up, "
              f"nearest-body weights, graph, network; median of 3); {sp['outfit']} ({sp['vertices']:,} vertices) "
              f"then runs at {sp['fps']['1t']:.0f} frames/s at batch 1 on 1 thread, {sp['fps']['2t']:.0f} on 2 (given "
              "the posed body's joint transforms; best of 3: this machine's speed varies from run to run).", "",
              f"Training data: {data['data']['train_outfits']} train outfits (recon.garment.deepsd.data); model card: "
              "recon/garment/weights/MODEL_CARD.md."]
    return "\n".join(lines)


def evaluate_and_report(out_dir: Path = report.RESULTS, log=print) -> Path:
    data = evaluate(log=log)
    return report.write(Path(out_dir) / "garment-deepsd", data, render(data))
