"""``recon garment eval --model ncs``: skinning, PBNS and NCS on held-out mocap clips
(eval/results/garment-ncs.{json,md}).

Per outfit, a row each for the skinned template (dT = 0), PBNS and NCS:
- collision % and edge error (mm) over the frames of every test clip (the models run on every
  frame at 30 fps; every ``STRIDE``-th frame is scored), split by the body's own
  self-intersection as PBNS's table is (recon.garment.metrics.physical_metrics);
- against newton's VBD run dynamically (recon.garment.reference.simulate: velocities kept, the
  body and the held vertices moving, the cloth starting at the skinned outfit's velocity and
  damped relative to it) on a few short held-out clips (``DYNAMIC_CLIPS``: a turn, a run that
  stops, a walk; each scored after a lead-in of the clip's earlier frames), for the outfits'
  pinned garments (a skirt), or the whole outfit held at its shoulders when nothing is pinned (a
  dress; ``recon.garment.ncs.model.hanging_part``):
  ``sim_error_mm``, the mean per-vertex distance per frame, and the hem's
  swing: the hem centroid's horizontal offset from where skinning puts it (``hem_peak_mm`` per
  model and for the simulation; ``hem_error_mm``: the mean distance between the model's offset
  and the simulation's over the frames), also for NCS at motion control 0 (``STATIC_PART``: its
  static part alone, which tells what its dynamics add);
- speed: frames per second on one thread for batch 1 (PBNS: one pose; NCS: one frame streamed with
  its recurrent state) and batch 64 (64 poses; NCS: 64 frames of a sequence in one call), given
  the body's joint transforms.
The simulations are cached (``~/.cache/recon/garment-dynamic/``): they take minutes per clip.
"""
from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from recon import report
from recon.body import default_body
from recon.body.base import BodyModel
from recon.errors import MissingFile
from recon.garment import reference, store
from recon.garment.collide import CollisionResolver
from recon.garment.data import posed_bodies
from recon.garment.metrics import physical_metrics
from recon.garment.ncs.model import NCS, motion_inputs
from recon.garment.ncs.reference_eval import (
    DYNAMIC_CLIPS,
    VAL_CLIPS,
    DynamicClip,
    clip_motion,
    dynamic_reference,
    hem_twist,
    hem_vertices,
    lead_in,
)
from recon.garment.pbns.model import PBNS
from recon.garment.self_intersection import SkinSelfIntersection
from recon.poses.mocap import SPLIT_SUBJECTS, MocapPoses
from recon.timing import frames_per_second

MODELS = ("skinning only (dT = 0)", "PBNS", "NCS")
STATIC_PART = "NCS at motion control 0 (its static part)"
STRIDE = 4


CHECK_CLIP = ("12_01", 0, 16, 0)  # the slice tests/test_results.py recomputes


@torch.no_grad()
def run_models(pbns: PBNS, ncs: NCS | None, body: BodyModel, shape: torch.Tensor, rot: torch.Tensor,
               transl: torch.Tensor, static_part: bool = False) -> dict:
    """The models on one sequence: {model: (T, N, 3)} (NCS only when given; ``static_part``: also
    NCS at motion control 0, under ``STATIC_PART``)."""
    with torch.no_grad():
        transforms = body(rot, shape.expand(len(rot), -1), transl=transl, points_only=True).transforms
    chunks = range(0, len(rot), 64)
    out = {MODELS[0]: torch.cat([pbns.skin(pbns.rest, transforms[i:i + 64]) for i in chunks]),
           MODELS[1]: torch.cat([pbns.pose(rot[i:i + 64], transforms[i:i + 64]) for i in chunks])}
    if ncs is not None:  # at the rate it was trained at (NCS.motion_codes resamples)
        zs, zd = ncs.motion_codes(body, rot, shape, transl)
        out[MODELS[2]] = ncs.pose_codes(zs + zd, transforms)
        if static_part:
            out[STATIC_PART] = ncs.pose_codes(zs, transforms)
    return out


