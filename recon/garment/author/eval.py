"""``recon garment eval --model author`` -> eval/results/garment-author.{json,md}: the authoring
model on held-out parameter sets and held-out clips (the test performers' windows of
``author.data``; ``--val``: the val performers'), against the simulation with the true parameters.

1. Shape descriptor: reconstruction error against PCA at 20/40/50/100/200 dimensions (and without
   the Laplacian term), on the held-out frames.
2. Motion-invariant encoding: decode(encode(S | M) | M) (same motion) and z from one frame decoded
   on the other windows of the same parameter set (cross-motion), for the paper's model and its two
   ablations (concatenated motion; embedding-loss training).
3. Keyframe propagation: all frames of a window from 1, 2, 5, 10 and 20 % keyframes (at least 2),
   against NCS and PBNS (no keyframes), linear interpolation between the keyframes of the
   character-space vertices, of the offsets from PBNS's drape and from NCS's cloth (a baseline
   that knows the motion's dynamics for the default fabric), and of the shape descriptors; the
   paper's claim (ours at 2 % against interpolation of the vertices at 20 %).
4. Learning curve: the model trained on the first 8, 16, 32, 64, 143 and 715 train sets (1.1k to
   100k frames; ``recon garment train --model author --train-sets N``), those that exist.
5. Speed: re-propagating a 300-frame clip after a keyframe edit, and after a motion edit.

Tables 1 and 2 train 7 more networks (their time: the model card); ``ablations=False`` skips them and keeps
the previous report's, marked with the data they were made on.
"""
from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from recon import report
from recon.body import default_body
from recon.body.base import BodyModel
from recon.garment import store
from recon.garment.author.curves import invariance, probe, render_probe, vertex_error
from recon.garment.author.data import AuthorDataConfig, sim_folder, teacher_config, train_frames
from recon.garment.author.model import (
    PELVIS,
    AuthorModel,
    Session,
    base_ncs,
    clip_inputs,
    interpolate_latents,
)
from recon.garment.author.train import (
    AuthorTrainConfig,
    Frames,
    hanging_outfit,
    is_trained,
    laplacian,
    load_frames,
    model_path,
    principal_basis,
    train,
    train_descriptor,
)
from recon.garment.dress import Dresser
from recon.garment.ncs.data import Chunk, Motions
from recon.garment.pbns.model import PBNS
from recon.poses.mocap import MocapPoses

DIMS = (20, 40, 50, 100, 200)
RATIOS = (0.01, 0.02, 0.05, 0.10, 0.20)
CURVE_SETS = (8, 16, 32, 64, 143, 715)  # train sets of the learning curve: 1.1k to 100k frames
CLAIM = ("0.02", "0.2")  # the paper's claim: ours with keyframes on 2 % of the frames, interpolation on 20 %
VARIANTS = ("ours", "concat", "embedding")
BASES = {"pbns": "PBNS's drape", "ncs": "NCS's cloth"}  # what a model's offsets are taken from


def descriptor_table(train_f: Frames, test_f: Frames, faces: np.ndarray, model: AuthorModel,
                     tcfg: AuthorTrainConfig, log=print) -> list[dict]:
    lap = laplacian(faces, test_f.offsets.shape[1])
    n = test_f.offsets.shape[1]

    def errors(rec):
        d = (rec - test_f.offsets).numpy()
        lap_d = np.stack([lap @ x for x in d])
        return vertex_error(rec, test_f.offsets), float(np.linalg.norm(lap_d, axis=-1).mean() * 1000)

    rows = []
    for dims in DIMS:
        mean, basis, _ = principal_basis(train_f.offsets, dims)
        x = test_f.offsets.reshape(len(test_f.offsets), -1) - mean
        pca = ((x @ basis) @ basis.T + mean).view(-1, n, 3)
        desc = model.descriptor if dims == model.cfg.shape_dims else train_descriptor(
            train_f.offsets, faces, tcfg, dims, log)
        with torch.no_grad():
            ours = desc.decode(desc.encode(test_f.offsets))
        row = {"dims": dims, "pca_mm": errors(pca)[0], "pca_laplacian_mm": errors(pca)[1],
               "ours_mm": errors(ours)[0], "ours_laplacian_mm": errors(ours)[1]}
        if dims == model.cfg.shape_dims:
            plain = train_descriptor(train_f.offsets, faces, replace(tcfg, model=replace(tcfg.model, laplacian=0.0)),
                                     dims, log)
            with torch.no_grad():
                e = errors(plain.decode(plain.encode(test_f.offsets)))
            row |= {"no_laplacian_mm": e[0], "no_laplacian_laplacian_mm": e[1]}
        rows.append(row)
        log(f"descriptor {row}")
    return rows


