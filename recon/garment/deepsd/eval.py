"""``recon garment eval --model deepsd`` -> eval/results/garment-deepsd.{json,md}: DeePSD on held-out
outfits (``recon.garment.outfits``' held-out family and parameter bands) at poses of the test
performers, against their drapes (``deepsd.data``; the supervision's solver):

1. vertex error to the drape (mm), edge error (mm, against the template), bending and collision %
   (vertices inside the body), for DeePSD with and without its physics branch, the ablations that
   matter (no global descriptor, deformations instead of blend shapes, physics without extra
   poses; thesis tables 4.1 and 4.3) and LBS with the nearest body vertex's (diffused) weights;
2. per outfit family (table 4.4), held-out family apart;
3. the five presets at the same poses, where per-outfit PBNS exists: DeePSD against PBNS;
   DeePSD and PBNS followed by the Dresser's post-step (recon.garment.collide: strain step and
   collision resolution), reported apart from the networks;
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
from recon.body.base import BodyModel
from recon.body.lbs import blend_transforms
from recon.garment import store
from recon.garment.collide import CollisionResolver
from recon.garment.deepsd.data import DeePSDDataConfig, folder
from recon.garment.deepsd.model import DeePSD, OutfitGraph
from recon.garment.deepsd.train import VARIANTS, Sample, load_samples, variant_config
from recon.garment.metrics import physical_metrics
from recon.garment.outfits import HELD_OUT_FAMILIES
from recon.garment.pbns.model import PBNS, BlendShapeGarment, pose_features
from recon.garment.templates import PRESETS, RestBody, make_outfit

METRICS = ("error_mm", "edge_mm", "bend", "collision_pct")
SPEED_OUTFIT = "tshirt-skirt"  # 12,292 vertices


@torch.no_grad()
def scores(v: torch.Tensor, s: Sample) -> dict:
    """The four metrics of predictions ``v`` (K, N, 3) on sample ``s``."""
    m = physical_metrics(v, s.graph.faces, s.graph.rest, s.body_v, s.body_n)
    return {"error_mm": float((v - s.drapes).norm(dim=-1).mean()) * 1000, "edge_mm": m["edge_mm"],
            "bend": m["bend"], "collision_pct": m["collision_pct"]}


# rows of a method's output through the post-step: (method, with the strain step)
POSTED = {"ours+collisions": ("ours", False), "ours+post": ("ours", True), "pbns+post": ("pbns", True)}
FAMILY_METHODS = ("lbs", "ours", "ours+post", "pbns", "pbns+post")


@torch.no_grad()
def post_step(v: torch.Tensor, s: Sample, faces_body: np.ndarray, strain: bool = True) -> torch.Tensor:
    """The Dresser's post-step on predictions ``v`` (K, N, 3) of sample ``s``: the strain step
    (``strain``) and collision resolution."""
    res = CollisionResolver(s.graph.faces, s.layer)
    return res(v, s.body_v, faces_body, rest=s.graph.rest if strain else None)


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


def evaluate(data: DeePSDDataConfig | None = None, log=print, previous: dict | None = None) -> dict:
    """``previous``: an earlier garment-deepsd.json whose rows of the ablation variants without
    weights in this cache are carried over (marked so; they do not depend on anything re-run)."""
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
    carried = [v for v in VARIANTS if v != "ours" and v not in models and previous
               and v in previous.get("test", {}).get("rows", {})]
    methods = (["drape", "lbs", "ours-no-physics", "ours", "ours+collisions", "ours+post"]
               + [v for v in VARIANTS if v != "ours" and (v in models or v in carried)])
    out: dict = {"methods": methods, "carried_over": carried}
    for split in ("test", "preset"):
        samples = load_samples(body, split, data)
        pbns = {}
        if split == "preset":
            pbns = {p: PBNS.load(store.pbns_path(p))[0] for p in PRESETS if store.pbns_path(p).exists()}
        ms = methods + (["pbns", "pbns+post"] if pbns else [])
        per: dict[str, list[dict]] = {m: [] for m in ms}
        fam: dict[str, dict[str, list[dict]]] = {}
        post_s, frames = 0.0, 0
        for s in samples:
            preds: dict[str, torch.Tensor | None] = {}
            for m in ms:
                if m in POSTED:
                    base, strain = POSTED[m]
                    t0 = time.perf_counter()
                    v = None if preds.get(base) is None else post_step(preds[base], s, body.faces, strain)
                    if m == "ours+post":
                        post_s, frames = post_s + time.perf_counter() - t0, frames + len(v)
                else:
                    v = predict(m, s, models, pbns)
                preds[m] = v
                if v is None:
                    continue
                sc = scores(v, s) | {"family": s.family, "vertices": len(s.graph.rest)}
                per[m].append(sc)
                if m in FAMILY_METHODS:
                    fam.setdefault(s.family, {}).setdefault(m, []).append(sc)
        rows = mean_rows(per) | {v: previous[split]["rows"][v] for v in carried if v in previous[split]["rows"]}
        out[split] = {"outfits": len(samples), "poses": int(len(samples[0].rotmats)) if samples else 0,
                      "rows": rows, "families": {f: mean_rows(v) for f, v in sorted(fam.items())},
                      "per_outfit": {m: per[m] for m in FAMILY_METHODS if m in per},
                      "post_step_ms": 1000 * post_s / max(frames, 1)}
        log(f"{split}: " + json.dumps(out[split]["rows"].get("ours")))
    out["speed"] = speed(body, models["ours"])
    timing = folder(data) / "timing.json"
    train = len(list(folder(data).glob("train-*.pt")))
    out["data"] = {"train_outfits": train, "val_outfits": len(list(folder(data).glob("val-*.pt"))),
                   "seconds": json.loads(timing.read_text())["seconds"] if timing.exists() else None}
    if previous and not train:  # evaluated from the eval splits alone: the training data's record stays
        out["data"] = previous["data"]
    if carried:  # how far the rows run again moved from the previous run's
        out["rerun_moved_mm"] = max(abs(out[sp]["rows"][m]["error_mm"] - previous[sp]["rows"][m]["error_mm"])
                                    for sp in ("test", "preset") for m in ("lbs", "ours", "ours-no-physics")
                                    if m in previous[sp]["rows"])
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


def speed(body: BodyModel, model: DeePSD, repeats: int = 3) -> dict:
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
          "physics-no-extra-poses": "DeePSD, physics without extra poses", "pbns": "per-outfit PBNS",
          "ours+collisions": "DeePSD + collision resolution (post-step)",
          "ours+post": "DeePSD + strain step + collision resolution (post-step)",
          "pbns+post": "per-outfit PBNS + strain step + collision resolution (post-step)"}


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
             report.table(_rows(t["rows"], ["lbs"] + data["methods"][2:] + ["drape"]), heads, fmt), ""]
    if data.get("carried_over"):
        lines += ["Rows carried over from the previous run (their weights were not in this run's cache): "
                  + ", ".join(LABELS.get(m, m) for m in data["carried_over"]) + ". The rows run again here moved "
                  f"by at most {data['rerun_moved_mm']:.2f} mm from the previous run's (the test drapes are made "
                  "again from the same configuration when not in the cache).", ""]
    lines += [
             "Per family (DeePSD with and without the post-step; LBS):", ""]
    fam_rows = [[f + (" (held-out family)" if f in HELD_OUT_FAMILIES else ""), r["lbs"]["error_mm"]]
                + [r[m][k] for m in ("ours", "ours+post") for k in ("error_mm", "edge_mm", "collision_pct")]
                for f, r in t["families"].items()]
    lines += [report.table(fam_rows, ["family", "LBS mm", "DeePSD mm", "edge mm", "collision %",
                                      "+ post-step mm", "edge mm", "collision %"],
                           ["", ".1f", ".1f", ".2f", ".2f", ".1f", ".2f", ".2f"]), "",
              "Post-step: the Dresser's default after any garment model (recon.garment.collide): the strain step "
              "(projective dynamics towards the rest edge lengths, anchored to the prediction, contact planes) "
              f"then collision resolution; {t['post_step_ms']:.0f} ms a frame on 1 thread (mean over these outfits, "
              "its factorisation included). Its settings were chosen on the val outfits.", ""]
    lines += [f"The five presets at the same poses ({p['outfits']} outfits; per-outfit PBNS trained on each, "
              "DeePSD never saw them):", "",
              report.table(_rows(p["rows"], ["lbs", "ours-no-physics", "ours", "ours+post", "pbns", "pbns+post",
                                             "drape"]), heads, fmt), ""]
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
    old = Path(out_dir) / "garment-deepsd.json"
    data = evaluate(log=log, previous=json.loads(old.read_text()) if old.exists() else None)
    return report.write(Path(out_dir) / "garment-deepsd", data, render(data))