def clip_rows(body: BodyModel, pbns: PBNS, ncs: NCS | None, shape: torch.Tensor, clips: list[tuple],
              stride: int = STRIDE, split: str = "test", post: CollisionResolver | None = None) -> dict:
    """Physical metrics of the three models over the scored frames of ``clips`` [(name, start,
    frames, hold)] of the ``split``; ``post``: also PBNS's and NCS's frames through that post-step
    (the Dresser's, recon.garment.collide), as "<model> + post-step"."""
    poses = MocapPoses.load(split)
    models = MODELS if ncs is not None else MODELS[:2]
    posed: dict[str, list] = {m: [] for m in models}
    rots, trs = [], []
    for clip in clips:
        rot, tr = clip_motion(poses, *clip[:4])
        out = run_models(pbns, ncs, body, shape, rot, tr)
        keep = torch.arange(0, len(rot), stride)
        for m in models:
            posed[m].append(out[m][keep])
        rots.append(rot[keep])
        trs.append(tr[keep])
    bv, bn, _ = posed_bodies(body, torch.cat(rots), shape, transl=torch.cat(trs))
    self_pct = SkinSelfIntersection(body, shape).percent(bv)
    faces = pbns.faces.numpy()
    cloth = {m: torch.cat(posed[m]) for m in models}
    if post is not None:
        for m in models[1:]:
            cloth[f"{m} + post-step"] = torch.cat([post(cloth[m][i:i + 64], bv[i:i + 64], body.faces, rest=pbns.rest)
                                                   for i in range(0, len(bv), 64)])
    return {m: physical_metrics(v, faces, pbns.rest, bv, bn, self_pct) for m, v in cloth.items()}


def split_clips(split: str = "test") -> list[tuple]:
    """Every clip of a mocap split, whole: [(name, 0, None, 0)]."""
    poses = MocapPoses.load(split)
    return [(poses.clips[c]["name"], 0, None, 0) for c in np.unique(poses.clip)]


def dynamic_rows(body: BodyModel, outfit_name: str, pbns: PBNS, ncs: NCS, shape: torch.Tensor, clip: DynamicClip,
                 log=None) -> dict:
    """Per model, on one simulated clip (its scored frames, after the lead-in): sim_error_mm, the
    hem's swing against the simulation, the hem's twist and, after a dead stop, its overshoot."""
    sim = dynamic_reference(body, outfit_name, pbns, shape, clip, log)
    rot, tr = lead_in(clip)
    out = {m: v[clip.lead:] for m, v in run_models(pbns, ncs, body, shape, rot, tr, static_part=True).items()}
    sub = sim["subset"]
    ref = torch.from_numpy(sim["vertices"][clip.lead:]).float()
    hem = hem_vertices(pbns.rest.numpy(), pbns.faces.numpy())
    hem_sub = np.cumsum(sub)[hem] - 1  # hem indices within the simulated subset
    skin_hem = out[MODELS[0]][:, hem]
    skin_c = skin_hem.mean(1)
    travel = tr[clip.lead + clip.frames - 1] - tr[clip.lead]  # the body's way over the scored frames
    travel = (travel[[0, 2]] / travel[[0, 2]].norm().clamp_min(1e-9))

    def swing(v_hem: torch.Tensor) -> torch.Tensor:  # (T, 2) hem centroid's horizontal offset from skinning
        d = v_hem.mean(1) - skin_c
        return d[:, [0, 2]]

    def summary(v_hem: torch.Tensor) -> dict:
        s = swing(v_hem)
        r = {"hem_peak_mm": float(s.norm(dim=-1).max() * 1000),
             "hem_twist_peak_deg": float(hem_twist(v_hem, skin_hem).abs().max().rad2deg())}
        if clip.hold:  # after the body stops: how far the hem swings on along the way it went
            r["hem_overshoot_mm"] = float((s[clip.frames:] @ travel).max() * 1000)
        return r

    sim_swing = swing(ref[:, hem_sub])
    rows = {}
    for m in (*MODELS, STATIC_PART):
        v = out[m][:, torch.from_numpy(np.nonzero(sub)[0])]
        rows[m] = {"sim_error_mm": float((v - ref).norm(dim=-1).mean() * 1000),
                   "hem_error_mm": float((swing(out[m][:, hem]) - sim_swing).norm(dim=-1).mean() * 1000),
                   **summary(out[m][:, hem])}
    sim_summary = summary(ref[:, hem_sub])
    return {"clip": clip.name, "split": clip.split, "start": clip.start, "frames": clip.frames, "hold": clip.hold,
            "lead": clip.lead, "motion": clip.motion, "rows": rows,
            "sim_hem_peak_mm": sim_summary["hem_peak_mm"], "sim": sim_summary, "sim_seconds": float(sim["seconds"]),
            "simulated_vertices": int(sub.sum())}