def keyframes(t: int, lead: int, ratio: float) -> list[int]:
    """max(2, ratio x frames) keyframes evenly spread over the frames after the lead."""
    n = t - lead
    k = max(2, int(round(ratio * n)))
    return [lead + int((i + 0.5) * n / k) for i in range(k)]


def interpolate(values: torch.Tensor, frames: list[int], t: int) -> torch.Tensor:
    """Per-frame linear interpolation of ``values`` (K, ...) given at ``frames``, held at the ends."""
    flat = values.reshape(len(values), -1)
    return interpolate_latents(flat, frames, t).reshape(t, *values.shape[1:])


def propagation(model: AuthorModel, sims, folder: Path, lead: int, body: BodyModel, pbns: PBNS, shape: torch.Tensor,
                log=print, baselines: bool = True) -> dict:
    """Per ratio and method the mean vertex error (mm) of the hanging part over the frames after the
    lead, over all windows x parameter sets; and material carried from another window.
    ``baselines=False``: the model's own row alone."""
    idx = model.index
    dresser = Dresser(model.outfit)
    own_ncs = base_ncs(model.outfit, model.cfg)
    motions = Motions(body, shape[None], teacher_config(model.outfit).smooth_motion)
    errs: dict[str, dict[str, list[float]]] = {}
    carried: list[float] = []
    latents: dict[tuple[int, int], torch.Tensor] = {}
    cache, runs = {}, []
    for s in sims:
        x = torch.from_numpy(np.load(folder / f"{s.name}.npy").astype(np.float32))
        key = (s.chunk.clip, s.chunk.start)
        if key not in cache:
            rot, transl = motions.motion(s.chunk)
            static, yaw, joints = clip_inputs(body, pbns, shape, rot, transl)
            base = clip_inputs(body, pbns, shape, rot, transl, own_ncs)[0] if own_ncs is not None else static
            ncs = torch.from_numpy(dresser.animate(body, rot, shape, transl, 30.0).vertices[:, idx]) if baselines \
                else None
            cache[key] = (static, base, yaw, joints, ncs)
        static, base, yaw, joints, ncs = cache[key]
        t = len(x)
        truth = static.clone()
        truth[:, idx] += x
        ev = slice(lead, None)
        true_h = truth[ev][:, idx]
        session = Session(model, base, yaw, joints)
        runs.append((s, session, truth))
        pelvis = joints[:, PELVIS:PELVIS + 1]
        for ratio in RATIOS:
            keys = keyframes(t, lead, ratio)
            row = errs.setdefault(f"{ratio:g}", {})
            session.keys = {k: truth[k] for k in keys}
            if not baselines:
                row.setdefault("ours", []).append(vertex_error(session.propagate()[ev][:, idx], true_h))
                continue
            session.fade = 10
            faded = session.propagate()
            session.fade = None
            got = {"ours": session.propagate(), "ours, no residual": session.propagate(residuals=False),
                   "ours, residual faded over 10 frames": faded,
                   "NCS (default parameters)": static.clone(), "PBNS": static}
            got["NCS (default parameters)"][:, idx] = ncs
            char = torch.einsum("kji,knj->kni", yaw[keys], truth[keys] - pelvis[keys])
            got["interpolation: vertices"] = torch.einsum("tij,tnj->tni", yaw, interpolate(char, keys, t)) + pelvis
            pbns_local = torch.einsum("kji,knj->kni", yaw[keys], truth[keys] - static[keys])
            got["interpolation: offsets from PBNS"] = static + torch.einsum("tij,tnj->tni", yaw,
                                                                           interpolate(pbns_local, keys, t))
            dynamic = got["NCS (default parameters)"]
            ncs_local = torch.einsum("kji,knj->kni", yaw[keys], truth[keys] - dynamic[keys])
            got["interpolation: offsets from NCS"] = dynamic + torch.einsum("tij,tnj->tni", yaw,
                                                                            interpolate(ncs_local, keys, t))
            with torch.no_grad():  # the descriptor's offsets are from the model's base cloth
                s_keys = model.descriptor.encode(session.local(keys, truth[keys])[:, idx])
                dec = model.descriptor.decode(interpolate(s_keys, keys, t))
            desc = base.clone()
            desc[:, idx] += torch.einsum("tij,tnj->tni", yaw, dec)
            got["interpolation: descriptors"] = desc
            for name, v in got.items():
                row.setdefault(name, []).append(vertex_error(v[ev][:, idx], true_h))
            if ratio == RATIOS[0]:
                latents[(s.set, s.chunk.clip)] = session.latents()
        log(f"propagated {s.name}: 2 keys ours {errs[f'{RATIOS[0]:g}']['ours'][-1]:.1f} mm")
    # the material carried: the 2 keyframes' z of another window of the same set, no residuals
    for s, session, truth in runs:
        other = [z for (st, c), z in latents.items() if st == s.set and c != s.chunk.clip]
        if not other:
            continue
        z = other[0].mean(0, keepdim=True).expand(len(session), -1)
        got = session.propagate(latents=z, residuals=False)
        carried.append(vertex_error(got[lead:, idx], truth[lead:, idx]))
    out = {r: {m: float(np.mean(v)) for m, v in row.items()} for r, row in errs.items()}
    return {"ratios": out, "keys": {f"{r:g}": len(keyframes(len(static), lead, r)) for r in RATIOS},
            "material_from_other_clip_mm": float(np.mean(carried)) if carried else None}


