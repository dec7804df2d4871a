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


def cmd_demo(args) -> int:
    from recon.demo import body_demo

    for p in body_demo(Path(args.out), seed=args.seed):
        print(p)
    return 0


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    ap = argparse.ArgumentParser(prog="recon", description=__doc__)
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default $RECON_THREADS or 1)")
    sub = ap.add_subparsers(dest="cmd", required=True)
    b = sub.add_parser("body", help="body model: build the anny cache or print model facts")
    b.add_argument("action", choices=["build-cache", "info"])
    b.add_argument("--model", default="anny", help="'anny' or an SMPL-family .npz/.pkl")
    b.add_argument("--force", action="store_true")
    b.set_defaults(func=cmd_body)
    p = sub.add_parser("poses", help="retargeted mocap: build the cache or print split statistics")
    p.add_argument("action", choices=["build", "stats"])
    p.add_argument("--force", action="store_true")
    p.add_argument("--limit", type=int, default=None, help="only the first N clips (quick checks)")
    p.set_defaults(func=cmd_poses)
    d = sub.add_parser("demo", help="render bodies in held-out mocap poses; write PNG, OBJ and GLB")
    d.add_argument("--out", default="out/demo")
    d.add_argument("--seed", type=int, default=0)
    d.set_defaults(func=cmd_demo)
    args = ap.parse_args(argv)
    _threads(args.threads)
    try:
        return args.func(args)
    except (FileNotFoundError, ValueError, KeyError, RuntimeError) as e:
        print(f"recon: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