@torch.no_grad()
def speed(pbns: PBNS, ncs: NCS, body: BodyModel, shape: torch.Tensor) -> dict:
    """Frames per second given the transforms: batch 1 and 64 (see the module's docstring)."""
    rot, tr = clip_motion(MocapPoses.load("test"), CHECK_CLIP[0], 0, 64)
    static, dynamic, pose, transforms = motion_inputs(body, rot, shape, tr)
    _, h = ncs.animate(static[:8], dynamic[:8], pose[:8], transforms[:8])
    fps = frames_per_second
    return {MODELS[1]: {"fps_batch1": fps(lambda: pbns.pose(rot[:1], transforms[:1]), 1),
                        "fps_batch64": fps(lambda: pbns.pose(rot, transforms), 64)},
            MODELS[2]: {"fps_batch1": fps(lambda: ncs.animate(static[8:9], dynamic[8:9], pose[8:9], transforms[8:9],
                                                              h=h), 1),
                        "fps_batch64": fps(lambda: ncs.animate(static, dynamic, pose, transforms), 64)}}


def load_models(outfit: str, ncs_weights: Path | None = None) -> tuple[PBNS, NCS, dict, torch.Tensor]:
    """An outfit's shipped PBNS, its NCS (``ncs_weights``: another file), NCS's checkpoint and the
    outfit's body shape (1, S)."""
    path = Path(ncs_weights or store.ncs_path(outfit))
    if not path.exists():
        raise MissingFile(f"{path} not found: train it with `recon garment train --model ncs --outfit {outfit}`")
    pbns, ck = PBNS.load(store.pbns_path(outfit))
    ncs, nck = NCS.load(path)
    return pbns, ncs, nck, ck["shape"][None]


def ncs_check(outfits: list[str]) -> dict:
    """The check slice of garment-ncs.json: skinning and PBNS (the shipped weights) on CHECK_CLIP."""
    body = default_body()
    out = {}
    for o in outfits:
        pbns, ck = PBNS.load(store.pbns_path(o))
        rows = clip_rows(body, pbns, None, ck["shape"][None], [CHECK_CLIP])
        out[o] = {m: {k: r[k] for k in ("collision_pct", "edge_mm")} for m, r in rows.items()}
    return out


def post_step(outfit: str, pbns: PBNS) -> CollisionResolver:
    """The Dresser's post-step for an outfit's shipped PBNS (its garment layers)."""
    return CollisionResolver(pbns.faces.numpy(), PBNS.load(store.pbns_path(outfit))[1]["layer"].numpy())


def post_step_check(outfit: str) -> dict:
    """The check slice of garment-post-step-clips.json (eval/post_step_clips.py): PBNS and NCS
    without and with the Dresser's post-step on CHECK_CLIP."""
    body = default_body()
    pbns, ncs, _, shape = load_models(outfit)
    rows = clip_rows(body, pbns, ncs, shape, [CHECK_CLIP], post=post_step(outfit, pbns))
    return {m: {k: r[k] for k in ("collision_pct", "edge_mm")} for m, r in rows.items()}