def speed(model: AuthorModel, body: BodyModel, pbns: PBNS, shape: torch.Tensor, frames: int = 300,
          repeats: int = 5) -> dict:
    """Frames a second of re-propagating a ``frames``-frame test clip with 2 keyframes after a
    keyframe edit (the motion's inputs kept) and after a motion edit (signatures and the base cloth
    redone), on one thread."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _speed(model, body, pbns, shape, frames, repeats)
    finally:
        torch.set_num_threads(threads)


def _speed(model: AuthorModel, body: BodyModel, pbns: PBNS, shape: torch.Tensor, frames: int, repeats: int) -> dict:
    m = Motions(body, shape[None], teacher_config(model.outfit).smooth_motion)
    clips = MocapPoses.load("test")
    c = int(max(np.unique(clips.clip), key=lambda k: (clips.clip == k).sum()))
    rot, transl = m.motion(Chunk("test", c, 0, frames))
    ncs = base_ncs(model.outfit, model.cfg)
    static, yaw, joints = clip_inputs(body, pbns, shape, rot, transl, ncs)
    session = Session(model, static, yaw, joints)
    for k in (frames // 4, 3 * frames // 4):
        session.set_key(k, static[k])
    key_times, motion_times = [], []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        session.set_key(frames // 4, static[frames // 4] + 0.001)
        session.propagate()
        key_times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        session.set_motion(*clip_inputs(body, pbns, shape, rot, transl, ncs))
        session.propagate()
        motion_times.append(time.perf_counter() - t0)
    return {"frames": frames, "threads": 1, "key_edit_fps": frames / float(np.median(key_times[1:])),
            "motion_edit_fps": frames / float(np.median(motion_times[1:]))}


def ensure_variant(outfit: str, variant: str, log=print) -> AuthorModel:
    """The ablation ``variant``'s model, trained first unless trained on the same simulations."""
    cfg = AuthorTrainConfig(data=AuthorDataConfig(outfit=outfit), variant=variant)
    if not is_trained(cfg):
        log(f"training the {variant} variant of {outfit}")
        train(cfg, log=log)
    return AuthorModel.load(model_path(cfg))[0]


def learning_curve(outfit: str, sims, folder: Path, lead: int, done: dict, body: BodyModel, pbns: PBNS,
                   shape: torch.Tensor, log=print) -> dict:
    """The model's propagation errors per ratio on the held-out ``sims`` for each train-set count of
    ``CURVE_SETS`` whose model is trained on the current simulations (``done``: {sets: errors}
    already measured); the other counts listed."""
    rows, absent = [], []
    for n in CURVE_SETS:
        cfg = AuthorTrainConfig(data=replace(AuthorDataConfig(outfit=outfit), train_sets=n))
        if n in done:
            errors = done[n]
        elif is_trained(cfg):
            model = AuthorModel.load(model_path(cfg))[0]
            p = propagation(model, sims, folder, lead, body, pbns, shape, log, baselines=False)
            errors = {r: v["ours"] for r, v in p["ratios"].items()}
        else:
            absent.append(n)
            continue
        rows.append({"sets": n, "frames": train_frames(cfg.data), "ours_mm": errors})
    return {"rows": rows, "absent": absent}


