"""The actions of ``recon garment``: PBNS and NCS outfits, their resizers, tables and physics references."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

from recon.body import default_body
from recon.cli.garment import NCS_FLAGS
from recon.cli.parsing import default
from recon.errors import ReconError
from recon.garment import store
from recon.garment.author import eval as author_eval
from recon.garment.author import train as author_train
from recon.garment.author.command import author
from recon.garment.author.data import AuthorDataConfig
from recon.garment.author.data import generate as generate_author
from recon.garment.deepsd import eval as deepsd_eval
from recon.garment.deepsd import train as deepsd_train
from recon.garment.deepsd.data import DeePSDDataConfig
from recon.garment.gcvae import train as gcvae_train
from recon.garment.gcvae.command import sample_command
from recon.garment.ncs import eval as ncs_eval
from recon.garment.ncs import train as ncs_train
from recon.garment.pbns import eval as pbns_eval
from recon.garment.pbns import reference_eval
from recon.garment.pbns import train as pbns_train
from recon.garment.resize import ResizeConfig
from recon.garment.taylor import eval as taylor_eval
from recon.garment.taylor import train as taylor_build
from recon.garment.taylor.config import PoseFitConfig, TaylorBuildConfig
from recon.garment.templates import PRESETS


def outfits(names: list[str]) -> list[str]:
    """'all' -> every preset; unknown names refused with the presets listed."""
    if names == ["all"]:
        return list(PRESETS)
    for n in names:
        store.check_outfit(n)
    return names


def train_deepsd(args) -> None:
    """DeePSD is one model for every outfit: drapes of generated outfits, then the network (and its
    ablation variants with ``--variant``)."""
    data = DeePSDDataConfig(**{k: getattr(args, k) for k in ("train_outfits", "workers") if getattr(args, k)})
    names = list(deepsd_train.VARIANTS) if args.variant == "all" else [args.variant]
    for name in names:
        cfg = deepsd_train.variant_config(name, deepsd_train.DeePSDTrainConfig(data=data))
        more = {k: getattr(args, k) for k in ("steps", "physics_steps") if getattr(args, k) is not None}
        if not cfg.physics_steps:  # the variants without a physics branch keep none
            more.pop("physics_steps", None)
        if cfg.init_from:  # a physics variant on the shipped supervised part
            more.pop("steps", None)
        cfg = replace(cfg, **more)
        meta = deepsd_train.train(cfg)
        print(json.dumps({"variant": name, "weights": str(store.deepsd_path(cfg.name)),
                          **{k: meta[k] for k in ("train_outfits", "train_drapes", "train_seconds", "final_rms_mm")}}))


def check_variant(args, variants: dict) -> None:
    if args.variant not in (*variants, "all"):
        raise ReconError(f"--model {args.model} has no variant {args.variant!r}: {', '.join(variants)} or all")


def train_author(names: list[str], args) -> None:
    """Simulations and models for each --train-sets count in turn, every outfit at a count before the
    next count (the data of one count is the start of the next's; models already trained on the same
    data are kept); --data-only: the simulations alone."""
    counts = sorted(set(args.train_sets or [AuthorDataConfig.train_sets]))
    more = {"workers": args.workers} if args.workers else {}
    if args.data_only:  # the largest count's simulations hold every smaller count's
        for o in names:
            data = AuthorDataConfig(outfit=o, train_sets=counts[-1], **more)
            print(json.dumps({"outfit": o, "sets": counts[-1], "simulations": str(generate_author(data))}))
        return
    for n in counts:
        for o in names:
            cfg = author_train.AuthorTrainConfig(data=AuthorDataConfig(outfit=o, train_sets=n, **more))
            if author_train.is_trained(cfg):
                print(json.dumps({"outfit": o, "sets": n, "weights": "already trained on these simulations"}))
                continue
            path, meta = author_train.train(cfg)
            print(json.dumps({"outfit": o, "weights": str(path), "frames": meta["frames"], "sets": meta["sets"],
                              "seconds": meta["seconds"]}))


def train(args) -> None:
    if (args.train_sets or args.data_only) and args.model != "author":
        raise ReconError("--train-sets and --data-only are --model author's")
    if args.model in ("deepsd", "gcvae"):
        check_variant(args, deepsd_train.VARIANTS if args.model == "deepsd" else gcvae_train.VARIANTS)
    if args.model == "deepsd":
        return train_deepsd(args)
    if args.model == "gcvae":
        names = list(gcvae_train.VARIANTS) if args.variant == "all" else [args.variant]
        for name in names:
            cfg = gcvae_train.variant_config(name)
            if args.epochs:
                cfg = replace(cfg, epochs=args.epochs)
            meta = gcvae_train.train(cfg)
            print(json.dumps({"variant": name, "train_garments": meta["train_garments"],
                              "train_seconds": meta["train_seconds"], "last": meta["curve"][-1]}))
        return
    if args.model == "author":
        return train_author(outfits(args.outfit), args)
    for o in outfits(args.outfit):
        if args.model == "taylor":
            more = {k: getattr(args, k) for k in ("anchors", "shapes", "pose_examples", "workers")
                    if getattr(args, k) is not None}
            if args.fit_poses is not None:
                more["pose_fit"] = PoseFitConfig(poses=args.fit_poses)
            path = taylor_build.build(TaylorBuildConfig(outfit=o, **more))
            meta = json.loads(taylor_build.read_meta(path))
            keys = ("anchors", "pose_examples", "fit_poses", "drape_seconds", "fit_seconds", "explained_variance",
                    "ridge")
            print(json.dumps({"outfit": o, "weights": str(path), **{k: meta[k] for k in keys}}))
            continue
        if args.model == "ncs":
            if args.epochs:
                raise ReconError("--epochs is PBNS's: NCS takes --chunks and --steps")
            more = {k: getattr(args, k) for k in NCS_FLAGS if getattr(args, k) is not None}
            meta = ncs_train.train(default_body(), ncs_train.NCSTrainConfig(outfit=o, **more))
            weights = store.ncs_path(o)
        else:
            epochs = {"epochs": args.epochs} if args.epochs else {}
            meta = pbns_train.train(default_body(), pbns_train.GarmentTrainConfig(outfit=o, poses=args.poses,
                                                                                         **epochs))
            weights = store.pbns_path(o)
        last = meta["curve"][-1]
        print(json.dumps({"outfit": meta["outfit"], "weights": str(weights), "train_seconds": meta["train_seconds"],
                          **{k: v for k, v in last.items() if k.startswith("val_")}}))


def resize(args) -> None:
    for o in outfits(args.outfit):
        meta = pbns_train.train_resizer(default_body(), store.pbns_path(o), cfg=ResizeConfig(epochs=args.epochs))
        print(json.dumps({"outfit": meta["outfit"], "weights": str(store.resizer_path(o)),
                          "train_seconds": meta["train_seconds"], "transfer_only": meta["val_transfer_only"],
                          "resized": meta["curve"][-1]}))


def evaluate(args) -> None:
    body, names = default_body(), outfits(args.outfit)
    if args.model == "ncs":
        weights = [Path(w) for w in args.ncs_weights] if args.ncs_weights else None
        if weights and len(weights) != len(names):
            raise ReconError("--ncs-weights takes one file per outfit")
        print(Path(ncs_eval.evaluate_and_report(body, names, Path(args.out), dynamic=not args.no_simulation,
                                                         ncs_weights=weights, log=print, val=args.val,
                                                         update=args.update)).read_text())
        return
    if args.model == "deepsd":
        print(Path(deepsd_eval.evaluate_and_report(Path(args.out))).read_text())
        return
    if args.model == "gcvae":
        print(Path(gcvae_train.evaluate_and_report(Path(args.out))).read_text())
        return
    if args.model == "author":
        print(Path(author_eval.evaluate_and_report(names, "val" if args.val else "test", Path(args.out),
                                                   ablations=not args.no_ablations,
                                                   update=args.update)).read_text())
        return
    if args.model == "taylor":
        print(Path(taylor_eval.evaluate_and_report(names, args.n or default(taylor_eval.evaluate_and_report, "poses"),
                                                   out_dir=Path(args.out),
                                                   speed_outfits=list(PRESETS), newton=not args.no_simulation)
                   ).read_text())
        return
    n = args.n or default(pbns_eval.evaluate_and_report, "n_poses")
    print(Path(pbns_eval.evaluate_and_report(body, names, n, Path(args.out))).read_text())
    for o in names:  # the resizing table, for outfits with a trained resizer
        if store.resizer_path(o).exists():
            print(Path(pbns_eval.evaluate_resizer(body, o, out_dir=Path(args.out))).read_text())


def sample(args) -> None:
    print(json.dumps(sample_command(args.type, args.n, args.out, args.seed, sheet=not args.no_sheet)))


def author_clip(args) -> None:
    store.check_outfit(args.outfit)
    author(args.outfit, args.motion, args.out, keys=args.key or [], export=args.export or [], loop=args.loop,
           render=args.render, max_seconds=args.max_seconds, page=not args.no_page)


def reference(args) -> None:
    names = outfits(args.outfit)
    if not set(names) <= set(PRESETS):
        raise ReconError("reference drapes are for the preset outfits: " + ", ".join(PRESETS))
    for o in names:
        md = (reference_eval.rescore_reference(o, Path(args.out)) if args.rescore
              else reference_eval.reference_and_report(o, args.n, Path(args.out), args.frames, args.workers))
        print(Path(md).read_text())