def evaluate(body: BodyModel, outfit: str, dynamic: bool = True, ncs_weights: Path | None = None, log=None,
             clips: tuple[DynamicClip, ...] = DYNAMIC_CLIPS) -> dict:
    """Every row of the table for one outfit; ``dynamic``: against the simulations of ``clips``.
    Collisions and strain over every clip of the split ``clips`` come from (val clips: the val split)."""
    pbns, ncs, nck, shape = load_models(outfit, ncs_weights)
    meta = json.loads(nck["meta_json"])
    split = clips[0].split
    rows = clip_rows(body, pbns, ncs, shape, split_clips(split), split=split)
    for m, r in speed(pbns, ncs, body, shape).items():
        rows[m] |= r
    dyn = [dynamic_rows(body, outfit, pbns, ncs, shape, c, log) for c in clips] if dynamic else []
    if dyn:
        for m in MODELS:
            for k in ("sim_error_mm", "hem_error_mm"):
                rows[m][k] = float(np.mean([d["rows"][m][k] for d in dyn]))
        rows[MODELS[2]]["sim_error_static_mm"] = float(np.mean([d["rows"][STATIC_PART]["sim_error_mm"] for d in dyn]))
    return {"outfit": meta["outfit"], "ncs_weights": path_label(ncs_weights), "vertices": int(pbns.rest.shape[0]),
            "train_seconds": meta["train_seconds"], "train_steps": meta["curve"][-1]["step"] if meta["curve"] else 0,
            "train_chunks": len(meta.get("chunks", [])),
            "stride": STRIDE, "rows": rows, "dynamic_clips": dyn, "threads": torch.get_num_threads(),
            "simulation": asdict(reference.DynamicConfig())}


def path_label(ncs_weights: Path | None) -> str:
    """Where the NCS weights came from: the shipped file, or (an experiment) a file's name."""
    return "shipped" if ncs_weights is None else Path(ncs_weights).name


# the outfits whose hanging part swings (a skirt, a dress): the ones simulated dynamically
SIMULATED = ("tshirt-skirt", "dress")


def evaluate_and_report(body: BodyModel, outfits: list[str], out_dir: Path = report.RESULTS, dynamic: bool = True,
                        ncs_weights: list[Path] | None = None, log=None, val: bool = False,
                        update: bool = False) -> Path:
    """garment-ncs.{json,md} (``val``: garment-ncs-val, against the val performers' simulations,
    what the recipe is tuned on); the dynamic simulations for the outfits in ``SIMULATED``.
    ``ncs_weights``: one NCS file per outfit instead of the shipped ones. ``update``: keep the
    other outfits' rows of the existing file (one outfit re-evaluated after retraining)."""
    weights = ncs_weights or [None] * len(outfits)
    clips = VAL_CLIPS if val else DYNAMIC_CLIPS
    results = [evaluate(body, o, dynamic and o in SIMULATED, w, log, clips)
               for o, w in zip(outfits, weights, strict=True)]
    path = Path(out_dir) / ("garment-ncs-val" if val else "garment-ncs")
    if update and path.with_suffix(".json").exists():  # the re-evaluated outfits' rows where they were
        mine = {r["outfit"]: r for r in results}
        old = json.loads(path.with_suffix(".json").read_text())["outfits"]
        had = {r["outfit"] for r in old}
        results = [mine.get(r["outfit"], r) for r in old] + [r for r in results if r["outfit"] not in had]
    names = [r["outfit"] for r in results]
    data = {"outfits": results, "clips": "val" if val else "test",
            "check": {"function": "recon.garment.ncs.eval:ncs_check", "kwargs": {"outfits": names},
                      "values": ncs_check(names)}}
    return report.write(path, data, render(data))


