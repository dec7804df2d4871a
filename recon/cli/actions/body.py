"""The actions of ``recon body`` and ``recon poses``: the body model and the retargeted pose set."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import torch

from recon.body import anny_model, create
from recon.export.mesh import write_mesh
from recon.poses import mocap


def body_build_cache(args) -> None:
    print(anny_model.build_cache(force=args.force))


def body_info(args) -> None:
    body = create(args.model)
    out = body()
    print(json.dumps({
        "model": args.model, "vertices": body.num_vertices, "faces": int(body.faces.shape[0]),
        "joints": list(body.joint_names), "landmarks": list(body.landmark_names),
        "landmark_vertex_ids": body.landmark_indices.tolist(), "shape_params": list(body.shape_names),
        "height_m": float(out.vertices[0, :, 1].max() - out.vertices[0, :, 1].min())}, indent=1))


def body_export(args) -> None:
    """The rest body (mean shape) that garments are modelled on: body frame, metres, +Y up."""
    body = create(args.model)
    with torch.no_grad():
        v = body.rest_geometry(body.mean_shape[None])[0][0].numpy()
    print(write_mesh(args.out, v, body.faces.numpy()))


def poses_build(args) -> None:
    out = Path(args.out) if args.out else mocap.built_path()
    if out.exists() and not args.force:
        print(f"{out} exists (use --force to rebuild)")
        return
    print(mocap.build(mocap_root=args.mocap, out=out, limit=args.limit))
    print(f"use it with RECON_POSES={out} (the shipped set is {mocap.SHIPPED})", file=sys.stderr)


def poses_stats(args) -> None:
    m = mocap.MocapPoses.load()
    stats = {s: {"frames": len(m.split(s)), "minutes": round(len(m.split(s)) / mocap.FPS / 60, 2),
                 "clips": sum(c["split"] == s for c in m.clips),
                 "subjects": sorted({c["subject"] for c in m.clips if c["split"] == s})}
             for s in ("train", "val", "test")}
    stats["max_primary_bone_error_deg"] = max(c["max_primary_bone_error_deg"] for c in m.clips)
    stats["file"] = str(mocap.poses_path())
    print(json.dumps(stats, indent=1))