def evaluate(outfit: str = "tshirt-skirt", split: str = "test", ablations: bool = True, log=print) -> dict:
    """Every table of one outfit (the networks the ablations train use the threads torch has)."""
    body = default_body()
    model, meta = AuthorModel.load(store.author_path(outfit))
    dcfg = AuthorDataConfig(**meta["config"]["data"])
    folder = sim_folder(dcfg)
    tcfg = AuthorTrainConfig(data=dcfg, model=model.cfg)
    hanging = hanging_outfit(body, outfit)
    pbns, _ = PBNS.load(store.trained_pbns(outfit))
    train_f, _, lead = load_frames(dcfg, "train", model.cfg, body, log)
    test_f, test_sims, _ = load_frames(dcfg, split, model.cfg, body, log)
    out = {"outfit": outfit, "split": split, "frames": {"train": len(train_f.offsets), split: len(test_f.offsets)},
           "sets": {"train": int(len(torch.unique(train_f.set_id))), split: int(len(torch.unique(test_f.set_id)))},
           "windows": len({(s.chunk.clip, s.chunk.start) for s in test_sims}), "lead": lead,
           "vertices": int(len(model.index)), "base": model.cfg.base, "network_share": model.cfg.network_share,
           "train_seconds": meta["seconds"],
           "data_seconds": json.loads((folder / "timing.json").read_text()) if (folder / "timing.json").exists()
           else None}
    out["propagation"] = propagation(model, test_sims, folder, lead, body, pbns, hanging.shape, log)
    ours = {r: v["ours"] for r, v in out["propagation"]["ratios"].items()}
    out["curve"] = learning_curve(outfit, test_sims, folder, lead, {dcfg.train_sets: ours}, body, pbns,
                                  hanging.shape, log)
    out["speed"] = speed(model, body, pbns, hanging.shape)
    if ablations:
        out["descriptor"] = descriptor_table(train_f, test_f, hanging.faces, model, tcfg, log)
    out["probe"] = probe(model, train_f, test_f, test_sims)
    out["invariance"] = {v: invariance(model if v == "ours" else ensure_variant(outfit, v, log), test_f, lead)
                         for v in (VARIANTS if ablations else VARIANTS[:1])}
    return out


def render(results: list[dict]) -> str:
    lines = ["# Keyframe garment authoring (intrinsic garment space)", "",
             "`recon garment eval --model author` (recon/garment/author/eval.py). Simulations of the outfit's "
             "hanging part with held-out intrinsic parameters (fabric, gravity, damping, friction) on held-out "
             "clips, by NCS's teacher (recon/garment/author/data.py); errors are mean per-vertex distances of the "
             "hanging part to the simulation with the true parameters, over the frames after the lead.", ""]
    for r in results:
        p = r["propagation"]
        lines += [f"## {r['outfit']} ({r['split']}: {r['sets'][r['split']]} parameter sets x {r['windows']} windows, "
                  f"{r['frames'][r['split']]} frames; trained on {r['frames']['train']} frames of "
                  f"{r['sets']['train']} sets)", "", "### Keyframe propagation (mm)", ""]
        if "base" in r:
            lines += [f"Ours: offsets from {BASES[r['base']]}, the network's share between keyframes "
                      f"{r['network_share']:g} (chosen on the val windows; 1 is the paper's propagation).", ""]
        ratios = list(p["ratios"])
        methods = list(p["ratios"][ratios[0]])
        heads = ["method"] + [f"{float(x) * 100:g} % ({p['keys'][x]} keys)" for x in ratios]
        lines += [report.table([[m] + [p["ratios"][x][m] for x in ratios] for m in methods], heads), ""]
        ours, interp = CLAIM
        if ours in p["ratios"] and interp in p["ratios"]:
            a, b = p["ratios"][ours]["ours"], p["ratios"][interp]["interpolation: vertices"]
            lines += [f"The paper's claim (keyframes on {float(ours) * 100:g} % of the frames as good as linear "
                      f"interpolation on {float(interp) * 100:g} %): ours {a:.1f} mm against {b:.1f} mm, "
                      f"{'met' if a <= b else 'not met'}.", ""]
        c = r.get("curve")
        if c:
            lines += ["### Learning curve (ours, mm)", "",
                      "The model trained on the first N train parameter sets of the same simulations "
                      "(`recon garment train --model author --train-sets N`).", ""]
            lines += [report.table([[row["sets"], row["frames"]] + [row["ours_mm"].get(x) for x in ratios]
                                    for row in c["rows"]], ["train sets", "train frames"] + heads[1:]), ""]
            if c["absent"]:
                lines += [f"Not trained yet: {', '.join(str(n) for n in c['absent'])} sets.", ""]
        if p["material_from_other_clip_mm"] is not None:
            lines += [f"Material carried from another clip (z of its 2 keyframes, no residuals): "
                      f"{p['material_from_other_clip_mm']:.1f} mm.", ""]
        s = r["speed"]
        lines += [f"Speed ({s['frames']}-frame clip, {s['threads']} thread): {s['key_edit_fps']:.0f} frames/s "
                  f"after a keyframe edit, {s['motion_edit_fps']:.0f} after a motion edit.", ""]
        lines += _ablation_tables(r["invariance"], r.get("descriptor"))
        if "probe" in r:
            lines += render_probe(r["probe"], r["invariance"].get("ours"), r.get("probe_curve"))
        old = r.get("previous_ablations")
        if old:
            lines += [f"### Ablations not re-run in this report: {old['data']}", ""]
            lines += [line.replace("### ", "#### ") for line in _ablation_tables(old["invariance"], old["descriptor"])]
        d = r["data_seconds"]
        sim = f"{d['seconds'] / 60:.1f} min on {d['workers']} processes (all runs)" if d else "not recorded"
        fit = ", ".join(f"{k} {v:.0f} s" for k, v in r["train_seconds"].items() if k != "data" and v is not None)
        lines += [f"Simulation: {sim}; training: {fit or 'not recorded'}.", ""]
    return "\n".join(lines)