def render(data: dict) -> str:
    val = data.get("clips") == "val"
    lines = ["# NCS (dynamic) vs PBNS (quasi-static) vs skinning on held-out clips"
             + (" (val: the clips the recipe is tuned on)" if val else ""), "",
             "`recon garment eval --model ncs` (recon/garment/ncs/eval.py). Collision % / edge error: "
             f"every {STRIDE}th frame of every {'val' if val else 'test'}-split clip (performers "
             f"{', '.join(sorted(SPLIT_SUBJECTS['val' if val else 'test'], key=int))}), the models run on "
             "every frame at 30 fps. Against the simulation: newton VBD with velocities (recon.garment.reference."
             "simulate) on the clips below; hem swing = the hem centroid's horizontal offset from where "
             "skinning puts it. Simulated: pinned garments on their own (a skirt); an outfit without pins (a "
             "dress) held by its top band (`hanging_part`), else VBD with velocities lets it slide off; an "
             "outfit without rows below was evaluated before it was held. Speed: one thread, given the body's "
             "transforms. sim_error_mm at motion 0: NCS with its dynamic code off (motion control 0), its "
             "static part alone."]
    if any("lead" in d for r in data["outfits"] for d in r["dynamic_clips"]):
        lines[-1] += (" Each simulated clip is scored after a lead-in (the frames of the clip before it, which "
                      "the simulation and the models run through), and the simulated cloth starts from its drape "
                      "moving as the skinned outfit moves.")
    lines.append("")
    head = ("| outfit | model | collision % | edge mm | sim_error_mm | sim_error_mm at motion 0 | hem_error_mm | "
            "fps b=1 | fps b=64 |", "|---|---|---|---|---|---|---|---|---|")
    lines += list(head)

    def f(x, d=2):
        return "-" if x is None else f"{x:,.{d}f}"
    def label(r, m):
        w = r.get("ncs_weights", "shipped")
        return m if m != MODELS[2] or w == "shipped" else f"{m} ({w}, {r['train_steps']} steps, not shipped)"
    for r in data["outfits"]:
        for m in MODELS:
            x = r["rows"][m]
            lines.append(f"| {r['outfit']} | {label(r, m)} | {f(x['collision_pct'])} | {f(x['edge_mm'])} | "
                         f"{f(x.get('sim_error_mm'), 1)} | {f(x.get('sim_error_static_mm'), 1)} | "
                         f"{f(x.get('hem_error_mm'), 1)} | "
                         f"{f(x.get('fps_batch1'), 0)} | {f(x.get('fps_batch64'), 0)} |")
    lines += ["", "## Per simulated clip", "",
              "hem peak: the hem centroid's largest horizontal offset from where skinning puts it; twist: the "
              "hem ring's largest rotation about the vertical from skinning's (a spin's lag); overshoot: after "
              "the body stops dead, how far the hem swings on along the way the body went. In brackets, the "
              "simulation's.", "",
              "| outfit | clip | motion | model | sim_error_mm | hem_error_mm | hem peak mm | twist deg | "
              "overshoot mm |", "|---|---|---|---|---|---|---|---|---|"]
    for r in data["outfits"]:
        for d in r["dynamic_clips"]:
            sim = d.get("sim", {"hem_peak_mm": d["sim_hem_peak_mm"]})
            for m in (m for m in (*MODELS, STATIC_PART) if m in d["rows"]):
                x = d["rows"][m]
                span = f"[{d['start']}:+{d['frames']}" + (f", after {d['lead']}]" if d.get("lead") else "]")

                def both(k, x=x, sim=sim):
                    return "-" if k not in x else f"{x[k]:,.0f} ({sim[k]:,.0f})"
                lines.append(f"| {r['outfit']} | {d['clip']} {span} | {d['motion']} | {m} | "
                             f"{f(x['sim_error_mm'], 1)} | {f(x['hem_error_mm'], 1)} | {both('hem_peak_mm')} | "
                             f"{both('hem_twist_peak_deg')} | {both('hem_overshoot_mm')} |")
    bins = list(data["outfits"][0]["rows"][MODELS[0]].get("by_body_self_intersection", {}))
    lines += ["", "## By the body's self-intersection (% of the covered skin inside the body)", "",
              "| outfit | model | " + " | ".join(f"{b}: frames, collision %, edge mm" for b in bins) + " |"]
    lines.append("|---|---|" + "---|" * len(bins))
    for r in data["outfits"]:
        for m in MODELS:
            b = r["rows"][m].get("by_body_self_intersection", {})
            cells = [f"{b[k]['poses']}, {f(b[k]['collision_pct'])}, {f(b[k]['edge_mm'])}" for k in bins]
            lines.append(f"| {r['outfit']} | {m} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