def _ablation_tables(inv: dict, descriptor: list[dict] | None) -> list[str]:
    rows = [[v, inv[v]["descriptor_mm"], inv[v]["same_motion_mm"], inv[v]["cross_motion_mm"]] for v in inv]
    lines = ["### Motion-invariant encoding (mm)", "",
             report.table(rows, ["model", "descriptor alone", "same motion", "cross-motion"]), ""]
    if descriptor:
        rows = [[d["dims"], d["pca_mm"], d["ours_mm"], d["pca_laplacian_mm"], d["ours_laplacian_mm"],
                 d.get("no_laplacian_mm"), d.get("no_laplacian_laplacian_mm")] for d in descriptor]
        lines += ["### Shape descriptor (mm: vertex error, Laplacian error)", "",
                  report.table(rows, ["dims", "PCA", "ours", "PCA lap.", "ours lap.", "no Laplacian term",
                                      "no Lap. term lap."], ["d", ".2f", ".2f", ".3f", ".3f", ".2f", ".3f"]), ""]
    return lines


def evaluate_and_report(outfits: list[str], split: str = "test", out_dir: Path = report.RESULTS,
                        ablations: bool = True, update: bool = False, log=print) -> Path:
    """The tables of ``outfits``; ``ablations=False`` keeps the previous report's ablation tables of
    each outfit, marked as made on that report's data; ``update`` keeps the other outfits' tables
    of the existing report (one outfit re-evaluated)."""
    name = "garment-author" if split == "test" else f"garment-author-{split}"
    path = Path(out_dir) / f"{name}.json"
    before = {r["outfit"]: r for r in json.loads(path.read_text())["outfits"]} if path.exists() else {}
    mine = {}
    for o in outfits:
        r = evaluate(o, split, ablations, log)
        prev = before.get(o, {})
        old = prev.get("previous_ablations")
        if prev.get("descriptor"):  # the previous report ran the ablations: those are the ones to keep
            old = {"data": f"the previous report's ({prev['frames']['train']} train frames of {prev['sets']['train']} "
                           f"sets, offsets from {BASES[prev.get('base', 'pbns')]})", "invariance": prev["invariance"],
                   "descriptor": prev["descriptor"]}
        if not ablations and old:
            r["previous_ablations"] = old
        mine[o] = r
    data = list(mine.values())
    if update:  # the re-evaluated outfits where they were, the others as they were
        data = [mine.get(o, r) for o, r in before.items()] + [r for o, r in mine.items() if o not in before]
    return report.write(Path(out_dir) / name, {"outfits": data}, render(data))
